"""Writes the mesh files the mesh scenes use, so the repository can rebuild them.

    python scenes/make_mesh_models.py              # scenes/models/torus.ply
    python scenes/make_mesh_models.py --big PATH   # a ~1M-triangle terrain for benchmarks
    python scenes/make_mesh_models.py --big PATH --triangles 1000 --rough  # see terrain's rough

The models are built with NumPy and written by trimesh (binary PLY); nothing
here parses or writes a mesh format by hand.
"""

from __future__ import annotations

import argparse
from pathlib import Path

import numpy as np
import trimesh

MODELS = Path(__file__).resolve().parent / "models"


def torus(major=1.0, minor=0.35, rings=96, sides=48) -> trimesh.Trimesh:
    """A torus around the y axis with smooth vertex normals."""
    a, b = np.meshgrid(np.linspace(0, 2 * np.pi, rings, endpoint=False),
                       np.linspace(0, 2 * np.pi, sides, endpoint=False), indexing="ij")
    x = (major + minor * np.cos(b)) * np.cos(a)
    z = (major + minor * np.cos(b)) * np.sin(a)
    y = minor * np.sin(b)
    normals = np.stack((np.cos(b) * np.cos(a), np.sin(b), np.cos(b) * np.sin(a)), axis=-1).reshape(-1, 3)
    vertices = np.stack((x, y, z), axis=-1).reshape(-1, 3)
    i, j = np.meshgrid(np.arange(rings), np.arange(sides), indexing="ij")
    p = i * sides + j
    q = ((i + 1) % rings) * sides + j
    r = ((i + 1) % rings) * sides + (j + 1) % sides
    s = i * sides + (j + 1) % sides
    faces = np.concatenate((np.stack((p, s, r), -1).reshape(-1, 3), np.stack((p, r, q), -1).reshape(-1, 3)))
    mesh = trimesh.Trimesh(vertices, faces, vertex_normals=normals, process=False)
    mesh.fix_normals()  # outward winding, so front faces face out
    return mesh


def terrain(triangles: int, seed: int = 7, rough: bool = False) -> trimesh.Trimesh:
    """A bumpy height field of about ``triangles`` triangles over [-1, 1]^2.

    The surface is the same at every triangle count: a broad swell plus 16
    fixed waves (random directions and phases from ``seed``), sampled on a
    finer or coarser grid, so that a 1k and a 1M terrain differ only in how
    finely they are cut (the benchmarks' time-per-segment ratio measures the
    triangle count, not a different scene).

    ``rough``: instead of the waves, independent noise of 0.004 at every
    vertex, the benchmarks' terrain up to session 7.  Its slopes grow with
    the resolution (~0.04 at 1k triangles, ~1.4 at 1M: a surface of
    sub-pixel spikes, where 55 % of bounce rays hit it again nearby), which
    makes it a stress case for the BVH rather than the same scene cut finer.
    """
    n = max(1, int(round(np.sqrt(triangles / 2))))
    rng = np.random.default_rng(seed)
    x, z = np.meshgrid(np.linspace(-1, 1, n + 1), np.linspace(-1, 1, n + 1))
    y = 0.08 * np.sin(6 * x) * np.cos(5 * z)
    if rough:
        y += 0.004 * rng.normal(size=x.shape)
    else:
        waves, amplitude = 16, 0.003
        k = 12 * rng.normal(size=(waves, 2))  # wavelengths of ~0.2 to a few units
        phase = rng.uniform(0, 2 * np.pi, waves)
        for (kx, kz), p in zip(k, phase):
            y += amplitude * np.sin(kx * x + kz * z + p)
    vertices = np.stack((x, y, z), axis=-1).reshape(-1, 3)
    i = (np.arange(n)[:, None] * (n + 1) + np.arange(n)[None, :]).ravel()
    faces = np.concatenate((np.stack((i, i + n + 1, i + n + 2), -1), np.stack((i, i + n + 2, i + 1), -1)))
    return trimesh.Trimesh(vertices, faces, process=False)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--big", metavar="PATH", help="write a ~1M-triangle terrain (binary PLY) to PATH")
    parser.add_argument("--triangles", type=int, default=1_000_000)
    parser.add_argument("--rough", action="store_true", help="per-vertex noise instead of the fixed waves (see terrain)")
    args = parser.parse_args()
    if args.big:
        terrain(args.triangles, rough=args.rough).export(args.big, file_type="ply")
        return
    MODELS.mkdir(exist_ok=True)
    torus().export(MODELS / "torus.ply", file_type="ply")
    print("wrote", MODELS / "torus.ply")


if __name__ == "__main__":
    main()

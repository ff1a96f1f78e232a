"""Time per path segment on the generated terrains at ~1k and ~1M triangles, one core (issue #11's floor: <= 3x).

    .venv/bin/python benchmarks/terrain_segments.py                 # this checkout, 3 interleaved runs
    .venv/bin/python benchmarks/terrain_segments.py --runs 5 --root /path/to/other/checkout
    .venv/bin/python benchmarks/terrain_segments.py --set BIG_LEAF_ROUNDS=2 --set SUBTREE_LEVELS=3

The quick, wavefront-only form of ``bench.py --section geometry``'s one-core
rows, for iterating on the intersection engine.  Each run is a fresh process
that compiles the scene (timed: the BVH build), then renders it with that
compiled scene on one worker, so the per-segment time is the render's alone
and not a difference of two noisy timings.  Both wall and CPU time are
printed: on a machine shared with other jobs the CPU time is the steadier of
the two.  The terrains (scenes/make_mesh_models.py) are written once to
``--folder``: one surface cut into ~1k and ~1M triangles (the floor's pair), and
the rough terrains (per-vertex noise, a stress case: at 1M a surface of
sub-pixel spikes, at 1k nearly smooth; ``--no-rough`` skips them); ``--torus`` adds
a second model, scenes/make_mesh_models.py's torus at 1,024 and 1,048,576 triangles.  ``--set NAME=VALUE`` sets a constant of ``wavefront.bvh`` in
the children before the scene is compiled, to try a tuning without editing
the module (compare against a run without it: interleave, medians).
"""

from __future__ import annotations

import argparse
import json
import statistics
import subprocess
import sys
import tempfile
from pathlib import Path

ROOT = Path(__file__).resolve().parent.parent
CHILD = r"""
import json, sys, time
sys.path.insert(0, sys.argv[2])
import wavefront
from wavefront import bvh
for setting in json.loads(sys.argv[3]):  # --set NAME=VALUE: constants of wavefront.bvh
    name, value = setting.split("=", 1)
    current = getattr(bvh, name, None)
    if not name.isupper() or not isinstance(current, (int, float)):
        sys.exit(f"--set {setting}: wavefront.bvh has no numeric constant {name}")
    setattr(bvh, name, type(current)(float(value)))
scene = wavefront.load_scene(sys.argv[1])
wall = time.perf_counter()
compiled = scene.compile()
build = time.perf_counter() - wall
wall, cpu = time.perf_counter(), time.process_time()
r = wavefront.render_scene(scene, workers=1, memory=1536 << 20, compiled=compiled)
wall, cpu = time.perf_counter() - wall, time.process_time() - cpu
print(json.dumps({"build": build, "wall": wall, "cpu": cpu, "segments": r.stats.segments, "samples": r.stats.samples,
                  "peak": r.stats.peak_memory, "wavefront": wavefront.__file__}))
"""


def terrain(folder: Path, triangles: int, rough: bool = False) -> Path:
    """The geometry section's terrain scene (written once to ``folder``)."""
    scene = folder / f"{'rough_' if rough else ''}terrain_{triangles}.yaml"
    if not scene.exists():
        sys.path.insert(0, str(ROOT / "benchmarks"))
        from bench import terrain_scene  # the same scene as bench.py's geometry section

        return Path(terrain_scene(folder, triangles, rough))
    return scene


def torus(folder: Path, rings: int, sides: int) -> Path:
    """A second model for the ratio: scenes/make_mesh_models.py's torus cut into
    rings x sides x 2 triangles (written once to ``folder``)."""
    scene = folder / f"torus_{rings}x{sides}.yaml"
    if not scene.exists():
        sys.path.insert(0, str(ROOT / "scenes"))
        from make_mesh_models import torus as make_torus

        make_torus(rings=rings, sides=sides).export(folder / f"torus_{rings}x{sides}.ply", file_type="ply")
        sys.path.insert(0, str(ROOT / "benchmarks"))
        from bench import MESH_SCENE

        scene.write_text(MESH_SCENE.format(script="terrain_segments.py --torus",
                                           what=f"a torus of {rings}x{sides}x2 triangles",
                                           camera="{look_from: [0, 2.0, 2.6], look_at: [0, 0, 0], vfov: 45}",
                                           file=f"torus_{rings}x{sides}.ply"))
    return scene


def main(argv=None) -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--runs", type=int, default=3)
    parser.add_argument("--root", default=str(ROOT), help="checkout whose wavefront package to time")
    # (a new name: "wavefront-terrain" held session 7's rough terrains under the plain names)
    parser.add_argument("--folder", default=str(Path(tempfile.gettempdir()) / "wavefront-terrains"))
    parser.add_argument("--no-rough", action="store_true", help="time the floor's pair only")
    parser.add_argument("--torus", action="store_true",
                        help="also a torus of 1,024 and 1,048,576 triangles (a second model for the ratio)")
    parser.add_argument("--set", action="append", default=[], metavar="NAME=VALUE",
                        help="set a numeric constant of wavefront.bvh in the timed children (repeatable)")
    args = parser.parse_args(argv)
    folder = Path(args.folder)
    folder.mkdir(parents=True, exist_ok=True)
    scenes = {"1k": terrain(folder, 1_000), "1M": terrain(folder, 1_000_000)}
    if not args.no_rough:
        scenes.update({"1k rough": terrain(folder, 1_000, True), "1M rough": terrain(folder, 1_000_000, True)})
    if args.torus:
        scenes.update({"1k torus": torus(folder, 32, 16), "1M torus": torus(folder, 1024, 512)})
    runs = {label: [] for label in scenes}
    for _ in range(args.runs):
        for label, scene in scenes.items():  # interleaved, so both see the same machine
            # cwd=root: `python -c` puts the cwd first on sys.path
            child = subprocess.run([sys.executable, "-c", CHILD, str(scene), args.root, json.dumps(args.set)],
                                   capture_output=True, text=True, cwd=args.root)
            if child.returncode:
                sys.exit(f"the {label} run failed:\n{child.stderr.strip()}")
            runs[label].append(json.loads(child.stdout))
    settings = f" with {', '.join(args.set)}" if args.set else ""
    print(f"wavefront from {runs['1k'][0]['wavefront']}{settings}; medians of {args.runs} interleaved runs, one core\n")
    print("| terrain | BVH build (compile) | wall per segment | CPU per segment | segments per path | peak memory |\n"
          "|---|---|---|---|---|---|")
    per = {}
    for label, rs in runs.items():
        wall = statistics.median(r["wall"] / r["segments"] * 1e9 for r in rs)
        cpu = statistics.median(r["cpu"] / r["segments"] * 1e9 for r in rs)
        per[label] = wall, cpu
        print(f"| {label} | {statistics.median(r['build'] for r in rs):.2f} s | {wall:.0f} ns | {cpu:.0f} ns | "
              f"{rs[0]['segments'] / rs[0]['samples']:.2f} | {max(r['peak'] for r in rs) / 2**20:.0f} MiB |")
    print(f"\n1M / 1k per segment, the same surface: {per['1M'][0] / per['1k'][0]:.2f}x wall, "
          f"{per['1M'][1] / per['1k'][1]:.2f}x CPU")
    if "1M torus" in per:
        print(f"1M / 1k per segment, torus: {per['1M torus'][0] / per['1k torus'][0]:.2f}x wall, "
              f"{per['1M torus'][1] / per['1k torus'][1]:.2f}x CPU")
    if "1M rough" in per:
        print(f"1M / 1k per segment, rough terrains (a different surface at each size): "
              f"{per['1M rough'][0] / per['1k rough'][0]:.2f}x wall, {per['1M rough'][1] / per['1k rough'][1]:.2f}x CPU")


if __name__ == "__main__":
    main()

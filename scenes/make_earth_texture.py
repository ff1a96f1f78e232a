"""Write scenes/earthmap.png: a procedural, earth-like equirectangular map for earth.yaml.

RTOW book 2 wraps a photograph of the Earth on a sphere; this repository
rebuilds a stand-in from noise so it carries no third-party image.  Every
pixel's direction on the unit sphere (the inverse of ``get_sphere_uv``) is fed
to fractal Perlin noise (wavefront's own, seeded), so continents do not tear
at the map's seam or pinch at its poles.  Height above a sea level makes
oceans (deeper is darker), coasts, grassland, forest, desert and mountains;
ice caps cover high latitudes.

    python scenes/make_earth_texture.py            # 512 x 256, about a second
"""

from __future__ import annotations

import argparse
import os

import imageio.v3 as iio
import numpy as np

from wavefront.textures import Perlin

HERE = os.path.dirname(os.path.abspath(__file__))


def fractal(perlin: Perlin, p: np.ndarray, octaves: int, frequency: float) -> np.ndarray:
    """Signed fractal noise ``(N,)``: octaves of Perlin noise, each twice the frequency and half the weight."""
    total, weight = np.zeros(p.shape[1]), 1.0
    for _ in range(octaves):
        total += weight * perlin.noise(p * frequency)
        weight *= 0.5
        frequency *= 2.0
    return total


def earth_map(width: int, height: int, seed: int = 7) -> np.ndarray:
    """An sRGB ``(height, width, 3)`` uint8 map; row 0 is the north (v = 1)."""
    u = (np.arange(width) + 0.5) / width
    v = 1.0 - (np.arange(height) + 0.5) / height
    uu, vv = np.meshgrid(u, v)
    phi, theta = 2.0 * np.pi * uu.ravel() - np.pi, np.pi * vv.ravel()  # as get_sphere_uv, inverted
    direction = np.stack((-np.sin(theta) * np.cos(phi), -np.cos(theta), np.sin(theta) * np.sin(phi)))
    perlin = Perlin.build(seed)
    height_field = fractal(perlin, direction + 10.0, 8, 1.6)
    moisture = fractal(Perlin.build(seed + 1), direction - 5.0, 5, 2.0)
    latitude = np.arcsin(np.abs(direction[1])) / (0.5 * np.pi)  # 0 at the equator, 1 at the poles
    sea_level = 0.02
    land = height_field > sea_level
    elevation = np.clip((height_field - sea_level) / 0.5, 0.0, 1.0)
    depth = np.clip((sea_level - height_field) / 0.5, 0.0, 1.0)

    ocean = np.array([[0.02, 0.12, 0.35]]).T * (1.0 - 0.6 * depth) + np.array([[0.0, 0.05, 0.08]]).T * (1 - depth)
    grass, forest = np.array([[0.30, 0.45, 0.15]]).T, np.array([[0.10, 0.28, 0.08]]).T
    desert, rock = np.array([[0.75, 0.65, 0.42]]).T, np.array([[0.45, 0.38, 0.30]]).T
    # drier near the tropics' deserts (|lat| ~ 0.4) and where moisture is low
    dry = np.clip(0.6 - 2.0 * moisture - 1.5 * np.abs(latitude - 0.3), 0.0, 1.0)
    ground = grass * (1 - dry) + desert * dry
    ground = ground * (1 - np.clip(moisture * 2.0, 0, 1) * (1 - dry)) + forest * np.clip(moisture * 2.0, 0, 1) * (1 - dry)
    ground = ground * (1 - elevation ** 2) + rock * elevation ** 2
    color = np.where(land, ground, ocean)
    ice = np.clip((latitude - 0.86 + 0.1 * height_field) / 0.03, 0.0, 1.0)
    color = color * (1 - ice) + 0.9 * ice
    return np.round(np.clip(color.T, 0, 1) * 255).astype(np.uint8).reshape(height, width, 3)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--width", type=int, default=512)
    parser.add_argument("--output", default=os.path.join(HERE, "earthmap.png"))
    args = parser.parse_args()
    iio.imwrite(args.output, earth_map(args.width, args.width // 2))
    print(f"wrote {args.output}")


if __name__ == "__main__":
    main()

"""Scenes with exact answers: lossless spheres in a white furnace vanish."""

from pathlib import Path

import numpy as np
import pytest

from wavefront import Lambertian, Scene, Solid, Sphere, load_scene, render

SCENES = Path(__file__).resolve().parent.parent / "scenes"


@pytest.mark.parametrize("name", ["furnace_lambertian", "furnace_mirror", "furnace_glass"])
def test_lossless_sphere_in_white_furnace_renders_as_background(name):
    scene = load_scene(SCENES / f"{name}.yaml")
    image = render(scene, workers=1)
    assert image.shape == (64, 64, 3)
    # Each path returns exactly 1 unless it is still bouncing inside glass at
    # max_depth (probability ~ R^49, never seen); allow float32 rounding only.
    np.testing.assert_allclose(image, 1.0, atol=1e-6)


@pytest.mark.parametrize("albedo", [0.0, 0.3, 0.7])
def test_grey_lambertian_sphere_in_furnace_shows_its_albedo(albedo):
    """A convex sphere is hit at most once, so its pixels equal the albedo
    exactly; pixels straddling the silhouette lie between albedo and 1."""
    scene = Scene(spheres=[Sphere((0, 0, 0), 1, "m")], materials={"m": Lambertian((albedo,) * 3)},
                  background=Solid((1, 1, 1)), width=48, height=48).with_overrides(samples_per_pixel=4)
    scene = scene.replace(camera=scene.camera.__class__(look_from=(0, 0, 3), look_at=(0, 0, 0), vfov=40))
    image = render(scene, workers=1)
    centre = image[18:30, 18:30]
    np.testing.assert_allclose(centre, albedo, atol=1e-6)
    assert image.min() >= albedo - 1e-6 and image.max() <= 1 + 1e-6
    np.testing.assert_allclose(image[0, 0], 1.0)  # a corner sees only the background

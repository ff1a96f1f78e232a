"""Scenes with exact answers: lossless spheres in a white furnace vanish."""

import dataclasses
from pathlib import Path

import numpy as np
import pytest

from wavefront import Lambertian, Scene, Solid, Sphere, load_scene, render

SCENES = Path(__file__).resolve().parent.parent / "scenes"


@pytest.mark.parametrize("name", ["furnace_lambertian", "furnace_mirror", "furnace_glass"])
def test_lossless_sphere_in_white_furnace_renders_as_background(name):
    scene = load_scene(SCENES / f"{name}.yaml")
    scene = scene.replace(render=dataclasses.replace(scene.render, russian_roulette=False))
    image = render(scene, workers=1)
    assert image.shape == (64, 64, 3)
    # Each path returns exactly 1 unless it is still bouncing inside glass at
    # max_depth (probability ~ R^49, never seen); allow float32 rounding only.
    np.testing.assert_allclose(image, 1.0, atol=1e-6)


@pytest.mark.parametrize("name", ["furnace_lambertian", "furnace_mirror"])
def test_white_furnace_stays_exact_with_roulette_on(name):
    """With the scenes' settings (light sampling and roulette from depth 5 on):
    a convex lossless sphere ends every path within two segments, before
    roulette starts, so the image is still exactly 1."""
    scene = load_scene(SCENES / f"{name}.yaml")
    assert scene.render.russian_roulette is not None and scene.render.russian_roulette.depth == 5
    np.testing.assert_allclose(render(scene, workers=1), 1.0, atol=1e-6)


@pytest.mark.parametrize("name, depth", [("furnace_glass", 5), ("furnace_glass", 1), ("furnace_lambertian", 1),
                                         ("furnace_mirror", 1)])
def test_white_furnace_with_roulette_is_exact_within_noise(name, depth):
    """Where roulette does end paths (inside the glass; from depth 1 on every
    kind), the survival cap of 0.95 makes single samples 0 or 1/q: the image
    must still average 1 within its noise."""
    scene = load_scene(SCENES / f"{name}.yaml").with_overrides(samples_per_pixel=64)
    scene = scene.replace(render=dataclasses.replace(scene.render, russian_roulette={"depth": depth}))
    image = render(scene, workers=1)[..., 0].astype(np.float64)
    # pixels are independent: the image mean's standard error is their spread / sqrt(count)
    error = image.std(ddof=1) / np.sqrt(image.size)
    assert abs(image.mean() - 1.0) < 5 * error + 1e-6, (image.mean(), error)
    assert image.min() >= 0 and image.max() <= 1 / 0.95 ** 64  # no sample beyond 64 survivals
    if depth == 1:
        assert image.std() > 0  # roulette really ran: samples are no longer all exactly 1


def test_negative_control_biased_roulette_fails_the_furnace(monkeypatch):
    """Roulette that forgets to divide by the survival probability darkens the furnace."""
    import wavefront.path

    def biased(sampler, live, absorbed, start_depth, drawn=None):  # draws its own uniforms: the same numbers
        rows = np.flatnonzero(~absorbed & (live.depth + 1 >= start_depth))
        u = sampler.pairs(live.state.take(rows), wavefront.path.light_choice_dimension(live.depth.take(rows)))[1]
        absorbed[rows[u >= 0.95]] = True
        return absorbed

    monkeypatch.setattr(wavefront.path, "russian_roulette", biased)
    scene = load_scene(SCENES / "furnace_lambertian.yaml").with_overrides(samples_per_pixel=64)
    scene = scene.replace(render=dataclasses.replace(scene.render, russian_roulette={"depth": 1}))
    image = render(scene, workers=1)[..., 0]
    assert image.mean() < 0.97


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

"""Next-event estimation with MIS and Russian roulette in the path integrator.

The estimator changes, the picture must not: images with light sampling and
roulette on are compared with the book estimator (both off, independent
numbers) by a per-pixel
z-test with a Bonferroni correction (as ``test_reference.py``), on the
Cornell box, a scene lit by a small sphere lamp and a glass ball under a quad
light; a deliberately wrong MIS weight must be rejected by the same test.
With both off (and ``sampler: independent``) the image is the book estimator's bit for bit; with them on it
is still independent of chunk size and worker count.
"""

import dataclasses
import functools
from pathlib import Path

import numpy as np
import pytest
from scipy import stats

import wavefront.path
from wavefront import (Camera, Dielectric, Emissive, Lambertian, Metal, Quad, RenderSettings, Scene, SceneError,
                       Solid, Sphere, load_scene, render)
from wavefront.scenefile import scene_from_dict

from .test_render import assert_same_on_two_workers

SCENES = Path(__file__).resolve().parent.parent / "scenes"
DATA = Path(__file__).resolve().parent / "data"


def with_settings(scene, **settings):
    return scene.replace(render=dataclasses.replace(scene.render, **settings))


def book(scene):
    """The book's estimator: no light sampling, no roulette, independent
    numbers.  (With the default sobol sampler its rare hits of a small lamp
    are stratified too, and then 16 renders of a block can all miss the lamp
    at once, which this test's across-render variance cannot see: seeds
    100-115 do so on sphere_lamp's far floor.  The light-sampling side keeps
    the default sampler, so the comparison also crosses samplers.)"""
    return with_settings(scene, light_sampling=False, russian_roulette=False, sampler="independent")


# The test compares blocks of BLOCK x BLOCK pixels (their mean is as
# unbiased as a pixel's).  The book estimator finds a small light by rare
# hits: per pixel, a render of a few hundred samples often sees none, and its
# variance estimate then claims a certainty it does not have (measured: the
# far floor of the glass scene is exactly 0 in 512 samples, 0.009 with light
# sampling).  A block pools 16 pixels' samples, enough hits for its variance.
BLOCK = 4


def estimate(scene, splits, seed, samples_per_pixel=32):
    """Mean block image over ``splits`` renders with unrelated seeds, and the variance of that mean."""
    scene = scene.with_overrides(samples_per_pixel=samples_per_pixel)
    images = np.stack([render(scene.with_overrides(seed=seed + k), workers=1) for k in range(splits)])
    k, h, w, c = images.shape
    blocks = images[:, :h - h % BLOCK, :w - w % BLOCK].reshape(k, h // BLOCK, BLOCK, w // BLOCK, BLOCK, c)
    blocks = blocks.mean(axis=(2, 4), dtype=np.float64)
    return blocks.mean(axis=0), blocks.var(axis=0, ddof=1) / splits


def rejected(a, b, alpha=1e-3):
    """Per-pixel two-sample z-test, Bonferroni-corrected over every value."""
    (m1, v1), (m2, v2) = a, b
    z = (m1 - m2) / np.sqrt(v1 + v2 + 1e-12)
    critical = stats.norm.isf(alpha / (2 * z.size))
    return np.abs(z).max() > critical, np.abs(z).max()


def cornell():
    return load_scene(SCENES / "cornell_box.yaml").with_overrides(width=16, height=16, samples_per_pixel=32)


def sphere_lamp():
    """A small sphere lamp over a floor with a coloured ball and a fuzzy metal
    ball.  The camera looks down on the floor: at a grazing far floor the book
    estimator meets the lamp too rarely for its own variance estimate to hold."""
    materials = {"floor": Lambertian((0.6, 0.6, 0.6)), "ball": Lambertian((0.7, 0.3, 0.2)),
                 "metal": Metal((0.8, 0.8, 0.8), 0.3), "lamp": Emissive((20, 20, 20))}
    spheres = [Sphere((-0.6, 0.5, 0), 0.5, "ball"), Sphere((0.6, 0.5, 0.1), 0.5, "metal"),
               Sphere((0.2, 1.6, 0.6), 0.3, "lamp")]
    return Scene(spheres=spheres, quads=[Quad((-2, 0, 2), (4, 0, 0), (0, 0, -4), "floor")], materials=materials,
                 camera=Camera(look_from=(0, 3.5, 3.5), look_at=(0, 0.3, 0), vfov=50),
                 background=Solid((0.05, 0.05, 0.06)), width=24, height=16,
                 render=RenderSettings(samples_per_pixel=32, max_depth=10))


def glass_under_quad_light():
    """A glass ball on a floor under a quad light facing down: its caustic is
    found only through the glass (a delta), so those emission hits count in full."""
    materials = {"floor": Lambertian((0.7, 0.7, 0.7)), "glass": Dielectric(1.5), "lamp": Emissive((8, 8, 8))}
    quads = [Quad((-3, 0, 3), (6, 0, 0), (0, 0, -6), "floor"),
             Quad((-0.5, 2.0, 0.5), (0, 0, -1), (1, 0, 0), "lamp")]  # cross(u, v) = -y: shines down
    return Scene(spheres=[Sphere((0, 0.5, 0), 0.5, "glass")], quads=quads, materials=materials,
                 camera=Camera(look_from=(0, 2.0, 3.5), look_at=(0, 0.4, 0), vfov=45), background=Solid((0, 0, 0)),
                 width=24, height=16, render=RenderSettings(samples_per_pixel=32, max_depth=10))


SCENE_BUILDERS = {"cornell_box": cornell, "sphere_lamp": sphere_lamp, "glass_under_quad_light": glass_under_quad_light}
# The book estimator is far noisier, and its rare light hits must be seen
# often enough for its variance estimate to hold: it gets 32x the samples.
BOOK_SPLITS, BOOK_SPP, NEE_SPLITS = 16, 256, 8


@functools.cache
def book_estimate(name):
    return estimate(book(SCENE_BUILDERS[name]()), BOOK_SPLITS, seed=100, samples_per_pixel=BOOK_SPP)


@pytest.fixture(scope="module", params=sorted(SCENE_BUILDERS))
def scene_and_book(request):
    return SCENE_BUILDERS[request.param](), book_estimate(request.param)


def test_light_sampling_and_roulette_keep_the_expectation(scene_and_book):
    scene, book_estimate = scene_and_book
    assert scene.render.light_sampling and scene.render.russian_roulette is not None  # the defaults
    bad, worst = rejected(estimate(scene, NEE_SPLITS, seed=500), book_estimate)
    assert not bad, f"largest |z| = {worst:.2f}"


def test_light_sampling_alone_keeps_the_expectation(scene_and_book):
    scene, book_estimate = scene_and_book
    bad, worst = rejected(estimate(with_settings(scene, russian_roulette=False), NEE_SPLITS, seed=700),
                          book_estimate)
    assert not bad, f"largest |z| = {worst:.2f}"


def test_negative_control_mis_weights_not_summing_to_one_are_rejected(scene_and_book, monkeypatch):
    """Both strategies at full weight count direct light twice."""
    scene, book_estimate = scene_and_book
    monkeypatch.setattr(wavefront.path, "mis_weight", lambda pdf_a, pdf_b: np.where(pdf_a > 0, 1.0, 0.0))
    bad, worst = rejected(estimate(scene, NEE_SPLITS, seed=500), book_estimate)
    assert bad, f"largest |z| = {worst:.2f}"


def test_roulette_alone_keeps_the_expectation():
    scene = with_settings(cornell(), light_sampling=False, russian_roulette={"depth": 1})
    bad, worst = rejected(estimate(scene, BOOK_SPLITS, seed=900, samples_per_pixel=BOOK_SPP // 4),
                          book_estimate("cornell_box"))
    assert not bad, f"largest |z| = {worst:.2f}"


def test_light_sampling_is_far_less_noisy_on_the_cornell_box():
    """Not a benchmark (no time involved): per-pixel variance at equal sample
    counts over the pixels that do not see the lamp (measured at 16x16, 32 spp:
    about 100x lower)."""
    scene = cornell()
    book_images = np.stack([render(book(scene).with_overrides(seed=100 + k), workers=1) for k in range(8)])
    nee_images = np.stack([render(scene.with_overrides(seed=500 + k), workers=1) for k in range(8)])
    walls = (book_images.mean(axis=0).max(axis=-1) < 1.0) & (nee_images.mean(axis=0).max(axis=-1) < 1.0)
    assert walls.sum() > 200
    assert nee_images.var(axis=0)[walls].mean() * 5 < book_images.var(axis=0)[walls].mean()


# -- the book estimator, bit for bit; determinism with both on --------------------

def test_both_off_is_the_book_estimator_bit_for_bit():
    """Images the integrator made before light sampling and roulette existed
    (tests/data/make_book_estimator.py, at a809293)."""
    stored = np.load(DATA / "book_estimator.npz")
    cb = load_scene(SCENES / "cornell_box.yaml").with_overrides(width=16, height=16, samples_per_pixel=4, max_depth=12)
    ts = load_scene(SCENES / "three_spheres.yaml").with_overrides(width=16, height=9, samples_per_pixel=4)
    np.testing.assert_array_equal(render(book(cb), workers=1), stored["cornell_box"])
    np.testing.assert_array_equal(render(book(ts), workers=1), stored["three_spheres"])
    # and the settings matter: the default (both on) is a different estimator
    assert not np.array_equal(render(cb, workers=1), stored["cornell_box"])


@pytest.fixture(scope="module")
def lamp_scene():
    """Spheres only, so the render runs in float32 (where a field whose type
    changed with a batch's refill history once made one pixel depend on the
    chunk size)."""
    scene = load_scene(SCENES / "slow_room.yaml").replace(width=37, height=23).with_overrides(samples_per_pixel=6)
    assert scene.compile().dtype == np.float32
    return scene


@pytest.fixture(scope="module")
def lamp_image(lamp_scene):
    return render(lamp_scene, workers=1)


@pytest.mark.parametrize("chunk_size", [97, 1000, 65536])
def test_light_sampling_image_does_not_depend_on_chunk_size(lamp_scene, lamp_image, chunk_size):
    np.testing.assert_array_equal(render(lamp_scene, workers=1, chunk_size=chunk_size), lamp_image)


def test_light_sampling_image_does_not_depend_on_worker_count(lamp_scene, lamp_image):
    assert_same_on_two_workers(lamp_scene, lamp_image, chunk_size=300)


def test_cornell_box_bvh_scene_is_deterministic_with_light_sampling():
    scene = cornell().with_overrides(samples_per_pixel=3)
    np.testing.assert_array_equal(render(scene, workers=1, chunk_size=211), render(scene, workers=1))


# -- the settings ---------------------------------------------------------------

def scene_doc(render_settings):
    return {"render": render_settings, "materials": {"m": {"type": "lambertian"}},
            "spheres": [{"center": [0, 0, -1], "radius": 0.5, "material": "m"}]}


def test_settings_default_to_light_sampling_and_roulette_from_depth_5():
    settings = scene_from_dict(scene_doc({})).render
    assert settings.light_sampling is True and settings.russian_roulette.depth == 5


def test_settings_from_yaml():
    settings = scene_from_dict(scene_doc({"light_sampling": False, "russian_roulette": {"depth": 3}})).render
    assert settings.light_sampling is False and settings.russian_roulette.depth == 3
    assert scene_from_dict(scene_doc({"russian_roulette": False})).render.russian_roulette is None
    assert scene_from_dict(scene_doc({"russian_roulette": True})).render.russian_roulette.depth == 5


@pytest.mark.parametrize("value, path, words", [
    ({"light_sampling": "yes"}, "render.light_sampling", "expected true or false"),
    ({"light_sampling": 1}, "render.light_sampling", "expected true or false"),
    ({"russian_roulette": {"depth": 0}}, "render.russian_roulette.depth", "must be >= 1"),
    ({"russian_roulette": {"depth": 2.5}}, "render.russian_roulette.depth", "expected an integer"),
    ({"russian_roulette": {"start": 5}}, "render.russian_roulette.start", "unknown key"),
    ({"russian_roulette": 5}, "render.russian_roulette", "expected false, true or a mapping"),
    ({"russian_roulette": None}, "render.russian_roulette", "got an empty value"),  # not silently off
])
def test_bad_settings_name_their_yaml_path(value, path, words):
    with pytest.raises(SceneError) as e:
        scene_from_dict(scene_doc(value), source="s.yaml")
    assert e.value.path == path and words in e.value.problem, str(e.value)


def test_settings_survive_overrides():
    scene = with_settings(cornell(), light_sampling=False, russian_roulette=False).with_overrides(seed=3)
    assert scene.render.light_sampling is False and scene.render.russian_roulette is None


def test_a_black_emitter_beside_a_lit_one_adds_nothing_and_breaks_nothing():
    """A zero-power emitter is left out of the table; paths that hit it must
    neither look it up (its index is -1) nor turn its zero into NaN."""
    scene = sphere_lamp()
    materials = dict(scene.materials, dark=Emissive((0, 0, 0)))
    dark = scene.replace(materials=materials, spheres=[*scene.spheres, Sphere((-0.8, 1.2, 0.8), 0.3, "dark")])
    image = render(dark.with_overrides(samples_per_pixel=8), workers=1)
    assert np.isfinite(image).all()
    assert len(dark.compile().emitters) == 1

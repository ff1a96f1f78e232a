"""Motion blur (RTOW book 2, section 2): spheres with ``center1``, rays with a time."""

import subprocess
import sys

import numpy as np
import pytest

from wavefront import Camera, Lambertian, Scene, Sphere, render
from wavefront.background import Solid
from wavefront.bvh import BVH
from wavefront.materials import Emissive
from wavefront.shapes import Primitives, SphereSet
from wavefront.validation import SceneError

from .test_furnace import SCENES


def two_balls(center1=None, other_center1=None, **render_options):
    """A still ball (the one under test) and a second ball that may move."""
    spheres = [Sphere((0, 0, -1), 0.5, "ball", center1=center1),
               Sphere((1.2, 0, -1.5), 0.4, "ball", center1=other_center1),
               Sphere((0, -100.5, -1), 100, "ground")]
    return Scene(spheres=spheres, materials={"ball": Lambertian((0.7, 0.3, 0.2)), "ground": Lambertian((0.5, 0.5, 0.5))},
                 camera=Camera(look_from=(0, 0.3, 1), look_at=(0, 0, -1)), width=40, height=24,
                 **render_options).with_overrides(samples_per_pixel=8)


def test_center1_equal_to_center_is_bit_identical_to_a_still_sphere():
    still = render(two_balls(), workers=1)
    np.testing.assert_array_equal(render(two_balls(center1=(0, 0, -1)), workers=1), still)


def test_center1_equal_to_center_is_bit_identical_among_moving_spheres():
    """With another sphere moving, every ray carries a time and every sphere is
    placed at ``center + t velocity``: a zero velocity must leave its answers unchanged."""
    moving = dict(other_center1=(1.2, 0.5, -1.5))
    reference = render(two_balls(**moving), workers=1)
    np.testing.assert_array_equal(render(two_balls(center1=(0, 0, -1), **moving), workers=1), reference)
    assert not np.array_equal(reference, render(two_balls(), workers=1))  # the other sphere does blur


def test_float32_moving_scene_is_the_same_with_chunks_and_workers():
    from wavefront import render_scene

    scene = two_balls(other_center1=(1.2, 0.5, -1.5)).replace(spheres=[
        Sphere((0, 0, -1), 0.5, "ball", center1=(0.2, 0.1, -1)), Sphere((1.2, 0, -1.5), 0.4, "ball"),
        Sphere((0, -100.5, -1), 100, "ground")])
    a = render(scene, workers=1)
    b = render_scene(scene, workers=2, chunk_size=333, memory=4 << 30).image
    np.testing.assert_array_equal(a, b)


def random_spheres(rng, n, moving_fraction=0.5, dtype=np.float64):
    center = rng.uniform(-5, 5, (3, n))
    radius = rng.uniform(0.05, 0.6, n)
    velocity = rng.uniform(-1, 1, (3, n)) * (rng.random(n) < moving_fraction)
    return SphereSet(center, radius, np.zeros(n, np.int32), dtype, velocity)


@pytest.mark.parametrize("seed, dtype", [(0, np.float64), (1, np.float64), (2, np.float32), (3, np.float32)])
def test_bvh_and_brute_force_agree_bit_for_bit_on_moving_spheres(seed, dtype):
    rng = np.random.default_rng(seed)
    primitives = Primitives([random_spheres(rng, 300, dtype=dtype)], dtype)
    bvh = BVH(primitives, 20.0)
    n = 4000
    origin = rng.uniform(-8, 8, (3, n)).astype(dtype)
    direction = rng.normal(size=(3, n))
    direction = (direction / np.linalg.norm(direction, axis=0)).astype(dtype)
    time = rng.random(n)
    brute, tree = primitives.intersect(origin, direction, time=time), bvh.intersect(origin, direction, time=time)
    np.testing.assert_array_equal(brute.primitive_idx, tree.primitive_idx)
    np.testing.assert_array_equal(brute.t, tree.t)
    assert (brute.primitive_idx >= 0).mean() > 0.1
    t_max = rng.uniform(0.5, 10, n).astype(dtype)
    np.testing.assert_array_equal(primitives.occluded(origin, direction, t_max, time),
                                  bvh.occluded(origin, direction, t_max, time))
    # the time matters: at time 0 other spheres are hit
    still = primitives.intersect(origin, direction, time=np.zeros(n))
    assert not np.array_equal(still.primitive_idx, brute.primitive_idx)


def test_bvh_bounds_hold_a_moving_sphere_over_the_interval():
    spheres = SphereSet(np.array([[0.0], [0.0], [0.0]]), np.array([1.0]), np.zeros(1, np.int32),
                        velocity=np.array([[3.0], [-2.0], [0.0]]))
    lo, hi = spheres.bounds()
    np.testing.assert_array_equal(lo[:, 0], [-1, -3, -1])
    np.testing.assert_array_equal(hi[:, 0], [4, 1, 1])
    center, radius = spheres.bounding_sphere()
    for t in np.linspace(0, 1, 11):  # the sphere at every time lies inside the bounding sphere
        c = np.array([3.0, -2.0, 0.0]) * t
        assert np.linalg.norm(c - center[:, 0]) + 1.0 <= radius[0] + 1e-12


def test_transform_moves_both_centres():
    sphere = Sphere((0, 0, 0), 1, "m", transform=[{"scale": 2}, {"translate": [1, 2, 3]}], center1=(0, 1, 0))
    spheres = SphereSet.build([sphere], [0], np.float64)
    np.testing.assert_allclose(spheres.center[:, 0], [1, 2, 3])
    np.testing.assert_allclose(spheres.velocity[:, 0], [0, 2, 0])
    assert spheres.radius[0] == 2


def test_center1_must_be_finite():
    with pytest.raises(SceneError) as e:
        Sphere((0, 0, 0), 1, "m", center1=(0, float("nan"), 0))
    assert e.value.path == "center1[1]"


# -- the blurred image is the time average of still ones ------------------------

START, END = np.array([-0.35, 0.0, -1.0]), np.array([0.3, 0.15, -1.0])


def coverage_scene(center, center1=None, spp=64, seed=1):
    """A grey ball on a white background seen once: a pixel's sample is 0.5 (ball:
    the one bounce escapes, albedo 0.5) or 1 (background), so a pixel's mean is
    ``1 - coverage / 2`` with Bernoulli noise of known variance."""
    scene = Scene(spheres=[Sphere(tuple(center), 0.25, "grey", center1=None if center1 is None else tuple(center1))],
                  materials={"grey": Lambertian((0.5, 0.5, 0.5))}, background=Solid((1, 1, 1)),
                  camera=Camera(look_from=(0, 0, 0), look_at=(0, 0, -1), vfov=60), width=24, height=16)
    from wavefront.scene import RenderSettings

    return scene.replace(render=RenderSettings(samples_per_pixel=spp, max_depth=2, seed=seed, light_sampling=False,
                                               russian_roulette=False))


def time_average(times, spp):
    images = [render(coverage_scene(START + t * (END - START), spp=spp, seed=k + 1), workers=1).astype(np.float64)
              for k, t in enumerate(times)]
    mean = np.mean(images, axis=0)
    # variance of the average: each still image is a mean of spp Bernoulli(q_k) samples scaled by 1/2
    q = np.clip(2.0 * (1.0 - np.array(images)), 0.0, 1.0)
    variance = (0.25 * q * (1 - q) / spp).sum(axis=0) / len(images) ** 2
    return mean, variance


def z_scores(blurred, spp, reference, reference_variance):
    # the blurred image's Bernoulli variance from its own coverage estimate
    q = np.clip(2.0 * (1.0 - blurred), 0.0, 1.0)
    variance = 0.25 * q * (1 - q) / spp + reference_variance
    diff = blurred - reference
    exact = variance == 0
    z = np.zeros_like(diff)
    z[~exact] = diff[~exact] / np.sqrt(variance[~exact])
    z[exact & (diff != 0)] = np.inf  # a pixel the ball never touches (or always covers) must match exactly
    return z[..., 0]


@pytest.fixture(scope="module")
def reference():
    times = (np.arange(128) + 0.5) / 128  # the midpoint rule over the shutter interval
    return time_average(times, spp=64)


# Bonferroni over 384 pixels at a family-wise 1e-3: |z| < 4.6
Z_LIMIT = 4.6


def test_moving_sphere_is_the_time_average_of_still_ones(reference):
    mean, variance = reference
    spp = 1024
    blurred = render(coverage_scene(START, END, spp=spp), workers=1).astype(np.float64)
    z = z_scores(blurred, spp, mean, variance)
    assert np.abs(z).max() < Z_LIMIT, np.abs(z).max()
    assert (np.abs(blurred - 1.0) > 0.01).sum() > 30  # the ball covers a fair part of the image


@pytest.mark.parametrize("wrong", ["still at the midpoint", "half the shutter"])
def test_time_average_negative_controls_fail(reference, wrong):
    mean, variance = reference
    spp = 1024
    if wrong == "still at the midpoint":
        image = render(coverage_scene(0.5 * (START + END), spp=spp), workers=1)
    else:  # a sampler whose times cover only [0, 0.5): the ball moves half as far
        image = render(coverage_scene(START, 0.5 * (START + END), spp=spp), workers=1)
    z = z_scores(image.astype(np.float64), spp, mean, variance)
    assert np.abs(z).max() > 2 * Z_LIMIT


def test_moving_light_is_sampled_where_it_is():
    """A moving emissive sphere above a floor: light sampling (which must place
    the light at each path's time) and pure material sampling agree."""
    from wavefront.scene import RenderSettings

    scene = Scene(spheres=[Sphere((-0.6, 1.0, -1), 0.3, "lamp", center1=(0.6, 1.0, -1)),
                           Sphere((0, -1000, -1), 1000, "floor")],
                  materials={"lamp": Emissive((4, 4, 4)), "floor": Lambertian((0.6, 0.6, 0.6))},
                  background=Solid((0, 0, 0)), camera=Camera(look_from=(0, 1.5, 2), look_at=(0, 0, -1), vfov=50),
                  width=24, height=16)
    images = {}
    for nee in (True, False):
        scene = scene.replace(render=RenderSettings(samples_per_pixel=256, max_depth=3, seed=3, light_sampling=nee,
                                                    russian_roulette=False))
        images[nee] = render(scene, workers=1).astype(np.float64)
    floor = images[True][10:, :], images[False][10:, :]  # the lower rows see the lit floor only
    assert floor[0].mean() > 0.01
    # Distinct pixels are independent, so the sum of their differences over
    # the root of the sum of their squares is a standard normal z if the two
    # agree.  (A fixed 5 % of the mean was about one standard error of the
    # material-sampling image, which finds the small lamp by chance: 3 seeds
    # in 8 failed it, with either sampler.)
    d = (floor[0] - floor[1])[..., 0]  # grey: the channels are equal
    assert abs(d.sum() / np.sqrt((d**2).sum())) < 4.0
    # a light sampled where it is at time 0 only would light the floor's left half alone
    left, right = floor[0][:, :12].mean(), floor[0][:, 12:].mean()
    assert 0.7 < left / right < 1.4


def test_center1_nan_through_the_cli(tmp_path):
    scene = tmp_path / "moving.yaml"
    scene.write_text("materials: {m: {type: lambertian}}\n"
                     "spheres:\n  - {center: [0, 0, -1], center1: [0, .nan, -1], radius: 0.5, material: m}\n")
    out = tmp_path / "out.png"
    r = subprocess.run([sys.executable, "-m", "wavefront", "render", str(scene), "-o", str(out)],
                       capture_output=True, text=True, timeout=300)
    assert r.returncode == 2
    lines = r.stderr.strip().splitlines()
    assert len(lines) == 1 and str(scene) in lines[0] and "spheres[0].center1[1]" in lines[0], r.stderr
    assert not out.exists()


def test_bouncing_spheres_scene_loads_with_moving_spheres():
    from wavefront import load_scene

    scene = load_scene(SCENES / "bouncing_spheres.yaml")
    moving = [s for s in scene.spheres if s.center1 is not None]
    assert len(moving) > 100 and all(s.center1[1] >= s.center[1] for s in moving)
    cs = scene.with_overrides(width=8, height=6, samples_per_pixel=1).compile()
    assert cs.shapes.moving


# -- the time sample ---------------------------------------------------------

def joint_pvalue(a, b, bins=16):
    """Chi-square p-value that ``a`` and ``b`` are independent and uniform on [0, 1)^2."""
    from scipy import stats

    counts, _, _ = np.histogram2d(a, b, bins=bins, range=[[0, 1], [0, 1]])
    return stats.chisquare(counts.ravel()).pvalue


def test_time_is_uniform_and_independent_of_the_camera_and_bounce_numbers():
    from wavefront.sampling import TIME_PAIR, bounce_dimension, path_state, scene_key, uniform_pairs

    state = path_state(scene_key(7), np.arange(200_000, dtype=np.uint64))
    time = uniform_pairs(state, TIME_PAIR)[0]
    assert time.min() >= 0 and time.max() < 1
    for other in (uniform_pairs(state, 0)[0], uniform_pairs(state, 1)[1], uniform_pairs(state, bounce_dimension(0))[0]):
        assert joint_pvalue(time, other) > 1e-4
    # negative control: a "time" that reuses the pixel jitter's pair is perfectly dependent on it
    assert joint_pvalue(uniform_pairs(state, 0)[1], uniform_pairs(state, 0)[1]) < 1e-12

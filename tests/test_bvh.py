"""The BVH finds exactly the sphere brute force finds, for any scene and ray."""

import numpy as np
from hypothesis import given
from hypothesis import strategies as st

from wavefront.accel import BVH_THRESHOLD, build_intersector
from wavefront.bvh import SphereBVH
from wavefront.geometry import SphereSet, intersect_brute_force, precision_for
from wavefront.vecmath import normalize


def random_scene(rng, m, spread, dtype=np.float64, scale=1.0):
    center = rng.uniform(-spread, spread, (3, m)) * scale
    radius = rng.uniform(0.01, 1.0, m) * rng.choice([1, 1, 1, 20], m) * scale  # a few large ones
    if m > 1:
        center[:, 1] = center[:, 0]  # a duplicated sphere: ties go to the lower index
        radius[1] = radius[0]
    return SphereSet(center, radius, np.zeros(m, dtype=np.int32), dtype)


def assert_same_hits(spheres, origin, direction, t_max):
    brute = intersect_brute_force(spheres, origin, direction, t_max)
    extent = max(np.abs(origin).max(), (np.abs(spheres.center) + spheres.radius).max()) * np.sqrt(3)
    bvh = SphereBVH(spheres, extent).intersect(origin, direction, t_max)
    np.testing.assert_array_equal(bvh.sphere_idx, brute.sphere_idx)
    np.testing.assert_array_equal(bvh.t, brute.t)
    return brute


@given(st.integers(1, 300), st.integers(0, 2**32 - 1), st.floats(1.0, 50.0), st.sampled_from([np.inf, 5.0]))
def test_bvh_agrees_exactly_with_brute_force(m, seed, spread, t_max):
    rng = np.random.default_rng(seed)
    spheres = random_scene(rng, m, spread)
    n = 400
    origin = rng.uniform(-spread, spread, (3, n))
    direction = normalize(rng.normal(size=(3, n)))
    direction[:, :5] = np.eye(3)[:, [0, 1, 2, 2, 0]] * np.array([1, 1, -1, 1, -1])  # axis-aligned rays
    origin[:, -3:] = spheres.center[:, :1] + np.array([[0.0], [0.0], [1.0]]) * spheres.radius[0]  # start on a surface
    assert_same_hits(spheres, origin, direction, t_max)


@given(st.integers(1, 200), st.integers(0, 2**32 - 1), st.booleans(),
       st.sampled_from([1e-3, 1.0, 1e3]), st.sampled_from([1.0, 30.0, 1e4]))
def test_bvh_agrees_on_grazing_rays_from_far_away(m, seed, prefer_float32, scale, distance):
    """The float32 traversal is conservative at any scale and distance.

    Rays start up to 10^4 scene sizes away and aim at points on sphere
    surfaces, many of them silhouettes, where a box test that rounds the
    wrong way would lose the hit.  Scenes run in float32 where the renderer
    would choose it (:func:`precision_for`), else in float64.
    """
    rng = np.random.default_rng(seed)
    spheres = random_scene(rng, m, 10.0, np.float64, scale)
    extent = 10.0 * scale * max(distance, 4.0)
    if prefer_float32 and precision_for(spheres.radius, extent) == np.float32:
        spheres = random_scene(np.random.default_rng(seed), m, 10.0, np.float32, scale)
    dtype = spheres.dtype
    n = 300
    target_sphere = rng.integers(0, m, n)
    on_surface = spheres.center.astype(np.float64)[:, target_sphere] + \
        normalize(rng.normal(size=(3, n))) * spheres.radius.astype(np.float64)[target_sphere]
    origin = normalize(rng.normal(size=(3, n))) * 10.0 * scale * distance
    direction = normalize(on_surface - origin)
    # a third of the rays run exactly along an axis through a target point
    axis = rng.integers(0, 3, n // 3)
    direction[:, : n // 3] = 0.0
    direction[axis, np.arange(n // 3)] = rng.choice([-1.0, 1.0], n // 3)
    origin[:, : n // 3] = on_surface[:, : n // 3] - direction[:, : n // 3] * 10.0 * scale * distance
    origin, direction = origin.astype(dtype), direction.astype(dtype)
    brute = assert_same_hits(spheres, origin, direction, np.inf)
    assert (brute.sphere_idx >= 0).mean() > 0.3  # the rays do find spheres


def test_bvh_with_a_ground_far_below_tiny_spheres():
    """Outsized spheres are tested outside the tree; rays start on the ground far from the tree."""
    rng = np.random.default_rng(3)
    m = 300
    center = np.vstack((rng.uniform(-5, 5, m), np.full(m, 0.2), rng.uniform(-5, 5, m)))
    radius = np.full(m, 0.2)
    center[:, 0], radius[0] = (0.0, -1000.0, 0.0), 1000.0
    spheres = SphereSet(center, radius, np.zeros(m, dtype=np.int32))
    n = 2000
    origin = np.vstack((rng.uniform(-60, 60, n), np.zeros(n), rng.uniform(-60, 60, n)))
    origin[1] = np.sqrt(1000.0**2 - origin[0] ** 2 - origin[2] ** 2) - 1000.0  # on the ground
    target = center[:, rng.integers(1, m, n)] + rng.normal(0, 0.2, (3, n))
    direction = normalize(target - origin)
    brute = assert_same_hits(spheres, origin, direction, np.inf)
    assert (brute.sphere_idx > 0).sum() > 100  # rays reach the small spheres
    assert (brute.sphere_idx == 0).sum() > 10  # and some hit the ground first


def test_switch_is_automatic():
    rng = np.random.default_rng(0)
    assert isinstance(build_intersector(random_scene(rng, BVH_THRESHOLD, 10)), SphereBVH)
    assert isinstance(build_intersector(random_scene(rng, BVH_THRESHOLD - 1, 10)), SphereSet)

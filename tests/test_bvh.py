"""The BVH finds exactly the sphere brute force finds, for any scene and ray."""

import numpy as np
from hypothesis import given
from hypothesis import strategies as st

from wavefront.accel import BVH_THRESHOLD, build_intersector
from wavefront.bvh import SphereBVH
from wavefront.geometry import SphereSet, intersect_brute_force
from wavefront.vecmath import normalize


def random_scene(rng, m, spread):
    center = rng.uniform(-spread, spread, (3, m))
    radius = rng.uniform(0.01, 1.0, m) * rng.choice([1, 1, 1, 20], m)  # a few large ones
    if m > 1:
        center[:, 1] = center[:, 0]  # a duplicated sphere: ties go to the lower index
        radius[1] = radius[0]
    return SphereSet(center, radius, np.zeros(m, dtype=np.int32))


@given(st.integers(1, 300), st.integers(0, 2**32 - 1), st.floats(1.0, 50.0), st.sampled_from([np.inf, 5.0]))
def test_bvh_agrees_exactly_with_brute_force(m, seed, spread, t_max):
    rng = np.random.default_rng(seed)
    spheres = random_scene(rng, m, spread)
    n = 400
    origin = rng.uniform(-spread, spread, (3, n))
    direction = normalize(rng.normal(size=(3, n)))
    direction[:, :5] = np.eye(3)[:, [0, 1, 2, 2, 0]] * np.array([1, 1, -1, 1, -1])  # axis-aligned rays
    origin[:, -3:] = spheres.center[:, :1] + np.array([[0.0], [0.0], [1.0]]) * spheres.radius[0]  # start on a surface
    brute = intersect_brute_force(spheres, origin, direction, t_max)
    bvh = SphereBVH(spheres).intersect(origin, direction, t_max)
    np.testing.assert_array_equal(bvh.sphere_idx, brute.sphere_idx)
    np.testing.assert_array_equal(bvh.t, brute.t)


def test_switch_is_automatic():
    rng = np.random.default_rng(0)
    assert isinstance(build_intersector(random_scene(rng, BVH_THRESHOLD, 10)), SphereBVH)
    assert isinstance(build_intersector(random_scene(rng, BVH_THRESHOLD - 1, 10)), SphereSet)

"""Chi-square tests of every sampler, each with a wrong sampler it must reject.

Samplers take their uniforms as arguments, so each test feeds them numbers
from the project's own hash (what renders use) and checks the distribution of
what comes out against its exact law.
"""

import numpy as np
import pytest
from scipy import stats

from wavefront.materials import scatter_lambertian
from wavefront.sampling import mix64, path_state, random_in_unit_disk, random_unit_vector, scene_key, uniform_pairs
from wavefront.vecmath import normalize

N = 200_000
ACCEPT = 1e-3  # a correct sampler fails with probability 0.1 % (fixed seeds: never, in practice)
REJECT = 1e-9  # a wrong sampler must be rejected overwhelmingly


def project_uniforms(count, n=N, seed=7):
    """``count`` streams of uniforms exactly as renders draw them (in pairs)."""
    state = path_state(scene_key(seed), np.arange(n, dtype=np.uint64))
    return list(np.concatenate([uniform_pairs(state, p) for p in range((count + 1) // 2)]))[:count]


def chi2_pvalue(counts, expected=None):
    counts = np.asarray(counts, dtype=np.float64).ravel()
    expected = np.full_like(counts, counts.sum() / counts.size) if expected is None else expected.ravel()
    return stats.chisquare(counts, expected).pvalue


def sphere_histogram(d, z_bins=10, phi_bins=12):
    """Equal-area bins on the sphere: z is uniform for a uniform direction."""
    z = np.clip(d[2], -1, 1 - 1e-12)
    phi = np.arctan2(d[1], d[0]) % (2 * np.pi)
    h, _, _ = np.histogram2d(z, phi, bins=(z_bins, phi_bins), range=((-1, 1), (0, 2 * np.pi)))
    return h


def test_project_uniforms_are_uniform():
    u = project_uniforms(1, n=N)[0]
    assert u.min() >= 0 and u.max() < 1
    assert chi2_pvalue(np.histogram(u, bins=100, range=(0, 1))[0]) > ACCEPT


def pair_histogram(a, b, bins=20):
    return np.histogram2d(a, b, bins=bins, range=((0, 1), (0, 1)))[0]


def test_project_uniforms_are_independent_across_dimensions_and_samples():
    u0, u1, u2 = project_uniforms(3)
    assert chi2_pvalue(pair_histogram(u0, u1)) > ACCEPT  # the two halves of one hash
    assert chi2_pvalue(pair_histogram(u0, u2)) > ACCEPT  # two hashes of one path
    assert chi2_pvalue(pair_histogram(u0[:-1], u0[1:])) > ACCEPT  # neighbouring paths
    other = project_uniforms(1, seed=8)[0]
    assert chi2_pvalue(pair_histogram(u0, other)) > ACCEPT  # neighbouring seeds


def test_negative_control_unmixed_counter_is_rejected():
    """A Weyl sequence without the mixing step is uniform but correlated."""
    ids = np.arange(N, dtype=np.uint64)
    weak = ((ids * np.uint64(0x9E3779B97F4A7C15)) >> np.uint64(11)).astype(np.float64) * 2.0**-53
    assert chi2_pvalue(np.histogram(weak, bins=100, range=(0, 1))[0]) > ACCEPT  # 1-D looks fine...
    assert chi2_pvalue(pair_histogram(weak[:-1], weak[1:])) < REJECT  # ...pairs do not


def test_mix64_is_a_bijection_on_a_sample():
    x = np.arange(1 << 16, dtype=np.uint64)
    assert np.unique(mix64(x)).size == x.size


def test_random_unit_vector_is_uniform_on_the_sphere():
    u0, u1 = project_uniforms(2)
    d = random_unit_vector(u0, u1)
    np.testing.assert_allclose(np.linalg.norm(d, axis=0), 1.0, rtol=1e-12)
    assert chi2_pvalue(sphere_histogram(d)) > ACCEPT


def test_negative_control_normalised_cube_is_rejected():
    u = project_uniforms(3)
    cube = normalize(np.stack([2 * x - 1 for x in u]))  # piles up towards the corners
    assert chi2_pvalue(sphere_histogram(cube)) < REJECT


def cosine_histogram(d, bins=10, phi_bins=8):
    """For density cos(theta)/pi, cos^2(theta) is uniform on [0, 1]."""
    c2 = np.clip(d[2], 0, 1) ** 2
    phi = np.arctan2(d[1], d[0]) % (2 * np.pi)
    return np.histogram2d(c2, phi, bins=(bins, phi_bins), range=((0, 1), (0, 2 * np.pi)))[0]


def lambertian_directions(u0, u1):
    n = np.zeros((3, u0.size))
    n[2] = 1.0
    _, d, absorbed = scatter_lambertian(n * -1, n, np.ones(u0.size, bool), np.ones((3, 1)), np.stack((u0, u1)))
    assert not absorbed.any()
    return d


def test_lambertian_directions_are_cosine_distributed():
    d = lambertian_directions(*project_uniforms(2))
    assert (d[2] >= 0).all()
    assert chi2_pvalue(cosine_histogram(d)) > ACCEPT


def test_negative_control_uniform_hemisphere_is_rejected():
    u0, u1 = project_uniforms(2)
    d = random_unit_vector(u0, u1)
    d[2] = np.abs(d[2])  # uniform over the hemisphere: the book's older, wrong "lambertian"
    assert chi2_pvalue(cosine_histogram(d)) < REJECT


def disk_histogram(p, bins=10, phi_bins=8):
    r2 = p[0] ** 2 + p[1] ** 2  # uniform on [0, 1) for a uniform point in the disk
    phi = np.arctan2(p[1], p[0]) % (2 * np.pi)
    return np.histogram2d(r2, phi, bins=(bins, phi_bins), range=((0, 1), (0, 2 * np.pi)))[0]


def test_random_in_unit_disk_is_uniform():
    p = random_in_unit_disk(*project_uniforms(2))
    assert (p[0] ** 2 + p[1] ** 2 < 1).all()
    assert chi2_pvalue(disk_histogram(p)) > ACCEPT


def test_negative_control_linear_radius_disk_is_rejected():
    u0, u1 = project_uniforms(2)
    p = np.stack((u0 * np.cos(2 * np.pi * u1), u0 * np.sin(2 * np.pi * u1)))  # r = u, crowds the centre
    assert chi2_pvalue(disk_histogram(p)) < REJECT


@pytest.mark.parametrize("seed", [0, 1, 2**63 - 1])
def test_scene_key_differs_between_seeds(seed):
    assert scene_key(seed) != scene_key(seed + 1 if seed < 2**63 - 1 else 0)

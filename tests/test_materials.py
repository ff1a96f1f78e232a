"""The scatter kernels follow the source documents row by row."""

import warnings

import numpy as np
from hypothesis import given
from hypothesis import strategies as st

from wavefront.materials import Metal, scatter_dielectric, scatter_lambertian, scatter_metal
from wavefront.sampling import random_unit_vector
from wavefront.scenefile import SceneWarning, scene_from_dict
from wavefront.vecmath import dot, normalize, reflect

unit_floats = st.floats(0.0, 1.0, exclude_max=True)


def random_hits(rng, n):
    """Unit incident directions and normals facing against them."""
    d = normalize(rng.normal(size=(3, n)))
    nrm = normalize(rng.normal(size=(3, n)))
    nrm = np.where(dot(d, nrm) < 0, nrm, -nrm)
    return d, nrm


def test_metal_with_zero_fuzz_is_an_exact_mirror():
    rng = np.random.default_rng(1)
    d, n = random_hits(rng, 1000)
    u = rng.random((2, 1000))
    att, out, absorbed = scatter_metal(d, n, np.ones(1000, bool), np.full((3, 1000), 0.9), np.zeros(1000), u)
    np.testing.assert_allclose(out, normalize(reflect(d, n)), atol=1e-12)
    assert not absorbed.any()
    np.testing.assert_array_equal(att, 0.9)


@given(st.sampled_from([0.0, -0.0]), st.sampled_from([np.float32, np.float64]), st.integers(0, 2**32 - 1))
def test_a_perfect_mirror_gives_the_jittered_formula_bit_for_bit(fuzz, dtype, seed):
    """scatter_metal with every fuzz zero skips the jitter (a signed zero)
    but where it changes a -0 component: bit for bit the formula's numbers,
    rays and normals with zero and -0 components included."""
    rng = np.random.default_rng(seed)
    d, n = random_hits(rng, 300)
    d[rng.integers(0, 3, 60), rng.integers(0, 300, 60)] = rng.choice([0.0, -0.0], 60)
    n[rng.integers(0, 3, 60), rng.integers(0, 300, 60)] = rng.choice([0.0, -0.0], 60)
    d[:, :4], n[:, :4] = [[-0.0, 0.0, 1.0, -1.0]] * 3, [[1.0, -0.0, 0.0, 0.0]] * 3
    d, n = d.astype(dtype), n.astype(dtype)
    u = rng.choice([0.0, 0.25, 0.5, 0.75, 0.3], (2, 300)).astype(dtype)
    f = np.full(300, fuzz, dtype=dtype)
    _, out, absorbed = scatter_metal(d, n, np.ones(300, bool), np.ones((3, 300), dtype), f, u)
    reflected = normalize(reflect(d, n))
    expected = f * random_unit_vector(u[0], u[1])
    expected += reflected
    np.testing.assert_array_equal(absorbed, dot(expected, n) <= 0)
    np.testing.assert_array_equal(np.signbit(out), np.signbit(normalize(expected)))
    np.testing.assert_array_equal(out, normalize(expected))


@given(st.floats(0.0, 1.0), st.integers(0, 2**32 - 1))
def test_metal_absorbs_exactly_the_rows_scattered_below_the_surface(fuzz, seed):
    rng = np.random.default_rng(seed)
    d, n = random_hits(rng, 500)
    u = rng.random((2, 500))
    _, out, absorbed = scatter_metal(d, n, np.ones(500, bool), np.ones((3, 500)), np.full(500, fuzz), u)
    expected = normalize(reflect(d, n)) + fuzz * random_unit_vector(u[0], u[1])
    np.testing.assert_array_equal(absorbed, dot(expected, n) <= 0)
    np.testing.assert_allclose(out, normalize(expected), atol=1e-12)


def test_metal_fuzz_is_clamped_to_one_with_a_warning():
    assert Metal(fuzz=3.0).fuzz == 1.0
    doc = {"materials": {"m": {"type": "metal", "fuzz": 2.5}},
           "spheres": [{"center": [0, 0, -1], "radius": 1, "material": "m"}]}
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        scene = scene_from_dict(doc)
    assert scene.materials["m"].fuzz == 1.0
    assert any(issubclass(w.category, SceneWarning) and "materials.m.fuzz" in str(w.message) for w in caught)


def test_lambertian_never_absorbs_and_falls_back_to_the_normal_when_degenerate():
    n = np.array([[0.0], [0.0], [1.0]])
    # u0 = 1 - tiny gives z = -1: random_unit_vector == -n, the sum vanishes
    _, out, absorbed = scatter_lambertian(-n, n, np.array([True]), np.ones((3, 1)), np.array([[1.0 - 1e-17], [0.0]]))
    np.testing.assert_allclose(out, n)
    assert not absorbed.any()


def test_dielectric_is_lossless_and_splits_by_schlick():
    n = 100_000
    d = np.tile(normalize(np.array([[1.0], [0.0], [-1.0]])), (1, n))  # 45 degrees incidence
    nrm = np.tile(np.array([[0.0], [0.0], [1.0]]), (1, n))
    u = np.random.default_rng(3).random((1, n))
    att, out, absorbed = scatter_dielectric(d, nrm, np.ones(n, bool), np.full(n, 1.5), u)
    np.testing.assert_array_equal(att, 1.0)
    assert not absorbed.any()
    reflected = out[2] > 0
    cos = np.cos(np.pi / 4)
    r0 = ((1 - 1 / 1.5) / (1 + 1 / 1.5)) ** 2
    expected = r0 + (1 - r0) * (1 - cos) ** 5
    p = reflected.mean()
    assert abs(p - expected) < 5 * np.sqrt(expected * (1 - expected) / n)


def test_lambertian_pdf_matches_its_sampler_and_eval_over_pdf_is_the_albedo():
    """The density MIS uses integrates to one over directions, equals the
    histogram of scatter_lambertian's directions, and eval / pdf is the albedo
    the kernel returns (so light and material sampling weigh the same BSDF)."""
    from scipy import stats

    from wavefront.materials import lambertian_eval, lambertian_pdf, scatter_lambertian
    from wavefront.sampling import path_state, random_unit_vector, scene_key, uniform_pairs

    n = 200_000
    state = path_state(scene_key(3), np.arange(n, dtype=np.uint64))
    u, v = uniform_pairs(state, 0), uniform_pairs(state, 1)
    normal = np.repeat(np.array([[0.6], [0.0], [0.8]]), n, axis=1)
    uniform = random_unit_vector(u[0], u[1])
    integral = 4 * np.pi * lambertian_pdf(normal, uniform)
    assert abs(integral.mean() - 1) < 5 * integral.std() / np.sqrt(n)
    albedo = np.repeat(np.array([[0.2], [0.5], [0.9]]), n, axis=1)
    _, d, _ = scatter_lambertian(-normal, normal, np.ones(n, bool), albedo, v)
    cos = (d * normal).sum(axis=0)
    # cos^2 is uniform on [0, 1] exactly when directions have density cos / pi
    assert stats.chisquare(np.histogram(cos**2, bins=50, range=(0, 1))[0]).pvalue > 1e-3
    assert stats.chisquare(np.histogram(cos, bins=50, range=(0, 1))[0]).pvalue < 1e-9  # a uniform-cos law fails
    np.testing.assert_allclose(lambertian_eval(albedo, normal, d) / lambertian_pdf(normal, d), albedo, rtol=1e-12)

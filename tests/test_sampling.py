"""Chi-square tests of every sampler, each with a wrong sampler it must reject.

Samplers take their uniforms as arguments, so each test feeds them numbers
from the project's own hash (what renders use) and checks the distribution of
what comes out against its exact law.

The sobol sampler (``render.sampler``'s default) gets exact tests of what
makes it low-discrepancy (a pixel's points of each pair are a (0, m, 2)-net;
the shuffle is a bijection; the unscrambled sequence is the textbook one) and
of what makes it unbiased (the scramble flips every bit by its own seed bit),
chi-square tests that its points are uniform and that two pairs of a path are
independent across pixels, a within-pixel test that each pair is shuffled on
its own (padding), each with a negative control, and render tests: furnaces
exact, sobol and independent images equal in expectation, a biased sampler
rejected.
"""

import dataclasses
import functools
from pathlib import Path

import numpy as np
import pytest
from hypothesis import given, strategies as st
from scipy import stats

from wavefront import (Camera, Emissive, Lambertian, Quad, RenderSettings, Scene, Solid, Sphere, load_scene,
                       render)
from wavefront.materials import scatter_lambertian
from wavefront.sampling import (LIGHT_PAIRS, MEDIUM_PAIRS, SAMPLERS, TIME_PAIR, Sampler, _hash32, _net_table,
                                _owen_mix, _reverse_bits_int, _sobol_dimension_1_columns, _to_unit, bounce_dimension,
                                cos_sin_2pi,
                                light_choice_dimension, light_point_dimension, mix64,
                                owen_premix, owen_scramble_reversed, pair_seeds, path_state, pixel_seeds,
                                random_in_unit_disk, random_unit_vector, reverse_bits, scene_key, shuffle_index,
                                sobol_points, sobol_reversed, uniform_pairs)
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


# -- the low-discrepancy sampler (render.sampler: sobol) ---------------------------------

# pairs from every block: camera, bounces, time, light, media
PAIRS = st.sampled_from([0, 1, 2, 3, 9, 52, TIME_PAIR, LIGHT_PAIRS, LIGHT_PAIRS + 1, LIGHT_PAIRS + 19,
                         MEDIUM_PAIRS, MEDIUM_PAIRS + 256 * 3 + 2]) | st.integers(0, (1 << 26) - 1)
SEEDS = st.integers(0, 2**63 - 1)
PIXELS = st.integers(0, (1 << 28) - 1)
DTYPES = st.sampled_from([np.float64, np.float32])


def pixel_points(sampler, pixel, pair, dtype=np.float64):
    """The ``(2, spp)`` uniforms of pair ``pair`` over every sample of one pixel."""
    spp = sampler.samples_per_pixel
    pixels = np.full(spp, pixel, dtype=np.int64)
    state = sampler.start(pixels, pixels.astype(np.uint64) * np.uint64(spp) + np.arange(spp, dtype=np.uint64))
    return sampler.pairs(state, pair, dtype).astype(np.float64)


def box_counts(u, m, a):
    """Points per elementary box of 2^a columns by 2^(m - a) rows (area 2^-m)."""
    x = np.floor(u[0] * (1 << a)).astype(np.int64)
    y = np.floor(u[1] * (1 << (m - a))).astype(np.int64)
    return np.bincount(x * (1 << (m - a)) + y, minlength=1 << m)


def is_02_net(u, m):
    """Every elementary box of area 2^-m, of every shape, holds exactly one of the 2^m points."""
    return all((box_counts(u, m, a) == 1).all() for a in range(m + 1))


@given(seed=SEEDS, pixel=PIXELS, pair=PAIRS, m=st.integers(0, 10), dtype=DTYPES)
def test_sobol_points_of_one_pixel_are_a_02_net(seed, pixel, pair, m, dtype):
    """With spp = 2^m, a pixel's points of any pair are a (0, m, 2)-net (exact)."""
    u = pixel_points(Sampler(scene_key(seed), 1 << m, "sobol"), pixel, pair, dtype)
    assert (u >= 0).all() and (u < 1).all()
    assert is_02_net(u, m)


def test_sobol_above_the_table_is_still_a_net():
    """Past 2^16 samples per pixel the points come from the byte tables instead of one lookup."""
    m = 17
    u = pixel_points(Sampler(scene_key(4), 1 << m, "sobol"), 12345, LIGHT_PAIRS + 1)
    assert is_02_net(u, m)


@given(seed=SEEDS, pixel=PIXELS, pair=PAIRS, spp=st.integers(3, 3000).filter(lambda n: n & (n - 1)))
def test_sobol_with_a_count_that_is_no_power_of_two_keeps_a_net(seed, pixel, pair, spp):
    """spp between 2^m and 2^(m+1): the nested shuffle sends the first 2^m
    samples onto an aligned block of the sequence (a net) and the rest onto
    distinct points of another, so every box of area 2^-m holds one or two."""
    u = pixel_points(Sampler(scene_key(seed), spp, "sobol"), pixel, pair)
    m = spp.bit_length() - 1
    assert np.unique(u[0]).size == spp and np.unique(u[1]).size == spp
    for a in range(m + 1):
        assert set(np.unique(box_counts(u, m, a))) <= {1, 2}


def test_negative_control_independent_points_are_no_net():
    sampler = Sampler(scene_key(1), 16, "independent")
    assert not any(is_02_net(pixel_points(sampler, pixel, 0), 4) for pixel in range(20))


def all_indices(index_bits):
    """Every sample index below ``2^index_bits``, as a sobol state's low word holds it."""
    return owen_premix(reverse_bits(np.arange(1 << index_bits, dtype=np.uint32)))


def multiplier_of(seed):
    return (seed >> np.uint32(16)) | np.uint32(1)


@given(index_bits=st.integers(0, 14), p=st.integers(0, 2**32 - 1))
def test_shuffle_is_a_bijection(index_bits, p):
    index = all_indices(index_bits)
    seed = np.full(index.size, p, dtype=np.uint32)
    j = shuffle_index(index, seed, multiplier_of(seed), index_bits)
    assert j.dtype == np.uint32 and np.array_equal(np.sort(j), np.arange(1 << index_bits))


def test_negative_control_low_bits_of_the_hash_are_no_bijection():
    """The scrambler's low output bits depend on the index's low (reversed:
    least significant) bits only; keeping them instead of the top ones maps
    the indices onto a few values."""
    index_bits = 6
    index = all_indices(index_bits)
    seed = np.full(index.size, 0x2545F491, dtype=np.uint32)
    wrong = _owen_mix(index + seed, multiplier_of(seed)) & np.uint32((1 << index_bits) - 1)
    assert np.unique(wrong).size < 1 << index_bits


@given(index_bits=st.integers(1, 10), p=st.integers(0, 2**32 - 1))
def test_shuffle_is_nested(index_bits, p):
    """Each unreversed index bit is flipped by a function of the bits above it
    only (Burley's nested shuffle): so every aligned block of indices maps
    onto an aligned block of points, which keeps the first 2^k of a count
    that is no power of two a net."""
    index = all_indices(index_bits)
    seed = np.full(index.size, p, dtype=np.uint32)
    shuffled = shuffle_index(index, seed, multiplier_of(seed), index_bits)  # bit-reversed
    j = (reverse_bits(shuffled) >> np.uint32(32 - index_bits)).astype(np.int64)
    i = np.arange(1 << index_bits)
    for size_bits in range(index_bits + 1):
        blocks = (j >> size_bits).reshape(-1, 1 << size_bits)  # the blocks of aligned indices...
        assert (blocks == blocks[:, :1]).all()  # ...land in one aligned block each
    assert np.array_equal(np.sort(j), i)


def test_shuffles_differ_between_seeds():
    index = all_indices(6)
    images = set()
    for p in range(50):
        seed = np.full(64, p * 0x9E3779B9 & 0xFFFFFFFF, dtype=np.uint32)
        images.add(tuple(shuffle_index(index, seed, multiplier_of(seed), 6)))
    assert len(images) == 50


@given(v=st.integers(0, 2**32 - 1), seed=st.integers(0, 2**32 - 1), multiplier=st.integers(0, 2**31 - 1),
       bit=st.integers(0, 31))
def test_scramble_flips_each_bit_by_its_own_seed_bit(v, seed, multiplier, bit):
    """Bit k of the scrambled (reversed) point is ``v_k ^ seed_k ^ f(bits
    below k)``: flipping seed bit k flips output bit k and no bit below it.
    So with a uniform seed independent of the point and the multiplier every
    bit of the result is exactly uniform, the top one first and each next one
    given those above: the point is exactly uniform on the 2^-32 grid."""
    def scramble(s):
        return int(owen_scramble_reversed(np.array([v], dtype=np.uint32), np.array([s], dtype=np.uint32),
                                          np.uint32(2 * multiplier + 1))[0])
    flipped = scramble(seed) ^ scramble(seed ^ (1 << bit))
    assert flipped & ((2 << bit) - 1) == 1 << bit


def test_negative_control_pbrts_multiplier_from_the_seed_is_not_exact():
    """pbrt's FastOwenScrambler multiplies by ``(seed >> 16) | 1``: seed bit k
    >= 16 then also changes the multiplier, and with it bits below k (why its
    points are not uniform past their top 16 bits)."""
    rng = np.random.default_rng(3)
    v, seed = rng.integers(0, 2**32, (2, 2000), dtype=np.uint64).astype(np.uint32)
    bit = 20
    flipped_seed = seed ^ np.uint32(1 << bit)
    a = owen_scramble_reversed(v.copy(), seed, multiplier_of(seed))
    b = owen_scramble_reversed(v.copy(), flipped_seed, multiplier_of(flipped_seed))
    assert ((a ^ b) & np.uint32((1 << bit) - 1)).any()


@given(x=st.lists(st.integers(0, 2**32 - 1), min_size=1, max_size=50))
def test_reverse_bits(x):
    v = np.array(x, dtype=np.uint32)
    assert reverse_bits(v).tolist() == [_reverse_bits_int(a) for a in x]


@pytest.mark.parametrize("shape", [(1,), (2, 512), (1025,), (2, 513), (3000,)])
def test_reverse_bits_byte_table_and_shifts_agree(shape):
    """Small arrays are reversed by a byte table, large ones by shifts: the
    two must give the same bits on each side of the switch (and on a
    non-contiguous view, which takes the shifts)."""
    v = np.random.default_rng(3).integers(0, 2**32, shape, dtype=np.uint32)
    expected = np.array([_reverse_bits_int(int(a)) for a in v.ravel()], dtype=np.uint32).reshape(shape)
    assert (reverse_bits(v.copy()) == expected).all()
    if v.ndim == 2:
        strided = v.copy().T  # not C-contiguous
        assert (reverse_bits(strided) == expected.T).all()


def test_unscrambled_sobol_points_are_the_textbook_ones():
    """Dimension 0 is van der Corput's sequence, dimension 1 Pascal's matrix
    mod 2 (pbrt-v4's SobolMatrices32 columns 0x80000000, 0xc0000000, 0xa0000000, 0xf0000000, ...)."""
    assert _sobol_dimension_1_columns()[:8] == [0x80000000, 0xC0000000, 0xA0000000, 0xF0000000,
                                                0x88000000, 0xCC000000, 0xAA000000, 0xFF000000]
    points = reverse_bits(sobol_reversed(np.arange(8, dtype=np.uint32))).astype(np.float64) * 2.0**-32
    np.testing.assert_array_equal(points[0], [0, 0.5, 0.25, 0.75, 0.125, 0.625, 0.375, 0.875])
    np.testing.assert_array_equal(points[1], [0, 0.5, 0.75, 0.25, 0.625, 0.125, 0.375, 0.875])
    # byte tables: an index with bits in every byte is the XOR of its columns
    j = 0x00A5_3C81
    expected = 0
    for bit in range(32):
        if j >> bit & 1:
            expected ^= _sobol_dimension_1_columns()[bit]
    assert sobol_reversed(np.array([j], dtype=np.uint32))[1, 0] == _reverse_bits_int(expected)


@pytest.mark.parametrize("index_bits", [0, 1, 3, 7])
def test_net_table_holds_the_premixed_reversed_points(index_bits):
    """Column r is point reverse(r) (in index_bits bits), reversed and premixed."""
    table = _net_table(index_bits)
    assert table.shape == (2, 1 << index_bits)
    for r in range(1 << index_bits):
        j = int(f"{r:0{index_bits}b}"[::-1], 2) if index_bits else 0
        expected = owen_premix(sobol_reversed(np.array([j], dtype=np.uint32)))[:, 0]
        np.testing.assert_array_equal(table[:, r], expected)


def test_unit_conversion_never_reaches_one_and_keeps_its_bits():
    top = np.full((2, 1), 0xFFFFFFFF, dtype=np.uint32)
    assert _to_unit(top.copy(), np.float64).max() == 1 - 2.0**-32
    assert _to_unit(top.copy(), np.float32).max() == np.float32(1 - 2.0**-24)
    # the low bits a float keeps are as uniform as the high ones: bits 17-24 in float32, 25-32 in float64
    for dtype, bits in ((np.float32, 24), (np.float64, 32)):
        v = one_sample_per_pixel(Sampler(scene_key(5), 16, "sobol"), 5, n=N, dtype=dtype)
        assert v.dtype == dtype
        low = (v.astype(np.float64) * 2.0**bits).astype(np.int64) & 255
        assert chi2_pvalue(np.bincount(low.ravel(), minlength=256)) > ACCEPT


def one_sample_per_pixel(sampler, pair, n=N, dtype=np.float64):
    """Pair ``pair`` of one sample (index ``pixel % spp``) of each of ``n``
    pixels: points of different pixels are independent, so chi-square applies."""
    pixel = np.arange(n, dtype=np.int64)
    sample_id = pixel.astype(np.uint64) * np.uint64(sampler.samples_per_pixel) + (
        pixel % sampler.samples_per_pixel).astype(np.uint64)
    return sampler.pairs(sampler.start(pixel, sample_id), pair, dtype)


@pytest.mark.parametrize("spp", [1, 16, 100])
@pytest.mark.parametrize("pair", [0, 5, LIGHT_PAIRS + 3])
def test_sobol_uniforms_are_uniform_over_pixels(spp, pair):
    u0, u1 = one_sample_per_pixel(Sampler(scene_key(7), spp, "sobol"), pair)
    assert u0.min() >= 0 and u1.max() < 1
    assert chi2_pvalue(np.histogram(u0, bins=100, range=(0, 1))[0]) > ACCEPT
    assert chi2_pvalue(np.histogram(u1, bins=100, range=(0, 1))[0]) > ACCEPT
    assert chi2_pvalue(pair_histogram(u0, u1)) > ACCEPT  # jointly uniform in the square


def test_negative_control_unscrambled_sobol_is_rejected():
    """The bare sequence (no scramble) puts sample 0 of every pixel at the origin."""
    spp, n = 16, N
    bare = reverse_bits(sobol_reversed((np.arange(n) % spp).astype(np.uint32))).astype(np.float64) * 2.0**-32
    assert chi2_pvalue(pair_histogram(bare[0], bare[1])) < REJECT


@pytest.mark.parametrize("spp", [16, 100])
def test_sobol_pairs_of_one_path_are_independent(spp):
    """Across pixels (one sample each), two pairs of the same path are
    independent: joint histograms of their coordinates."""
    sampler = Sampler(scene_key(9), spp, "sobol")
    a = one_sample_per_pixel(sampler, 3)
    b = one_sample_per_pixel(sampler, LIGHT_PAIRS + 4)
    c = one_sample_per_pixel(sampler, TIME_PAIR)
    for x, y in ((a[0], b[0]), (a[1], b[1]), (a[0], b[1]), (a[1], c[0]), (b[0], c[0])):
        assert chi2_pvalue(pair_histogram(x, y)) > ACCEPT


def test_negative_control_one_seed_for_every_pair_is_rejected():
    """Without a hash per pair (pair 0's seeds for all), two pairs of a path coincide."""
    spp, n = 16, N
    sampler = Sampler(scene_key(9), spp, "sobol")
    pixel = np.arange(n)
    state = sampler.start(pixel, pixel.astype(np.uint64) * np.uint64(spp) + (pixel % spp).astype(np.uint64))
    a = b = sobol_points(state, pair_seeds(pixel_seeds(state), 0), 4)  # what pairs 3 and LIGHT_PAIRS + 4 would get
    assert chi2_pvalue(pair_histogram(a[0], b[0])) < REJECT


SEED_PIXELS = 1 << 22  # the weakness the negative control shows needs millions of pixels to stand out


def seed_words_histogram(a, b, shift):
    """Joint histogram of 5 bits of two words (from bit ``shift``) over pixels."""
    x = ((a >> np.uint32(shift)) & np.uint32(31)).astype(np.int64)
    y = ((b >> np.uint32(shift)) & np.uint32(31)).astype(np.int64)
    return np.bincount(x * 32 + y, minlength=1024)


def many_pixel_seeds():
    return pixel_seeds(Sampler(scene_key(5), 16, "sobol").start(np.arange(SEED_PIXELS),
                                                                   np.arange(SEED_PIXELS, dtype=np.uint64) * 16))


def test_seed_words_are_independent_across_rows_and_pairs():
    """A pair's three words, and the words of neighbouring pairs, are
    independent across pixels (top and bottom bits)."""
    q = many_pixel_seeds()
    for pair in (3, LIGHT_PAIRS):
        w, next_pair = pair_seeds(q, pair), pair_seeds(q, np.full(q.size, pair + 1))
        for a, b in ((w[0], w[1]), (w[0], w[2]), (w[1], w[2]), (w[0], next_pair[0]), (w[1], next_pair[1]),
                     (w[2], next_pair[0])):
            for shift in (27, 0):
                assert chi2_pvalue(seed_words_histogram(a, b, shift)) > ACCEPT


def test_negative_control_one_hash_of_nearby_keys_is_rejected():
    """The first design: one lowbias32 of the pixel seed XOR a key per (pair,
    row), keys ``(pair + row 2^30) * golden`` that differ in their top bits
    only: the shuffle's and the first scramble's words correlate."""
    q = many_pixel_seeds()
    keys = [np.uint32(((3 + (row << 30)) * 0x9E3779B9) & 0xFFFFFFFF) for row in range(2)]
    shuffle, scramble = (_hash32(q ^ key) for key in keys)
    assert chi2_pvalue(seed_words_histogram(shuffle, scramble, 27)) < REJECT


def within_pixel_statistic(x, y, pixels, spp, bins=4):
    """Mean over pixels of sum over the bins x bins cells of (count - expected)^2,
    where a pixel's samples are binned by ``x`` and ``y``."""
    a = np.minimum((x * bins).astype(np.int64), bins - 1)
    b = np.minimum((y * bins).astype(np.int64), bins - 1)
    counts = np.bincount(np.repeat(np.arange(pixels), spp) * bins * bins + a * bins + b,
                         minlength=pixels * bins * bins).reshape(pixels, bins * bins)
    return ((counts - spp / bins**2) ** 2).sum(axis=1).mean()


def random_correspondence(spp, bins=4):
    """The statistic's mean if a pixel's samples met pair two's points in a
    uniformly random order: each cell hypergeometric (spp, spp/bins, spp/bins)."""
    k = spp // bins
    return bins * bins * k * (k / spp) * (1 - k / spp) * (spp - k) / (spp - 1)


def random_function(spp, bins=4):
    """The statistic's mean if each sample's bin in pair two were drawn on its
    own, uniformly (pair one's bins stay stratified): each cell binomial
    (spp/bins, 1/bins), summed over bins^2 cells."""
    return spp * (1 - 1 / bins)


def all_samples(sampler, pixels):
    spp = sampler.samples_per_pixel
    pixel = np.repeat(np.arange(pixels), spp)
    return sampler.start(pixel, pixel.astype(np.uint64) * np.uint64(spp) + np.tile(np.arange(spp, dtype=np.uint64),
                                                                                    pixels))


@pytest.mark.parametrize("spp", [16, 64])
def test_sobol_pairs_are_padded_within_a_pixel(spp):
    """Each pair shuffles the pixel's points on its own, so which samples
    share a box in one pair says little about the next pair (pbrt's padding).
    A nested shuffle composed with another is nested: the correspondence of
    two pairs' coarse boxes behaves as a random function's, not a uniformly
    random order's (measured 0.98-1.01x :func:`random_function`, which is
    1.25x :func:`random_correspondence` at 16 spp and 1.31x at 64; Kensler's
    permutation measured 1.00-1.05x the random order's; samples independent
    within the pixel give 1.25x the random function's and fail)."""
    pixels = 192_000 // spp
    sampler = Sampler(scene_key(13), spp, "sobol")
    state = all_samples(sampler, pixels)
    for d1, d2 in ((2, 3), (0, LIGHT_PAIRS + 1), (LIGHT_PAIRS, MEDIUM_PAIRS)):
        u, v = sampler.pairs(state, d1), sampler.pairs(state, d2)
        for x in (0, 1):
            for y in (0, 1):
                assert within_pixel_statistic(u[x], v[y], pixels, spp) < 1.1 * random_function(spp)


def test_negative_control_one_shuffle_for_every_pair_is_rejected():
    """Own scrambles but pair 2's shuffle for pair 3 too: a sample gets
    the same point of both nets, and the boxes it shares, it shares again."""
    spp, pixels = 64, 3000
    sampler = Sampler(scene_key(13), spp, "sobol")
    state = all_samples(sampler, pixels)
    s2, s3 = pair_seeds(pixel_seeds(state), 2), pair_seeds(pixel_seeds(state), 3)
    s3[0] = s2[0]
    u, v = sobol_points(state, s2, 6), sobol_points(state, s3, 6)
    assert within_pixel_statistic(u[0], v[0], pixels, spp) > 5 * random_function(spp)


def test_sampler_kinds():
    assert SAMPLERS == ("sobol", "independent")
    with pytest.raises(ValueError):
        Sampler(scene_key(0), 4, "halton")


@pytest.mark.parametrize("pair", [0, 7, LIGHT_PAIRS + 3, MEDIUM_PAIRS + 700])
def test_sobol_pair_as_int_or_per_path_gives_the_same_numbers(pair):
    sampler = Sampler(scene_key(3), 10, "sobol")
    state = sampler.start(np.arange(1000) // 10, np.arange(1000, dtype=np.uint64))
    np.testing.assert_array_equal(sampler.pairs(state, pair), sampler.pairs(state, np.full(1000, pair)))


@pytest.mark.parametrize("kind", SAMPLERS)
@pytest.mark.parametrize("spp, sample_start, sample_stop", [(100, 0, 1), (100, 1, 3), (100, 16, 32), (100, 96, 100),
                                                            (7, 0, 7), (1, 0, 1), (70000, 65000, 65040)])
def test_grids_of_new_paths_are_their_paths(kind, spp, sample_start, sample_stop):
    """Sampler.start_grid and Sampler.pairs_grid (a refill's new paths: per-pixel
    and per-index words made once and combined) give every path's state and
    numbers bit for bit, pixel-major, in both precisions, past the index
    table's bits too."""
    sampler = Sampler(scene_key(8), spp, kind)
    pixel = np.random.default_rng(8).integers(0, 10**6, 37)
    index = np.arange(sample_start, sample_stop)
    grid = sampler.start_grid(pixel, sample_start, sample_stop)
    assert grid.shape == (37, index.size) and grid.dtype == np.uint64
    state = sampler.start(np.repeat(pixel, index.size), (pixel[:, None] * spp + index).ravel().astype(np.uint64))
    np.testing.assert_array_equal(grid.ravel(), state)
    for pair in (0, 1, 9, TIME_PAIR):
        for dtype in (np.float64, np.float32):
            u = sampler.pairs_grid(grid, pair, dtype)
            assert u.shape == (2, 37, index.size) and u.dtype == dtype
            np.testing.assert_array_equal(u.reshape(2, -1), sampler.pairs(state, pair, dtype))


@pytest.mark.parametrize("kind", SAMPLERS)
@pytest.mark.parametrize("n", [0, 1, 700])
def test_pairs_drawn_together_are_those_drawn_apart(kind, n):
    """Sampler.pairs_together (a small bounce's light, bounce and roulette
    pairs in one call) gives each pair's numbers bit for bit, each in its own
    precision, for pairs per path or one for all."""
    sampler = Sampler(scene_key(5), 12, kind)
    rng = np.random.default_rng(5)
    pixel = rng.integers(0, 10**6, n)
    state = sampler.start(pixel, (pixel * 12 + rng.integers(0, 12, n)).astype(np.uint64))
    depth = rng.integers(0, 60, n).astype(np.int32)
    pairs = [bounce_dimension(depth), light_point_dimension(depth), light_choice_dimension(depth), 3, np.full(n, 9)]
    dtypes = [np.float32, np.float64, np.float64, np.float32, np.float64]
    together = sampler.pairs_together(state, pairs, dtypes)
    assert len(together) == len(pairs)
    for got, pair, dtype in zip(together, pairs, dtypes):
        want = sampler.pairs(state, pair, dtype)
        assert got.dtype == want.dtype and got.shape == (2, n)
        np.testing.assert_array_equal(got, want)


@pytest.mark.parametrize("kind", SAMPLERS)
@pytest.mark.parametrize("spp", [1, 12, 1 << 17])
def test_one_uniform_of_a_pair_is_that_of_the_pair(kind, spp):
    """Sampler.uniform (one dimension of a pair, what roulette reads) gives
    the pair's numbers bit for bit, in either precision, for pairs per path
    or one for all."""
    sampler = Sampler(scene_key(6), spp, kind)
    rng = np.random.default_rng(6)
    pixel = rng.integers(0, 10**6, 700)
    state = sampler.start(pixel, (pixel * spp + rng.integers(0, spp, 700)).astype(np.uint64))
    depth = rng.integers(0, 60, 700).astype(np.int32)
    for pair in (light_choice_dimension(depth), np.full(700, 9), 4):
        for dimension in (0, 1):
            for dtype in (np.float64, np.float32):
                got, want = sampler.uniform(state, pair, dimension, dtype), sampler.pairs(state, pair, dtype)[dimension]
                assert got.dtype == want.dtype and got.shape == (700,)
                np.testing.assert_array_equal(got, want)


def test_independent_sampler_is_the_hash_of_the_sample_id():
    """sampler: independent draws exactly what path_state/uniform_pairs give
    (the numbers every image before the sobol sampler was made of)."""
    sampler = Sampler(scene_key(3), 10, "independent")
    pixel = np.arange(1000) // 10
    sample_id = np.arange(1000, dtype=np.uint64)
    state = sampler.start(pixel, sample_id)
    np.testing.assert_array_equal(state, path_state(scene_key(3), sample_id))
    np.testing.assert_array_equal(sampler.pairs(state, 5), uniform_pairs(state, 5))
    np.testing.assert_array_equal(sampler.pairs(state, np.full(1000, 5)), uniform_pairs(state, 5))


# -- rendering with the sobol sampler -----------------------------------------------------


SCENES = Path(__file__).resolve().parent.parent / "scenes"


def with_sampler(scene, sampler, **settings):
    return scene.replace(render=dataclasses.replace(scene.render, sampler=sampler, **settings))


@pytest.mark.parametrize("name", ["furnace_lambertian", "furnace_mirror", "furnace_glass"])
@pytest.mark.parametrize("spp", [5, 16])
def test_white_furnace_is_exact_under_sobol(name, spp):
    scene = with_sampler(load_scene(SCENES / f"{name}.yaml"), "sobol", russian_roulette=False)
    np.testing.assert_allclose(render(scene.with_overrides(samples_per_pixel=spp), workers=1), 1.0, atol=1e-6)


def cornell_box():
    """The Cornell box, small: a quad light, walls, boxes, every decision of a path."""
    return load_scene(SCENES / "cornell_box.yaml").with_overrides(width=40, height=40, samples_per_pixel=16)


def quad_lit():
    """A floor and a ball under a large, close quad light: where the light
    sample falls matters, so a biased sampler shows (on the Cornell box
    u ** 1.1 moves the image by about one standard error of this test)."""
    materials = {"floor": Lambertian((0.7, 0.7, 0.7)), "ball": Lambertian((0.3, 0.5, 0.7)),
                 "lamp": Emissive((4, 4, 4))}
    quads = [Quad((-2, 0, 2), (4, 0, 0), (0, 0, -4), "floor"),
             Quad((-0.8, 0.7, 0.8), (0, 0, -1.6), (1.6, 0, 0), "lamp")]  # cross(u, v) = -y: shines down
    return Scene(spheres=[Sphere((0.5, 0.3, 0.3), 0.3, "ball")], quads=quads, materials=materials,
                 camera=Camera(look_from=(0, 3.0, 2.5), look_at=(0, 0, 0), vfov=50),
                 background=Solid((0.1, 0.1, 0.1)), width=40, height=40,
                 render=RenderSettings(samples_per_pixel=16, max_depth=6))


LIT_SCENES = {"cornell_box": cornell_box, "quad_lit": quad_lit}


BLOCK = 5


def difference_z(a, b):
    """z-scores of ``a - b`` (two renders of one scene with unrelated seeds):
    the whole image's, then per BLOCK x BLOCK block.

    Both are unbiased for the same pixel means, so each pixel's difference
    has mean zero, and differences of distinct pixels are independent
    (distinct pixels hash to unrelated numbers): the sum of n of them over
    the root of the sum of their squares is a standard normal z.  (A pixel's
    own sample variance would not do: under sobol its samples are not
    independent, and it overstates the variance of their mean.)
    """
    d = (a.astype(np.float64) - b.astype(np.float64)).sum(axis=-1)  # channels of a pixel are not independent
    h, w = d.shape
    blocks = d[:h - h % BLOCK, :w - w % BLOCK].reshape(h // BLOCK, BLOCK, w // BLOCK, BLOCK)
    block_z = blocks.sum(axis=(1, 3)) / np.sqrt((blocks**2).sum(axis=(1, 3)) + 1e-300)
    return d.sum() / np.sqrt((d**2).sum()), block_z


def differ(a, b, alpha=1e-3):
    """Two-sided test of the whole image and of every block (Bonferroni)."""
    z, block_z = difference_z(a, b)
    return (abs(z) > stats.norm.isf(alpha / 2)
            or np.abs(block_z).max() > stats.norm.isf(alpha / (2 * block_z.size))), z, np.abs(block_z).max()


def mean_image(scene, seeds):
    return np.mean([render(scene.with_overrides(seed=s), workers=1).astype(np.float64) for s in seeds], axis=0)


@functools.cache
def independent_image(name, spp=16):
    return mean_image(with_sampler(LIT_SCENES[name](), "independent").with_overrides(samples_per_pixel=spp),
                      range(900, 904))


@pytest.mark.parametrize("name, spp", [("cornell_box", 16), ("quad_lit", 16), ("quad_lit", 12)])
def test_sobol_and_independent_images_are_equal_in_expectation(name, spp):
    scene = with_sampler(LIT_SCENES[name](), "sobol").with_overrides(samples_per_pixel=spp)
    bad, z, worst = differ(mean_image(scene, range(300, 304)), independent_image(name, spp))
    assert not bad, f"z = {z:.2f}, largest block |z| = {worst:.2f}"


def test_negative_control_biased_sampler_is_rejected(monkeypatch):
    """Every uniform raised to the power 1.1 (still in [0, 1), slightly towards 0)."""
    reference = independent_image("quad_lit")  # before the sampler goes wrong
    pairs = Sampler.pairs
    monkeypatch.setattr(Sampler, "pairs", lambda self, state, pair, dtype=np.float64, **runs: pairs(
        self, state, pair, dtype, **runs) ** 1.1)
    bad, z, worst = differ(mean_image(with_sampler(quad_lit(), "sobol"), range(300, 304)), reference)
    assert bad, f"z = {z:.2f}, largest block |z| = {worst:.2f}"


@pytest.mark.parametrize("dtype", [np.float32, np.float64])
def test_cos_sin_2pi_sign_is_copysign_bit_for_bit(dtype):
    """The sine's sign, copied by bits, is np.copysign's (at u = 0.5 and around it too)."""
    rng = np.random.default_rng(4)
    half = dtype(0.5)
    u = np.concatenate([rng.random(4096), [0.0, 0.25, half, np.nextafter(half, dtype(0)), np.nextafter(half, dtype(1)),
                                           0.75, np.nextafter(dtype(1), dtype(0))]]).astype(dtype)
    c, s = cos_sin_2pi(u)
    root = np.sqrt(np.maximum(0.0, 1.0 - c * c))
    expected = np.copysign(root, 0.5 - u)
    assert s.dtype == c.dtype == dtype
    np.testing.assert_array_equal(s.view(np.uint32 if dtype is np.float32 else np.uint64),
                                  expected.view(np.uint32 if dtype is np.float32 else np.uint64))
    assert (s < 0).any() and (s > 0).any()

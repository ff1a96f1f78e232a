"""Random numbers and the samplers built on them.

Why a counter-based hash and not one ``Generator`` per chunk
-------------------------------------------------------------
A wavefront compacts its rays after every bounce and refills free slots with
new camera samples, so a ray's position in a buffer says nothing stable about
it.  If random numbers came from a stream consumed in buffer order, changing
the chunk size, the worker count or the refill policy would change the image.
Instead every random number is a pure function of

    (scene key, sample id, dimension)

where ``sample id = pixel * samples_per_pixel + sample_index`` names one path
and the *dimension* counts the decisions along it (camera jitter, lens, then a
fixed block per bounce).  This is what pbrt's samplers do.  The key comes from
``numpy.random.SeedSequence(seed)``, so nearby seeds give unrelated images.
The hash is SplitMix64's finaliser (Steele, Lea & Flood 2014; Stafford's
"Mix13" constants), applied twice: once to fold the key into the sample id,
once per dimension.  ``tests/test_sampling.py`` checks uniformity and
independence with chi-square tests, and checks that a weak hash fails them.

That is ``render.sampler: independent``.  The default, ``sobol``, keeps the
same structure (a pure function of key, pixel, sample index and pair) but
makes the numbers of one pixel's samples a scrambled low-discrepancy net in
each pair instead of independent: see "the low-discrepancy sampler" below
and :class:`Sampler`, which every draw of a render goes through.

Samplers take their uniforms as arguments and own no state, which is what lets
the tests feed them controlled numbers.
"""

from __future__ import annotations

import sys
from dataclasses import dataclass

import numpy as np
from numpy.random import SeedSequence  # imported with the package: NumPy loads numpy.random lazily, ~7 ms

_GOLDEN = np.uint64(0x9E3779B97F4A7C15)  # Weyl increment: 2^64 / golden ratio
_MIX_1 = np.uint64(0xBF58476D1CE4E5B9)
_MIX_2 = np.uint64(0x94D049BB133111EB)
_S30, _S27, _S31 = (np.uint64(s) for s in (30, 27, 31))

# Numbers come in pairs from one hash.  Pairs 0 and 1 belong to the camera
# (pixel jitter x, y; lens u, v); bounce b owns pair CAMERA_PAIRS + b.  Fixed
# slots mean a sample draws the same number for the same decision however it
# was scheduled.
CAMERA_PAIRS = 2


def mix64(x: np.ndarray) -> np.ndarray:
    """SplitMix64 finaliser: a bijective, avalanching map of uint64 arrays."""
    z = x ^ (x >> _S30)
    z *= _MIX_1
    z ^= z >> _S27
    z *= _MIX_2
    z ^= z >> _S31
    return z


def scene_key(seed: int) -> np.uint64:
    """Derive the 64-bit hash key of a render from the user's ``seed``."""
    state = SeedSequence(int(seed)).generate_state(1, dtype=np.uint64)
    return np.uint64(state[0])


def path_state(key: np.uint64, sample_id: np.ndarray) -> np.ndarray:
    """Per-path hash state from the render key and global sample ids (uint64)."""
    return mix64(sample_id.astype(np.uint64, copy=False) ^ key)


# Next-event estimation and Russian roulette draw from a block of their own
# at every vertex, far above every bounce pair (depth is at most 10 000), so
# turning them on or off shifts none of the numbers the material sampling
# draws: with both off the image is bit for bit the book estimator's.  At the
# vertex a path reaches after ``depth + 1`` segments:
#   pair LIGHT_PAIRS + 2 depth      -> the point on the light (u0, u1)
#   pair LIGHT_PAIRS + 2 depth + 1  -> which light (u0), roulette (u1)
LIGHT_PAIRS = 1 << 24
# Motion blur: each path's time in [0, 1) is the first uniform of a pair of
# its own, outside every other block, so a scene that moves draws every
# other number exactly as a still one does.
TIME_PAIR = 1 << 23

# Participating media draw a free-flight distance for every straight piece of
# a path: from a vertex to the next vertex, cut at each medium boundary the
# ray crosses (a new medium needs a fresh distance).  The piece after the
# path's vertex at ``depth`` that follows ``crossing`` boundary crossings
# (0 <= crossing < CROSSINGS_PER_SEGMENT) draws
#   pair MEDIUM_PAIRS + depth * CROSSINGS_PER_SEGMENT + crossing -> distance (u0)
# (u1 unused).  10 000 depths x 256 pieces stay below 1 << 25 + 2.6 M, clear
# of every other block.  A medium vertex's scatter direction is drawn from
# its bounce pair, its light sample and roulette from its LIGHT_PAIRS pairs,
# exactly as a surface vertex's.
MEDIUM_PAIRS = 1 << 25
# Boundary crossings a path may make between two vertices (and a shadow ray
# in all): a straight ray crosses each closed boundary at most a few times, so
# this only stops rounding trouble from looping; a path over it ends.
CROSSINGS_PER_SEGMENT = 256


def bounce_dimension(depth: np.ndarray | int) -> np.ndarray | int:
    """Index of the pair of uniforms a path draws at bounce ``depth`` (the material's sample)."""
    return CAMERA_PAIRS + depth


def light_point_dimension(depth: np.ndarray | int) -> np.ndarray | int:
    """Index of the pair choosing the point on the light at bounce ``depth``."""
    return LIGHT_PAIRS + 2 * depth


def light_choice_dimension(depth: np.ndarray | int) -> np.ndarray | int:
    """Index of the pair choosing the light (first) and deciding roulette (second) at bounce ``depth``."""
    return LIGHT_PAIRS + 2 * depth + 1


def medium_dimension(depth: np.ndarray, crossing: np.ndarray) -> np.ndarray:
    """Index of the pair drawing the free-flight distance after ``crossing``
    boundary crossings of the segment leaving the vertex at ``depth``."""
    return MEDIUM_PAIRS + depth.astype(np.int64) * CROSSINGS_PER_SEGMENT + crossing


_LOW32 = np.uint64(0xFFFFFFFF)
_LOW24 = np.uint64(0xFFFFFF)
_S32, _S40, _S8 = np.uint64(32), np.uint64(40), np.uint64(8)
_TO_UNIT_32 = 2.0**-32
_TO_UNIT_24 = 2.0**-24


def _split_pairs(z: np.ndarray, dtype=np.float64) -> np.ndarray:
    """Two uniforms in [0, 1) from one 64-bit hash: 32 bits each in float64,
    24 bits each in float32 (all a float32 can hold below 1, so 1 is never
    reached).

    32 bits resolve directions far below a pixel; one hash per pair halves
    the cost of random numbers, the largest single item of a bounce after
    intersection.
    """
    out = np.empty((2, z.shape[0]), dtype=dtype)
    if np.dtype(dtype) == np.float32:
        np.multiply(z >> _S40, _TO_UNIT_24, out=out[0], casting="unsafe")
        np.multiply((z >> _S8) & _LOW24, _TO_UNIT_24, out=out[1], casting="unsafe")
    else:
        np.multiply(z >> _S32, _TO_UNIT_32, out=out[0])
        np.multiply(z & _LOW32, _TO_UNIT_32, out=out[1])
    return out


def uniform_pairs(state: np.ndarray, pair: int, dtype=np.float64) -> np.ndarray:
    """Uniforms for dimensions ``2 pair`` and ``2 pair + 1``; shape (2, N)."""
    offset = np.uint64((0x9E3779B97F4A7C15 * (pair + 1)) & 0xFFFFFFFFFFFFFFFF)
    return _split_pairs(mix64(state + offset), dtype)


def uniform_pairs_at(state: np.ndarray, pair: np.ndarray, dtype=np.float64) -> np.ndarray:
    """Like :func:`uniform_pairs` with a per-path pair index; shape (2, N)."""
    return _split_pairs(mix64(state + _GOLDEN * (pair.astype(np.uint64) + np.uint64(1))), dtype)


# -- the low-discrepancy sampler (pbrt-v4's PaddedSobolSampler) -------------------------
#
# Independent uniforms leave a pixel's samples clumped and gapped by chance,
# so its error falls as 1 / sqrt(spp).  pbrt-v4's default sampler instead
# gives every *pair* of a path (camera jitter, lens, each bounce's direction,
# each light sample, ...) its own scrambled Sobol' (0, 2)-sequence over the
# pixel's samples: with spp = 2^m a pixel's points of one pair put exactly
# one point in each of the 2^m elementary boxes of area 2^-m (any aspect
# ratio), so smooth integrands converge much faster, and edges and small
# lights no slower than with independent numbers.  For pair ``d`` of sample
# ``i`` of pixel ``p``:
#
#   h        = hash(key, p, d)                 (64 bits, and 64 more from it)
#   j        = permutation_element(i, spp, seed from h)
#   (u0, u1) = Sobol' point j, dimensions 0 and 1, each Owen-scrambled with
#              its own seed from h, then digitally shifted
#
# The permutation, a different one per pair, decides which of the pixel's
# points a sample gets in each pair, so the pairs of one path are not
# correlated with each other (pbrt-v4 section 8.7.3, "padding").  The scramble
# randomises the net while keeping it a net.  The final XOR with a random
# 32-bit word (a digital shift, which also maps every elementary box onto
# one) makes each point exactly uniform on the 2^-32 grid: the fast
# hash-based scramble alone is not uniform past its top 16 bits (one point
# under 2^26 random seeds: chi-square p ~ 1e-17 on the top 20 bits, 1e-80 on
# 22; 0.4-0.7 on 16).  So a
# pixel's estimate is unbiased whatever spp is; a count that is not a power of
# two keeps that and loses part of the stratification.
#
# Everything is NumPy arithmetic on uint32 arrays, whose multiplication wraps
# mod 2^32 as the C originals rely on; no loop runs per bit or per path.

_U32 = np.uint32


def _reverse_bits_int(x: int) -> int:
    return int(f"{x:032b}"[::-1], 2)


def _sobol_dimension_1_columns() -> list[int]:
    """Generator columns of Sobol' dimension 1 (Pascal's triangle mod 2, the
    primitive polynomial x + 1): column 0 is the top bit and each next column
    is the last one XOR itself shifted right by one.  (Dimension 0's columns
    are single bits: its points are the bit-reversed indices, van der
    Corput's sequence.)"""
    columns = [1 << 31]
    for _ in range(31):
        columns.append(columns[-1] ^ (columns[-1] >> 1))
    return columns


_BYTE, _S8U, _S16U = _U32(0xFF), _U32(8), _U32(16)
# Bit reversal without tables: swap bytes, then nibbles, pairs and bits
# within each byte.  In place on uint32 this measured 1.4-3x faster than
# four 256-entry (or two 65536-entry) table lookups, whose int64 index
# conversion and cache misses dominate.
_SWAPS = tuple((_U32(s), _U32(m)) for s, m in ((4, 0x0F0F0F0F), (2, 0x33333333), (1, 0x55555555)))


def reverse_bits(x: np.ndarray) -> np.ndarray:
    """Bit reversal of a uint32 array (bit 0 <-> bit 31), in place; returns ``x``."""
    x.byteswap(inplace=True)
    t = np.empty_like(x)
    for shift, mask in _SWAPS:
        np.right_shift(x, shift, out=t)
        t &= mask
        x &= mask
        x <<= shift
        x |= t
    return x


def _sobol_dimension_1_reversed_tables() -> np.ndarray:
    """``(4, 256)`` uint32: entry ``[b, x]`` is ``reverse(C1 (x << 8 b))``.

    The scramble works on bit-reversed values, and ``reverse(C1 j)`` is linear
    over GF(2) in ``j``: the XOR of one entry per byte of ``j``.  (Built with
    array operations: a loop per entry cost 1 ms of every import.)
    """
    columns = np.array(_sobol_dimension_1_columns(), dtype=np.uint32).reshape(4, 8)
    x = np.arange(256, dtype=np.uint32)
    tables = np.zeros((4, 256), dtype=np.uint32)
    for bit in range(8):
        tables ^= np.where((x >> _U32(bit)) & _U32(1), columns[:, bit:bit + 1], _U32(0))
    return reverse_bits(tables)


_SOBOL_1_REVERSED = _sobol_dimension_1_reversed_tables()


def sobol_reversed(j: np.ndarray, index_bits: int = 32) -> np.ndarray:
    """Sobol' points ``j`` (uint32) in dimensions 0 and 1, each bit-reversed
    (what the scramble takes); shape ``(2, N)`` uint32.

    Dimension 0 reversed is ``j`` itself.  ``index_bits`` bounds the indices
    (``j < 2^index_bits``), so small sample counts use one table lookup.
    """
    out = np.empty((2, j.shape[0]), dtype=np.uint32)
    out[0] = j
    out[1] = _SOBOL_1_REVERSED[0].take(j & _BYTE)
    for b in range(1, -(-index_bits // 8)):
        out[1] ^= _SOBOL_1_REVERSED[b].take((j >> _U32(8 * b)) & _BYTE)
    return out


def owen_scramble_reversed(v: np.ndarray, seed: np.ndarray) -> np.ndarray:
    """pbrt-v4's FastOwenScrambler on bit-reversed values, in place: a hash
    in which each output bit depends only on the bits below it (Laine and
    Karras 2011; these constants are Vegdahl's 2021 improvement), which is a
    nested (Owen) scramble of the unreversed value.  ``v`` and ``seed`` are
    uint32 arrays of one shape; returns ``v``."""
    v ^= v * _U32(0x3D20ADEA)
    v += seed
    v *= (seed >> _S16U) | _U32(1)
    v ^= v * _U32(0x05526C56)
    v ^= v * _U32(0x53A22864)
    return v


_PERMUTE_MULTIPLIERS = tuple(_U32(c) for c in (0xE170893D, 0x0929EB3F, 0x6935FA69, 0x74DCB303, 0x9E501CC3,
                                              0xC860A3DF))


def _permute_round(i: np.ndarray, w: np.uint32, p: np.ndarray) -> np.ndarray:
    """One round of Kensler's hash: a bijection of ``[0, w]`` (``w + 1`` a power
    of two) chosen by ``p``; every step is invertible on the low bits."""
    m1, m2, m3, m4, m5, m6 = _PERMUTE_MULTIPLIERS
    i = i ^ p
    i *= m1
    i ^= p >> _U32(16)
    i ^= (i & w) >> _U32(4)
    i ^= p >> _S8U
    i *= m2
    i ^= p >> _U32(23)
    i ^= (i & w) >> _U32(1)
    i *= (p >> _U32(27)) | _U32(1)
    i *= m3
    i ^= (i & w) >> _U32(11)
    i *= m4
    i ^= (i & w) >> _U32(2)
    i *= m5
    i ^= (i & w) >> _U32(2)
    i *= m6
    i &= w
    i ^= i >> _U32(5)
    return i


def permutation_element(i: np.ndarray, length: int, p: np.ndarray) -> np.ndarray:
    """Element ``i`` of the pseudo-random permutation of ``[0, length)`` chosen
    by ``p`` (Kensler, "Correlated Multi-Jittered Sampling", 2013; pbrt-v4's
    ``PermutationElement``); ``i`` and ``p`` uint32 arrays, ``0 <= i < length``.

    The hash permutes ``[0, 2^k)``, the smallest power of two holding
    ``length``; an index it sends past ``length`` is hashed again until it
    lands inside (cycle walking: following the bijection's cycle from
    ``i`` reaches an element below ``length`` before returning to ``i``, so
    the result is a bijection of ``[0, length)``).  Vectorised, each round
    hashes only the indices still outside; a round sends one outside with
    probability below 1/2, and ``2^k - length + 1`` rounds always suffice.
    Then a rotation by ``p``, reduced first so the sum cannot wrap (pbrt's
    ``(i + p) % l`` in uint32 is no bijection when it does).
    """
    w = (1 << max(length - 1, 0).bit_length()) - 1
    out = _permute_round(i, _U32(w), p)
    if length == w + 1:
        return (out + p) & _U32(w)
    outside = np.flatnonzero(out >= length)
    for _ in range(w + 1 - length):
        if outside.size == 0:
            break
        again = _permute_round(out.take(outside), _U32(w), p.take(outside))
        out[outside] = again
        outside = outside.take(np.flatnonzero(again >= length))
    return (out + p % _U32(length)) % _U32(length)


def _split_words(h: np.ndarray) -> np.ndarray:
    """A (contiguous) uint64 array's low and high 32-bit words; shape ``(2, N)``
    uint32: on a little-endian machine a view, no copy."""
    if sys.byteorder == "little":
        return h.view(np.uint32).reshape(-1, 2).T
    return np.stack((h.astype(np.uint32), (h >> _S32).astype(np.uint32)))


def _hash32(x: np.ndarray) -> np.ndarray:
    """A 32-bit avalanching bijection of uint32 arrays (Wellons' "lowbias32")."""
    x = x ^ (x >> _S16U)
    x *= _U32(0x7FEB352D)
    x ^= x >> _U32(15)
    x *= _U32(0x846CA68B)
    x ^= x >> _S16U
    return x


def _to_unit(v: np.ndarray, dtype) -> np.ndarray:
    """uint32 ``(2, N)`` to uniforms in [0, 1): all 32 bits in float64 (exact,
    at most ``1 - 2^-32``), the top 24 in float32 (exact, at most
    ``1 - 2^-24``): never 1, which is what pbrt's OneMinusEpsilon clamp is for
    when it rounds 32 bits into a float."""
    out = np.empty(v.shape, dtype=dtype)
    if np.dtype(dtype) == np.float32:
        np.multiply(v >> _S8U, _TO_UNIT_24, out=out, casting="unsafe")
    else:
        np.multiply(v, _TO_UNIT_32, out=out)
    return out


@dataclass(frozen=True, slots=True)
class PairSeeds:
    """The random words one pair of one pixel's samples is made from (uint32)."""

    permutation: np.ndarray  # (N,): which point of the net each sample index gets
    scramble: np.ndarray  # (2, N): the Owen scramble's seeds of dimensions 0 and 1
    shift: np.ndarray  # (2, N): the digital shifts of dimensions 0 and 1


def pair_seeds(pixel_hash: np.ndarray, pair) -> PairSeeds:
    """The seeds of pair ``pair`` (an int, or one per path) of pixels
    ``pixel_hash`` (uint64, the same for every sample of a pixel).

    ``h = hash(pixel_hash, pair)`` gives the two scramble seeds, the next
    word of a SplitMix64 stream from ``h`` the two shifts (so they are as
    independent of the scramble as hash outputs are taken to be, which is
    what makes the shifted points uniform), and a 32-bit hash of ``h``'s
    words the permutation (it only orders the pixel's points; a third 64-bit
    mix cost 2 % of a render).
    """
    pair_offset = (np.uint64((0x9E3779B97F4A7C15 * (int(pair) + 1)) & 0xFFFFFFFFFFFFFFFF)
                   if isinstance(pair, (int, np.integer)) else _GOLDEN * (pair.astype(np.uint64) + np.uint64(1)))
    h = mix64(pixel_hash + pair_offset)
    scramble = _split_words(h)
    return PairSeeds(permutation=_hash32(scramble[0] ^ scramble[1]), scramble=scramble,
                     shift=_split_words(mix64(h + _GOLDEN)))


def scrambled_sobol(j: np.ndarray, seeds: PairSeeds, index_bits: int = 32, dtype=np.float64) -> np.ndarray:
    """Sobol' points ``j`` (uint32, below ``2^index_bits``) in dimensions 0
    and 1, Owen-scrambled and shifted by ``seeds``; uniforms, shape (2, N)."""
    v = owen_scramble_reversed(sobol_reversed(j, index_bits), seeds.scramble)
    v = reverse_bits(v)
    v ^= seeds.shift
    return _to_unit(v, dtype)


def sobol_pairs(pixel_hash: np.ndarray, sample_index: np.ndarray, samples_per_pixel: int, pair,
                dtype=np.float64) -> np.ndarray:
    """The padded, scrambled Sobol' pair ``pair`` of each sample; shape (2, N).

    Parameters
    ----------
    pixel_hash : ndarray of shape (N,), uint64
        The hash of (key, pixel): the same for every sample of a pixel.
    sample_index : ndarray of shape (N,), uint32
        Each sample's index in its pixel, below ``samples_per_pixel``.
    pair : int or ndarray of shape (N,)
        The pair index (a fixed block of :mod:`wavefront.sampling`).
    """
    seeds = pair_seeds(pixel_hash, pair)
    j = permutation_element(sample_index, samples_per_pixel, seeds.permutation)
    return scrambled_sobol(j, seeds, max(samples_per_pixel - 1, 1).bit_length(), dtype)


SAMPLERS = ("sobol", "independent")


@dataclass(frozen=True)
class Sampler:
    """Where every uniform of a render comes from (``render.sampler``).

    ``kind`` is ``"sobol"`` (the padded, scrambled Sobol' sampler above) or
    ``"independent"`` (the counter-based hash: every number independent).
    Both are pure functions of (key, pixel, sample index, pair), so the image
    does not depend on the order paths are traced in.  A path carries one
    uint64 ``state`` from :meth:`start`:

    * independent: the hash of (key, sample id), as :func:`path_state`;
    * sobol: the hash of (key, pixel) with its low ``index_bits`` bits
      replaced by the sample index (``spp <= 2^24`` leaves 40 bits of pixel
      hash: two pixels share a pattern with probability ~ pixels^2 / 2^41).
    """

    key: np.uint64
    samples_per_pixel: int
    kind: str = "sobol"

    def __post_init__(self):
        if self.kind not in SAMPLERS:
            raise ValueError(f"sampler: expected one of {', '.join(SAMPLERS)}, got {self.kind!r}")

    @property
    def index_bits(self) -> int:
        """Low bits of a sobol state that hold the sample index."""
        return (self.samples_per_pixel - 1).bit_length()

    def start(self, pixel: np.ndarray, sample_id: np.ndarray) -> np.ndarray:
        """Per-path state (uint64, shape (N,)) of the samples ``sample_id =
        pixel * samples_per_pixel + sample index`` of pixels ``pixel``."""
        sample_id = sample_id.astype(np.uint64, copy=False)
        if self.kind == "independent":
            return path_state(self.key, sample_id)
        pixel = pixel.astype(np.uint64, copy=False)
        index = sample_id - pixel * np.uint64(self.samples_per_pixel)
        low = np.uint64((1 << self.index_bits) - 1)
        return (mix64(pixel ^ self.key) & ~low) | index

    def pairs(self, state: np.ndarray, pair, dtype=np.float64) -> np.ndarray:
        """Uniforms for pair ``pair`` (an int, or one per path) of each path; shape (2, N)."""
        if self.kind == "independent":
            if isinstance(pair, (int, np.integer)):
                return uniform_pairs(state, int(pair), dtype)
            return uniform_pairs_at(state, pair, dtype)
        low = np.uint64((1 << self.index_bits) - 1)
        return sobol_pairs(state & ~low, (state & low).astype(np.uint32), self.samples_per_pixel, pair, dtype)


def _cos_2pi(u: np.ndarray) -> np.ndarray:
    """cos(2 pi u) evaluated in float32, returned as float64.

    NumPy's float32 cosine is a SIMD loop while its float64 one calls libm
    element by element: measured 7.6x faster for 64 Ki values here.  Its
    ~1e-7 error is far below what a sampled direction needs (directions are
    renormalised after scattering anyway).
    """
    return np.cos(((2.0 * np.pi) * u).astype(np.float32)).astype(u.dtype, copy=False)


def cos_sin_2pi(u: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """``cos(2 pi u)`` and ``sin(2 pi u)``: the cosine from the library (in
    float32, see :func:`_cos_2pi`), the sine as a signed square root, so one
    transcendental instead of two (sin >= 0 exactly when u <= 1/2; copysign,
    not where: the sign is random, and a branchy where mispredicts on every
    other element)."""
    c = _cos_2pi(u)
    return c, np.copysign(np.sqrt(np.maximum(0.0, 1.0 - c * c)), 0.5 - u)


def random_unit_vector(u1: np.ndarray, u2: np.ndarray) -> np.ndarray:
    """Directions uniform on the unit sphere from two uniforms.

    Archimedes: ``z = 1 - 2 u1`` is uniform in [-1, 1] for a uniform point on
    the sphere, and the azimuth is independent.  Exact and branch-free, unlike
    the rejection sampler of the book.

    Returns
    -------
    ndarray of shape (3, N)
    """
    z = 1.0 - 2.0 * u1
    r = np.sqrt(np.maximum(0.0, 1.0 - z * z))
    c, s = cos_sin_2pi(u2)
    return np.stack((r * c, r * s, z))


def random_in_unit_disk(u1: np.ndarray, u2: np.ndarray) -> np.ndarray:
    """Points uniform in the unit disk (``r = sqrt(u1)``); shape ``(2, N)``."""
    r = np.sqrt(u1)
    c, s = cos_sin_2pi(u2)
    return np.stack((r * c, r * s))

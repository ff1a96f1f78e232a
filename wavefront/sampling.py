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

Samplers take their uniforms as arguments and own no state, which is what lets
the tests feed them controlled numbers.
"""

from __future__ import annotations

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


def _cos_2pi(u: np.ndarray) -> np.ndarray:
    """cos(2 pi u) evaluated in float32, returned as float64.

    NumPy's float32 cosine is a SIMD loop while its float64 one calls libm
    element by element: measured 7.6x faster for 64 Ki values here.  Its
    ~1e-7 error is far below what a sampled direction needs (directions are
    renormalised after scattering anyway).
    """
    return np.cos(((2.0 * np.pi) * u).astype(np.float32)).astype(u.dtype, copy=False)


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
    # cos(phi) from the library, sin(phi) as a signed square root: one
    # transcendental instead of two (sin >= 0 exactly when u2 <= 1/2)
    c = _cos_2pi(u2)
    # copysign, not where: the mask is random, and a branchy where
    # mispredicts on every other element
    s = np.copysign(np.sqrt(np.maximum(0.0, 1.0 - c * c)), 0.5 - u2)
    return np.stack((r * c, r * s, z))


def random_in_unit_disk(u1: np.ndarray, u2: np.ndarray) -> np.ndarray:
    """Points uniform in the unit disk (``r = sqrt(u1)``); shape ``(2, N)``."""
    r = np.sqrt(u1)
    c = _cos_2pi(u2)
    s = np.copysign(np.sqrt(np.maximum(0.0, 1.0 - c * c)), 0.5 - u2)  # sin(phi) >= 0 when u2 <= 1/2
    return np.stack((r * c, r * s))

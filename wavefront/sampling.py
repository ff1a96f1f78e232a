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

_GOLDEN = np.uint64(0x9E3779B97F4A7C15)  # Weyl increment: 2^64 / golden ratio
_MIX_1 = np.uint64(0xBF58476D1CE4E5B9)
_MIX_2 = np.uint64(0x94D049BB133111EB)
_S30, _S27, _S31, _S11 = (np.uint64(s) for s in (30, 27, 31, 11))
_TO_UNIT = 2.0**-53  # 53 random bits -> a double in [0, 1)

# Dimensions 0..CAMERA_DIMENSIONS-1 belong to the camera (pixel jitter x, y and
# lens u, v); bounce b then owns BOUNCE_DIMENSIONS dimensions starting at
# CAMERA_DIMENSIONS + b * BOUNCE_DIMENSIONS.  Fixed blocks mean a sample draws
# the same number for the same decision however it was scheduled.
CAMERA_DIMENSIONS = 4
BOUNCE_DIMENSIONS = 4


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
    state = np.random.SeedSequence(int(seed)).generate_state(1, dtype=np.uint64)
    return np.uint64(state[0])


def path_state(key: np.uint64, sample_id: np.ndarray) -> np.ndarray:
    """Per-path hash state from the render key and global sample ids (uint64)."""
    return mix64(sample_id.astype(np.uint64, copy=False) ^ key)


def uniform(state: np.ndarray, dimension: int) -> np.ndarray:
    """Uniform doubles in ``[0, 1)``, one per path, for one ``dimension``.

    Parameters
    ----------
    state : ndarray of shape (N,), uint64
        From :func:`path_state`.
    dimension : int
        Which decision along the path this number is for.
    """
    offset = np.uint64((0x9E3779B97F4A7C15 * (dimension + 1)) & 0xFFFFFFFFFFFFFFFF)
    z = mix64(state + offset)
    return (z >> _S11).astype(np.float64) * _TO_UNIT


def bounce_dimension(depth: np.ndarray | int, k: int) -> np.ndarray | int:
    """Dimension of the ``k``-th number drawn at bounce ``depth``."""
    return CAMERA_DIMENSIONS + depth * BOUNCE_DIMENSIONS + k


def uniform_at(state: np.ndarray, dimension: np.ndarray) -> np.ndarray:
    """Like :func:`uniform` but with a per-path ``dimension`` array.

    A refilled wavefront mixes paths at different depths, so each row asks for
    its own dimension.
    """
    z = mix64(state + _GOLDEN * (dimension.astype(np.uint64) + np.uint64(1)))
    return (z >> _S11).astype(np.float64) * _TO_UNIT


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
    phi = (2.0 * np.pi) * u2
    return np.stack((r * np.cos(phi), r * np.sin(phi), z))


def random_in_unit_disk(u1: np.ndarray, u2: np.ndarray) -> np.ndarray:
    """Points uniform in the unit disk (``r = sqrt(u1)``); shape ``(2, N)``."""
    r = np.sqrt(u1)
    phi = (2.0 * np.pi) * u2
    return np.stack((r * np.cos(phi), r * np.sin(phi)))

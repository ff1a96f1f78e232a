"""Vector maths on structure-of-arrays batches.

Every vector batch here is an ``ndarray`` of shape ``(3, N)``: one row per
component, one column per ray.  That layout makes ``a[0] * b[0] + ...`` three
contiguous multiply-adds, about twice as fast as ``(N, 3)`` for the dot
products and normalisations that dominate a bounce.

Conventions follow "Ray Tracing in One Weekend": an incident direction ``v``
points *towards* the surface, a normal ``n`` is unit length, and
``reflect(v, n) = v - 2 (v.n) n``.
"""

from __future__ import annotations

import numpy as np


def dot(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """Column-wise dot product.

    Parameters
    ----------
    a, b : ndarray of shape (3, N) (or (3,) broadcasting against (3, N))

    Returns
    -------
    ndarray of shape (N,)
    """
    if a.ndim == b.ndim == 2 and max(a.shape[1], b.shape[1]) <= SMALL_DOT:
        # Few columns: two calls instead of five.  A reduction along the
        # first axis adds the rows in order, ((p0 + p1) + p2) as below, and
        # starting it from -0.0 keeps an all -0.0 sum's sign (its default
        # start, +0.0, does not): the same numbers, bit for bit.
        return _add_reduce(a * b, axis=0, initial=-0.0)
    # summed in place, in the same order: two (N,) temporaries fewer
    d = a[0] * b[0]
    d += a[1] * b[1]
    d += a[2] * b[2]
    return d


# Up to this many columns :func:`dot` multiplies whole (3, N) arrays and sums
# the rows in one reduction: 0.9 us a call against 1.6-2.2 at 1-100 columns
# (float64; float32 1.3 against 2.1-2.7), the same at ~2000, 1.7x slower at
# 32 Ki (the (3, N) product is a temporary three times the result's size).
# The tail after roulette calls it ~14 times a bounce.
SMALL_DOT = 1024
_add_reduce = np.add.reduce


def length(v: np.ndarray) -> np.ndarray:
    """Euclidean length of each column; shape ``(N,)``."""
    n = dot(v, v)
    return np.sqrt(n, out=n)


def normalize(v: np.ndarray, out: np.ndarray | None = None, squared_length: np.ndarray | None = None) -> np.ndarray:
    """Unit vectors along each column of ``v`` (shape ``(3, N)``), into
    ``out`` if given (which may be ``v`` itself: the same numbers, without
    a (3, N) temporary).  ``squared_length``, if given, is ``dot(v, v)``
    already taken (it is overwritten).

    A zero column stays zero instead of becoming NaN; callers that can produce
    degenerate vectors handle them explicitly before calling this.
    """
    n = length(v) if squared_length is None else np.sqrt(squared_length, out=squared_length)
    # 0 * (1 / tiny) = 0 keeps a zero column zero, without a branchy where
    np.maximum(n, np.finfo(n.dtype).tiny, out=n)
    return np.multiply(v, np.divide(1.0, n, out=n), out=out)


def reflect(v: np.ndarray, n: np.ndarray) -> np.ndarray:
    """Mirror ``v`` about the unit normal ``n``: ``v - 2 (v.n) n``.

    The tangential part of ``v`` is kept and the normal part flipped, so the
    angle of incidence equals the angle of reflection and ``|r| = |v|``.
    """
    r = dot(v, n)
    r *= 2.0
    r = r * n
    if r.dtype != np.result_type(v, r):
        return v - r
    return np.subtract(v, r, out=r)  # v - (2 (v.n)) n, as written, into the product's array


def refract(uv: np.ndarray, n: np.ndarray, eta_ratio: np.ndarray | float,
            cos_theta: np.ndarray | None = None) -> np.ndarray:
    """Refract unit direction ``uv`` through a surface with unit normal ``n``.

    ``n`` faces against ``uv`` (``uv.n <= 0``) and ``eta_ratio`` is
    ``eta_incident / eta_transmitted``.  The result splits into a part
    perpendicular to ``n`` (Snell's law scales the tangential component by
    ``eta_ratio``) and a part along ``-n`` that restores unit length.  Callers
    must have ruled out total internal reflection (``eta_ratio * sin_theta >
    1``); there the parallel part is clamped to zero rather than NaN.
    ``cos_theta``, if given, is ``min(-uv.n, 1)`` already computed (the
    glass kernel's), not computed again.
    """
    if cos_theta is None:
        cos_theta = np.minimum(-dot(uv, n), 1.0)
    if not uv.dtype == n.dtype == np.result_type(uv, n, cos_theta, eta_ratio):
        r_perp = eta_ratio * (uv + cos_theta * n)  # mixed precisions: promoted as written
        r_parallel = -np.sqrt(np.abs(1.0 - dot(r_perp, r_perp))) * n
        return r_perp + r_parallel
    # eta (uv + cos n) - sqrt|1 - |r_perp|^2| n in place, one (3, N) temporary
    # fewer than as written above (sums and products commute exactly: the
    # same numbers)
    r_perp = cos_theta * n
    r_perp += uv
    r_perp *= eta_ratio
    s = dot(r_perp, r_perp)
    np.subtract(1.0, s, out=s)
    np.abs(s, out=s)
    np.sqrt(s, out=s)
    np.negative(s, out=s)
    r_perp += s * n
    return r_perp


def schlick(cosine: np.ndarray, eta_ratio: np.ndarray | float) -> np.ndarray:
    """Schlick's approximation to the Fresnel reflectance.

    ``R(theta) = R0 + (1 - R0) (1 - cos theta)^5`` with
    ``R0 = ((1 - eta_ratio) / (1 + eta_ratio))^2``; ``R0`` depends only on the
    ratio of the two indices, so it is the same from either side.
    """
    r0 = ((1.0 - eta_ratio) / (1.0 + eta_ratio)) ** 2
    m = 1.0 - cosine
    m2 = m * m
    return r0 + (1.0 - r0) * (m2 * m2 * m)


# Gather and scatter.  Measured on this machine with NumPy 2.4 (64 Ki rays):
# ``a[:, idx]`` on a (3, N) array is ~6x slower than ``np.take(a, idx,
# axis=-1)``, a boolean-mask filter ``x[mask]`` ~8x slower than
# ``x.take(np.flatnonzero(mask))``, and ``acc[:, idx] += v`` ~4x slower than a
# take-add-put per row.  The hot path therefore gathers and scatters only
# through these two helpers.  The method ``a.take`` rather than ``np.take``,
# which dispatches through a Python wrapper: ~0.6 us a call, the same numbers.

def gather(a: np.ndarray, idx: np.ndarray) -> np.ndarray:
    """Columns ``idx`` of ``a`` (last axis), e.g. ``(3, N) -> (3, len(idx))``,
    or elements of a 1-D ``a``; ``idx`` in ``[-N, N)``, as ``a.take`` reads them.

    ``mode="wrap"``: for such indices the same elements as ``take``'s
    default ``"raise"``, which checks each index by a slower path: 54 Ki of
    64 Ki columns 60 against 80 us from a (3, N) float32 array, 20 against
    27 from a (N,) array of any type (int64 indices; NumPy 2.4).  Only an
    out-of-range index (a bug) goes unreported.  A negative index wraps
    through a loop: slow where many are (see ``KernelGroups``).
    """
    if a.ndim != 2 or a.flags.c_contiguous:
        return a.take(idx, axis=-1, mode=TAKE_MODE)
    # a (3, N) view of the first columns of a wider array (PathBatch.fill's):
    # ``take`` would copy it whole before gathering; row by row, each row is
    # contiguous and gathered where it lies
    out = np.empty((a.shape[0], len(idx)), dtype=a.dtype)
    for row, into in zip(a, out):
        row.take(idx, mode=TAKE_MODE, out=into)
    return out


TAKE_MODE = "wrap"  # see gather


def true_rows(mask: np.ndarray) -> np.ndarray:
    """Indices of the True elements of 1-D ``mask``: ``np.flatnonzero``'s
    answer through the method, without that function's two Python wrappers
    (~0.7 us of each call, ~17 calls a bounce: a few percent of a bounce of
    the tail's few paths)."""
    return mask.nonzero()[0]


def scatter_add(acc: np.ndarray, idx: np.ndarray, values: np.ndarray) -> None:
    """``acc[:, idx] += values`` for *unique* ``idx``; ``acc`` is (C, S)."""
    if idx.size >= ADD_AT_MIN and np.result_type(acc, values) == acc.dtype:
        # in acc's type first (exact: float32 to float64, as the mixed add
        # below promotes): add.at with a cast per element is ~20x slower
        values = values.astype(acc.dtype, copy=False)
        for row, value in zip(acc, values):
            _add_at(row, idx, value)  # one addition per (unique) index: the same sums
        return
    for row, value in zip(acc, values):
        row[idx] = row.take(idx) + value


# From this many indices ``np.add.at`` (fast on 1-D arrays since NumPy 1.25)
# beats a take, an add and a fancy assignment per row, measured on rows of a
# job's 280 Ki samples: 3 Ki indices 15 against 26 us, 30 Ki 232 against 503;
# equal at ~100, a little slower below.
ADD_AT_MIN = 128
_add_at = np.add.at


def scatter(acc: np.ndarray, idx: np.ndarray, values: np.ndarray) -> None:
    """``acc[:, idx] = values``, a row at a time (see :func:`gather`)."""
    for row, value in zip(acc, values):
        row[idx] = value

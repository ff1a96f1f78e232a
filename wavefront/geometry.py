"""What every shape shares: the ray's ``T_MIN``, the precision rule, and the
exact ray-sphere arithmetic.

The shapes themselves (spheres, quads, triangles, meshes) and their
structure-of-arrays sets live in :mod:`wavefront.shapes`; ``wavefront.accel``
builds one BVH over all of them with exactly the answers of brute force.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from .transform import Transform

T_MIN = 1e-3  # skip self-intersection at the ray's own origin (shadow acne)

# float32 is accurate enough when every point a ray can start from or reach
# (sphere extents, the camera, lights) lies within FLOAT32_EXTENT of the
# origin and no sphere is smaller than FLOAT32_MIN_RADIUS of that extent.
# Positions then round by at most ~3e-5, far below T_MIN, so surfaces stay
# free of acne (a ground of radius 1000 does not fit); and with
# :func:`sphere_roots`' error of ``eps |oc| / r`` of a radius, silhouettes
# move by at most ~1e-4 of the smallest sphere's radius.
FLOAT32_EXTENT = 256.0
FLOAT32_MIN_RADIUS = 1e-3

# Elements of one (spheres x rays) temporary; bounds the memory of brute force
# and keeps blocks in cache.
BLOCK_ELEMENTS = 1 << 18


def precision_for(radius: np.ndarray, extent: float) -> np.dtype:
    """float32 where it is accurate enough for these radii within ``extent``
    of the origin (see ``FLOAT32_EXTENT``), else float64."""
    radius = np.asarray(radius, dtype=np.float64)
    small = radius.min() if radius.size else np.inf
    fits = extent <= FLOAT32_EXTENT and small >= FLOAT32_MIN_RADIUS * extent
    return np.dtype(np.float32 if fits else np.float64)


@dataclass(frozen=True)
class Sphere:
    """A sphere with a material name (or index once a scene is compiled).

    ``transform`` (translate, rotate and uniform scale only) moves it from
    object space to world space when the scene is compiled.
    """

    center: tuple[float, float, float]
    radius: float
    material: str | int
    transform: Transform | None = None


def sphere_roots(center, radius_squared, origin, direction):
    """Both ray parameters where unit-direction rays meet spheres (broadcasting).

    With ``oc = c - o`` and ``|d| = 1`` the roots are ``h -/+ sqrt(r^2 - |l|^2)``
    where ``h = d.oc`` and ``l = oc - h d`` is the offset of the sphere's
    centre from the ray's line (Haines et al., "Precision Improvements for
    Ray/Sphere Intersection", Ray Tracing Gems, 2019).  The textbook
    discriminant ``h^2 - (|oc|^2 - r^2)`` subtracts two numbers of size
    ``|oc|^2`` to get one of size ``r^2``, so a small sphere far from the ray's
    origin loses ``(|oc| / r)^2`` of its digits: in float32 a ball of radius
    0.01 a hundred units away vanished.  Here the error is ``eps |oc| / r`` of
    the radius.  Both the brute-force and the BVH intersectors call this with
    the same operands, so they agree bit for bit.

    Returns ``(h, sqrt_disc)``: the roots are ``h - sqrt_disc`` and
    ``h + sqrt_disc``.  A miss (negative discriminant) yields a NaN
    ``sqrt_disc`` rather than a separate mask: every comparison with NaN is
    false, so :func:`nearest_root` turns it into ``inf`` with no extra pass.
    """
    ox = center[0] - origin[0]
    oy = center[1] - origin[1]
    oz = center[2] - origin[2]
    h = direction[0] * ox
    h += direction[1] * oy
    h += direction[2] * oz
    ox -= h * direction[0]  # now l
    oy -= h * direction[1]
    oz -= h * direction[2]
    ox *= ox
    oy *= oy
    oz *= oz
    disc = radius_squared - ox
    disc -= oy
    disc -= oz
    with np.errstate(invalid="ignore"):
        sqrt_disc = np.sqrt(disc)
    return h, sqrt_disc


def nearest_root(h, sqrt_disc):
    """The first root ``h -/+ sqrt_disc`` past ``T_MIN``; ``inf`` or NaN where there is none.

    Written without ``np.where``, which measured 2-4 ns per element here
    against ~0.1-0.2 ns for arithmetic: dividing a root's absolute value by
    the mask ``root > T_MIN`` keeps a valid root bit for bit (it is positive,
    divided by 1) and sends the others to ``inf`` (or NaN for 0/0 and for a
    miss's NaN); ``fmin``, which ignores NaN, then picks the near root when it
    is valid, since the far one is never nearer.  A NaN result compares false
    with everything, so callers treat it as a miss and reduce with ``fmin``.
    """
    near = h - sqrt_disc
    far = h + sqrt_disc
    near_valid, far_valid = near > T_MIN, far > T_MIN
    with np.errstate(divide="ignore", invalid="ignore"):
        np.abs(near, out=near)
        near /= near_valid
        np.abs(far, out=far)
        far /= far_valid
    return np.fmin(near, far, out=near)


def is_hit(t):
    """Whether a root from :func:`nearest_root` is a hit (false for inf and NaN)."""
    return t < np.inf


def escaped_at_inf(best_t, hit, t_max):
    """``best_t`` with ``inf`` where nothing was hit.  Without a finite
    ``t_max`` it is already ``inf`` there, and an ``np.where`` over every ray
    (~2 ns each) is skipped."""
    if np.ndim(t_max) == 0 and t_max == np.inf:
        return best_t
    return np.where(hit, best_t, np.inf)

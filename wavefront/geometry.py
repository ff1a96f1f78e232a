"""Spheres and ray-sphere intersection for whole batches of rays.

``SphereSet`` stores the scene's spheres structure-of-arrays and intersects
``(3, N)`` batches of unit-direction rays against all of them at once, the
spheres handled in blocks broadcast against the rays so the Python loop runs
over blocks of spheres, never over rays.  For scenes with many spheres
``wavefront.accel`` provides a BVH with the same interface and exactly the same
answers.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from .vecmath import dot, gather

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
    """A sphere with a material name (or index once a scene is compiled)."""

    center: tuple[float, float, float]
    radius: float
    material: str | int


@dataclass(slots=True)
class Hits:
    """Nearest hits of a ray batch.

    ``t`` is ``inf`` and ``sphere_idx`` is -1 where a ray escaped.
    """

    t: np.ndarray  # (N,)
    sphere_idx: np.ndarray  # (N,) int32


class SphereSet:
    """All spheres of a scene as arrays: ``center (3, M)``, ``radius (M,)``."""

    def __init__(self, center: np.ndarray, radius: np.ndarray, material_idx: np.ndarray, dtype=np.float64):
        center = np.asarray(center, dtype=np.float64).reshape(3, -1)
        radius = np.asarray(radius, dtype=np.float64)
        # derived terms in float64 first, then stored at the render's precision
        self.dtype = np.dtype(dtype)
        self.center = np.ascontiguousarray(center, dtype=dtype)
        self.radius = np.ascontiguousarray(radius, dtype=dtype)
        self.material_idx = np.ascontiguousarray(material_idx, dtype=np.int32)
        self.radius_squared = (radius * radius).astype(dtype)
        self.inverse_radius = (1.0 / radius).astype(dtype)

    def __len__(self) -> int:
        return self.radius.shape[0]

    def subset(self, idx: np.ndarray) -> SphereSet:
        """The spheres ``idx``, with the derived terms copied rather than
        recomputed from rounded centres, so a float32 subset intersects
        bit for bit as the whole set does."""
        part = object.__new__(SphereSet)
        for name, value in vars(self).items():  # every per-sphere array, whatever it is called
            setattr(part, name, np.ascontiguousarray(value[..., idx]) if isinstance(value, np.ndarray) else value)
        return part

    def intersect(self, origin: np.ndarray, direction: np.ndarray, t_max=np.inf) -> Hits:
        """Nearest hit with ``T_MIN < t < t_max`` for every ray.

        Parameters
        ----------
        origin, direction : ndarray of shape (3, N)
            ``direction`` must be unit length.
        t_max : float or ndarray of shape (N,)
        """
        return intersect_brute_force(self, origin, direction, t_max)

    def occluded(self, origin, direction, t_max) -> np.ndarray:
        """Whether anything lies strictly between ``T_MIN`` and ``t_max``."""
        return self.intersect(origin, direction, t_max).sphere_idx >= 0

    def surface(self, origin, direction, t, sphere):
        """Point, normal and front-face flag where rays hit ``sphere`` at ``t``.

        All arguments are for hitting rows only.  The returned normal faces
        against the ray (the book's ``set_face_normal``); ``front_face`` says
        whether the ray struck the outside.
        """
        d = direction
        point = origin + t * d
        outward = (point - gather(self.center, sphere)) * self.inverse_radius.take(sphere)
        front_face = dot(d, outward) < 0.0
        sign = 2 * front_face.astype(outward.dtype) - 1  # flip to face the ray; cheaper than a (3, N) where
        normal = outward * sign
        return point, normal, front_face, sphere


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


def intersect_brute_force(spheres: SphereSet, origin, direction, t_max=np.inf) -> Hits:
    """Test every ray against every sphere, a block of spheres at a time.

    The nearest sphere of a block is found with a ``min`` reduction and an
    integer blend (lowest index wins a tie) rather than ``argmin``, which is
    a slow, branchy loop along the first axis.
    """
    n = origin.shape[1]
    best_t = np.broadcast_to(np.asarray(t_max, dtype=origin.dtype), (n,)).copy()
    best_idx = np.full(n, -1, dtype=np.int64)
    m = len(spheres)
    block = max(1, min(m, BLOCK_ELEMENTS // max(n, 1)))
    for start in range(0, m, block):
        stop = min(m, start + block)
        t = nearest_root(*sphere_roots(spheres.center[:, start:stop, None], spheres.radius_squared[start:stop, None],
                                       origin[:, None, :], direction[:, None, :]))
        t_block = np.fmin.reduce(t, axis=0)  # fmin: a miss may be NaN
        # strict: an earlier block keeps a tie; false where nothing was hit
        closer = t_block < best_t
        for j in range(stop - start - 1, -1, -1):  # downwards, so the lowest index is written last
            take = closer & (t[j] == t_block)
            best_idx += take * (start + j - best_idx)
        best_t = np.fmin(best_t, t_block)
    return Hits(escaped_at_inf(best_t, best_idx >= 0, t_max), best_idx.astype(np.int32))


def escaped_at_inf(best_t, hit, t_max):
    """``best_t`` with ``inf`` where nothing was hit.  Without a finite
    ``t_max`` it is already ``inf`` there, and an ``np.where`` over every ray
    (~2 ns each) is skipped."""
    if np.ndim(t_max) == 0 and t_max == np.inf:
        return best_t
    return np.where(hit, best_t, np.inf)

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

from .vecmath import dot

T_MIN = 1e-3  # skip self-intersection at the ray's own origin (shadow acne)

# Elements of one (spheres x rays) temporary; bounds the memory of brute force
# and keeps blocks in cache.
BLOCK_ELEMENTS = 1 << 18


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

    def __init__(self, center: np.ndarray, radius: np.ndarray, material_idx: np.ndarray):
        self.center = np.ascontiguousarray(center, dtype=np.float64).reshape(3, -1)
        self.radius = np.ascontiguousarray(radius, dtype=np.float64)
        self.material_idx = np.ascontiguousarray(material_idx, dtype=np.int32)
        self.radius_squared = self.radius * self.radius

    def __len__(self) -> int:
        return self.radius.shape[0]

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

    def surface(self, origin, direction, hits: Hits, hit_idx: np.ndarray):
        """Point, outward normal and front-face flag of the given hit rows.

        The returned normal faces against the ray (the book's
        ``set_face_normal``); ``front_face`` says whether the ray struck the
        outside.
        """
        sphere = hits.sphere_idx[hit_idx]
        d = direction[:, hit_idx]
        point = origin[:, hit_idx] + hits.t[hit_idx] * d
        outward = (point - self.center[:, sphere]) / self.radius[sphere]
        front_face = dot(d, outward) < 0.0
        normal = np.where(front_face, outward, -outward)
        return point, normal, front_face, sphere


def sphere_roots(center, radius_squared, origin, direction):
    """Both ray parameters where rays meet spheres (broadcasting).

    Uses the geometric form of the discriminant, ``r^2 - |oc - (d.oc) d|^2``
    (Haines et al., Ray Tracing Gems ch. 7), which loses far less precision
    than ``b^2 - c`` when a ray passes a huge sphere such as a ground of
    radius 1000.  Returns ``(near, far, valid)``.
    """
    oc = center - origin
    h = dot(direction, oc)
    perp = oc - h * direction
    disc = radius_squared - dot(perp, perp)
    valid = disc >= 0.0
    sqrt_disc = np.sqrt(np.where(valid, disc, 0.0))
    return h - sqrt_disc, h + sqrt_disc, valid


def intersect_brute_force(spheres: SphereSet, origin, direction, t_max=np.inf) -> Hits:
    """Test every ray against every sphere, a block of spheres at a time."""
    n = origin.shape[1]
    best_t = np.full(n, np.inf)
    best_idx = np.full(n, -1, dtype=np.int32)
    limit = np.broadcast_to(np.asarray(t_max, dtype=np.float64), (n,))
    m = len(spheres)
    block = max(1, min(m, BLOCK_ELEMENTS // max(n, 1)))
    o = origin[:, None, :]
    d = direction[:, None, :]
    for start in range(0, m, block):
        stop = min(m, start + block)
        near, far, valid = sphere_roots(
            spheres.center[:, start:stop, None],
            spheres.radius_squared[start:stop, None],
            o,
            d,
        )
        t = np.where(near > T_MIN, near, far)
        t = np.where(valid & (t > T_MIN), t, np.inf)
        j = np.argmin(t, axis=0)
        tj = np.take_along_axis(t, j[None, :], axis=0)[0]
        closer = (tj < best_t) & (tj < limit)
        best_t = np.where(closer, tj, best_t)
        best_idx = np.where(closer, j.astype(np.int32) + start, best_idx)
    return Hits(best_t, best_idx)

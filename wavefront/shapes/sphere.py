"""Spheres as a shape kind (the sphere object itself is :class:`wavefront.geometry.Sphere`)."""

from __future__ import annotations

import numpy as np

from ..geometry import Sphere, nearest_root, sphere_roots
from ..vecmath import gather
from .base import ShapeKind

__all__ = ["Sphere", "SphereSet", "world_sphere"]


def world_sphere(sphere: Sphere) -> tuple[np.ndarray, float]:
    """Centre and radius in world space (``transform`` must be a similarity,
    which the scene loader and :func:`SphereSet.build` check)."""
    center = np.asarray(sphere.center, dtype=np.float64)
    if sphere.transform is None or sphere.transform.is_identity:
        return center, float(sphere.radius)
    scale = sphere.transform.uniform_scale()
    if scale is None:
        raise ValueError("a sphere's transform may only translate, rotate and scale uniformly")
    return sphere.transform.points(center[:, None])[:, 0], float(sphere.radius) * scale


class SphereSet(ShapeKind):
    """Spheres as arrays: ``center (3, M)``, ``radius (M,)``, at the render's precision."""

    FIELDS = ("center", "radius_squared")
    name = "sphere"

    def __init__(self, center, radius, material_idx, dtype=np.float64):
        center = np.asarray(center, dtype=np.float64).reshape(3, -1)
        radius = np.asarray(radius, dtype=np.float64)
        # derived terms in float64 first, then stored at the render's precision
        self.dtype = np.dtype(dtype)
        self.center = np.ascontiguousarray(center, dtype=dtype)
        self.radius = np.ascontiguousarray(radius, dtype=dtype)
        self.material_idx = np.ascontiguousarray(material_idx, dtype=np.int32)
        self.radius_squared = (radius * radius).astype(dtype)
        self.inverse_radius = (1.0 / radius).astype(dtype)

    @classmethod
    def build(cls, spheres: list[Sphere], material_idx, dtype) -> SphereSet:
        m = len(spheres)
        center = np.zeros((3, m))
        radius = np.zeros(m)
        for i, s in enumerate(spheres):  # per scene object, at compile time
            center[:, i], radius[i] = world_sphere(s)
        return cls(center, radius, material_idx, dtype)

    def bounds(self):
        c, r = self.center.astype(np.float64), self.radius.astype(np.float64)
        return c - r, c + r

    def bounding_sphere(self):
        return self.center.astype(np.float64), self.radius.astype(np.float64)

    @staticmethod
    def exact_t(center, radius_squared, origin, direction):
        """The first root past ``T_MIN`` (``inf`` or NaN for none): see
        :func:`wavefront.geometry.sphere_roots` for why this arithmetic."""
        return nearest_root(*sphere_roots(center, radius_squared, origin, direction))

    def surface(self, idx, origin, direction, t, uv: bool):
        point = origin + t * direction
        outward = (point - gather(self.center, idx)) * self.inverse_radius.take(idx)
        return point, outward, outward, (sphere_uv(outward) if uv else None)


def sphere_uv(outward: np.ndarray) -> np.ndarray:
    """RTOW's ``get_sphere_uv``: ``u`` is the angle around the y axis from
    x = -1, ``v`` the angle from y = -1, both scaled to [0, 1]."""
    theta = np.arccos(np.clip(-outward[1], -1.0, 1.0))
    phi = np.arctan2(-outward[2], outward[0]) + np.pi
    return np.stack((phi / (2 * np.pi), theta / np.pi))


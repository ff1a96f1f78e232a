"""Choosing the intersector for a scene: brute force or a BVH."""

from __future__ import annotations

from .geometry import SphereSet

# Below this many spheres, testing every ray against every sphere in a few
# broadcast blocks beats any hierarchy's bookkeeping.
BVH_THRESHOLD = 64


def build_intersector(spheres: SphereSet, extent: float | None = None):
    """The intersector for ``spheres``: brute force for few, a BVH for many.

    ``extent`` bounds the distance from the origin of every ray origin (the
    BVH pads its boxes by the rounding error of rays from that far).
    """
    if len(spheres) < BVH_THRESHOLD:
        return spheres
    from .bvh import SphereBVH

    return SphereBVH(spheres, extent)

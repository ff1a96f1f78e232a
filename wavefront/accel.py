"""Choosing the intersector for a scene: brute force or a BVH."""

from __future__ import annotations

from .shapes import Primitives

# Below this many primitives, testing every ray against every primitive in a
# few broadcast blocks beats any hierarchy's bookkeeping.  With brute force's
# float32 slab filter, random triangle soups (one core, a nearest-hit and a
# shadow query per ray) cost 416 / 926 / 1,779 ns per ray by brute force at
# 32 / 64 / 128 triangles and 555 / 820 / 1,138 ns through the BVH (without
# the filter brute force took 4,043 ns at 32).
BVH_THRESHOLD = 64


def build_intersector(primitives: Primitives, extent: float | None = None):
    """The intersector for ``primitives``: brute force for few, a BVH for many.

    Both answer ``intersect``, ``occluded`` and ``surface`` alike.  ``extent``
    bounds the distance from the origin of every ray origin (the BVH pads its
    boxes by the rounding error of rays from that far).
    """
    if len(primitives) < BVH_THRESHOLD:
        return primitives
    from .bvh import BVH

    return BVH(primitives, extent)

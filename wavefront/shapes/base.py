"""What every shape kind provides, and the records an intersection produces.

A shape kind (spheres, quads, triangles) stores its primitives
structure-of-arrays, the primitive along the last axis of every array, and
answers four questions:

* ``bounds()``: each primitive's axis-aligned box (float64), for the BVH build;
* ``bounding_sphere()``: a sphere holding every point the exact test can
  accept, for the BVH's conservative float32 pre-filter;
* ``exact_t(*fields, origin, direction)``: the one exact ray-primitive test,
  elementwise over broadcast operands, so brute force (a block of primitives
  against all rays) and the BVH (gathered (ray, primitive) pairs) run the same
  arithmetic on the same numbers and agree bit for bit;
* ``surface(idx, origin, direction, t)``: point, outward geometric and shading
  normals and ``uv`` where the rays hit.
"""

from __future__ import annotations

import copy
from dataclasses import dataclass
from typing import Protocol

import numpy as np


@dataclass(slots=True)
class Hits:
    """Nearest hits of a ray batch.

    ``t`` is ``inf`` and ``primitive_idx`` is -1 where a ray escaped.
    """

    t: np.ndarray  # (N,)
    primitive_idx: np.ndarray  # (N,) int32, the scene-wide primitive index


@dataclass(slots=True)
class SurfaceHits:
    """What a batch of rays hit: the one record every stage after intersection reads.

    Integrators read this, never a shape's arrays.  Normals face against the
    incoming ray (RTOW's ``set_face_normal``); ``front_face`` says whether the
    ray struck the outside (sphere) or the front side (quad: ``cross(u, v)``;
    triangle: ``cross(v1 - v0, v2 - v0)``).
    """

    point: np.ndarray  # (3, N)
    normal: np.ndarray  # (3, N) shading normal, unit, facing the ray
    geometric_normal: np.ndarray  # (3, N) unit, facing the ray
    front_face: np.ndarray  # (N,) bool
    material_idx: np.ndarray  # (N,) int32
    primitive_idx: np.ndarray  # (N,) int32
    uv: np.ndarray | None = None  # (2, N) surface coordinates; None when not asked for
    # Room for what light sampling and participating media will need: which
    # emitter was hit (-1: none) and the medium on each side.  Not filled yet.
    emitter_idx: np.ndarray | None = None
    medium_idx: np.ndarray | None = None

    def __len__(self) -> int:
        return self.front_face.shape[0]


class Intersector(Protocol):
    """What the integrators ask of a scene's geometry: brute force
    (:class:`~wavefront.shapes.Primitives`) and the BVH both answer it, alike."""

    material_idx: np.ndarray  # (M,) per primitive
    moving: bool  # whether some primitive moves (rays then carry a time; motion blur)

    def intersect(self, origin, direction, t_max=np.inf, time=None) -> Hits:
        """Nearest hit with ``T_MIN < t < t_max`` per ray; ``time (N,)`` in
        [0, 1) places moving spheres (``None``: every sphere at its ``center``)."""

    def occluded(self, origin, direction, t_max, time=None) -> np.ndarray:
        """Whether any hit has ``T_MIN < t < t_max`` (shadow rays)."""

    def surface(self, origin, direction, t, idx, uv: bool = False, time=None) -> SurfaceHits:
        """What the hitting rays hit."""


class ShapeKind:
    """Base of the structure-of-arrays shape sets (see the module docstring).

    ``FIELDS`` names the per-primitive arrays ``exact_t`` reads, in its
    argument order.
    """

    FIELDS: tuple[str, ...] = ()
    material_idx: np.ndarray

    def __len__(self) -> int:
        return self.material_idx.shape[0]

    def block(self, start: int, stop: int) -> list:
        """Fields of primitives ``start:stop`` shaped to broadcast against ``(3, 1, N)`` rays."""
        return [getattr(self, f)[..., start:stop, None] for f in self.FIELDS]

    def gather(self, idx: np.ndarray) -> list:
        """Fields of primitives ``idx``, one column per (ray, primitive) pair."""
        return [np.take(getattr(self, f), idx, axis=-1) for f in self.FIELDS]

    def t_block(self, start: int, stop: int, origin, direction, time=None) -> np.ndarray:
        """``(stop - start, N)`` hit distances of every ray against a block of
        primitives (``time``: the rays' times, for kinds that move)."""
        return self.exact_t(*self.block(start, stop), origin[:, None, :], direction[:, None, :])

    def key_block(self, start: int, stop: int, origin, direction, time=None) -> np.ndarray | None:
        """:meth:`t_block` as keys of :func:`~wavefront.geometry.nearest_root_key`
        (unsigned, ordered as the hits, every non-hit above them), or None
        where a kind has no such form (then brute force reads :meth:`t_block`)."""
        return None

    def t_pairs(self, idx: np.ndarray, origin, direction, time=None) -> np.ndarray:
        """``(P,)`` hit distances of pairs: ray ``p`` (a column of ``origin``) against primitive ``idx[p]``."""
        return self.exact_t(*self.gather(idx), origin, direction)

    def any_hit_block(self, start: int, stop: int, origin, direction, t_max, time=None) -> np.ndarray:
        """``(N,)`` whether each ray meets some primitive of ``start:stop`` at
        ``T_MIN < t < t_max (N,)``: exactly whether :meth:`t_block`'s nearest
        hit is below ``t_max`` (a kind may answer it with less arithmetic)."""
        return (self.t_block(start, stop, origin, direction, time) < t_max).any(axis=0)  # NaN compares false

    def subset(self, idx: np.ndarray):
        """The primitives ``idx``, every per-primitive array copied (never
        recomputed from rounded values, so a subset intersects bit for bit as
        the whole set does)."""
        part = copy.copy(self)
        m = len(self)
        for name, value in vars(self).items():
            if isinstance(value, np.ndarray) and value.ndim and value.shape[-1] == m:
                setattr(part, name, np.ascontiguousarray(np.take(value, idx, axis=-1)))
        return part

    @staticmethod
    def exact_t(*args):  # pragma: no cover - every kind overrides it
        raise NotImplementedError


def in_box(point, lo, hi):
    """Whether each point lies in its (padded) box; elementwise, broadcasting."""
    inside = (point[0] >= lo[0]) & (point[0] <= hi[0])
    inside &= (point[1] >= lo[1]) & (point[1] <= hi[1])
    inside &= (point[2] >= lo[2]) & (point[2] <= hi[2])
    return inside


def exact_pad(dtype, extent: float) -> float:
    """How far outside its box a flat primitive's hit point may be computed.

    ``o + t d`` rounds by a few epsilons of ``|o| + t``, both within
    ``extent``; the quad and triangle tests accept a hit only inside their box
    grown by this much, so a hit found by rounding on a grazing or sliver
    primitive can never lie outside the (more widely padded) BVH boxes.
    """
    return 16.0 * float(np.finfo(dtype).eps) * max(extent, 1.0)


def pad_extent(dtype, pad: float) -> float:
    """The ``max(extent, 1)`` that :func:`exact_pad` grew a flat kind's boxes for."""
    return pad / (16.0 * float(np.finfo(dtype).eps))


def float32_down(x) -> np.ndarray:
    """``x`` in float32, rounded towards -inf (a lower bound that stays one)."""
    return np.nextafter(np.asarray(x).astype(np.float32), np.float32(-np.inf))


def float32_up(x) -> np.ndarray:
    """``x`` in float32, rounded towards +inf."""
    return np.nextafter(np.asarray(x).astype(np.float32), np.float32(np.inf))


def box_bounding_sphere(lo, hi):
    """The sphere through the corners of each box: holds every point of the box."""
    center = 0.5 * (lo + hi)
    half = 0.5 * (hi - lo)
    return center, np.sqrt(half[0] * half[0] + half[1] * half[1] + half[2] * half[2])

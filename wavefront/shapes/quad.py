"""Quads (parallelograms): the points ``corner + a u + b v`` with ``0 <= a, b <= 1``, as RTOW book 2's ``quad``."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

import math

from ..geometry import T_MIN, check_world_flat, material_field, position
from ..transform import Transform, transform_field
from ..validation import fail
from ..vecmath import gather
from .base import ShapeKind, box_bounding_sphere, exact_pad

Vec3 = tuple[float, float, float]


@dataclass(frozen=True)
class Quad:
    """A parallelogram; its front side (the side it emits from) is ``cross(u, v)``'s.

    ``corner``, ``u`` and ``v`` are three finite numbers each, ``u`` not
    parallel to ``v``; ``material`` a name or index; ``transform`` as for
    :class:`~wavefront.geometry.Sphere` but any steps.  Invalid values raise
    :class:`~wavefront.validation.SceneError` naming the field.
    """

    corner: Vec3
    u: Vec3
    v: Vec3
    material: str | int
    transform: Transform | None = None

    def __post_init__(self):
        set_field = object.__setattr__
        for key in ("corner", "u", "v"):
            set_field(self, key, position(self, getattr(self, key), key))
        set_field(self, "material", material_field(self, self.material))
        set_field(self, "transform", transform_field(self, self.transform, "transform"))
        if not _spans_a_plane(self.u, self.v):
            fail(self, "", _flat_problem("quad", self.u, self.v, "degenerate quad: u and v are parallel (or zero)"))
        if self.transform is not None:
            check_world_flat(self, np.stack(self.world()), "quad")

    def world(self) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """``corner, u, v`` in world space, each of shape (3,).  A mirroring
        transform swaps ``u`` and ``v``, so that the front side (``cross(u,
        v)``) stays the mirror image of the object's front side (pbrt's
        ``transformSwapsHandedness``), as a mirrored triangle's and box's do;
        the quad's ``(a, b)`` coordinates swap with them."""
        q, u, v = (np.asarray(x, dtype=np.float64) for x in (self.corner, self.u, self.v))
        if self.transform is None:
            return q, u, v
        q, u, v = (self.transform.points(q[:, None])[:, 0], self.transform.vectors(u[:, None])[:, 0],
                   self.transform.vectors(v[:, None])[:, 0])
        return (q, v, u) if np.linalg.det(self.transform.array[:3, :3]) < 0 else (q, u, v)


def _cross(a, b):
    return (a[1] * b[2] - a[2] * b[1], a[2] * b[0] - a[0] * b[2], a[0] * b[1] - a[1] * b[0])


def _flat_problem(kind: str, a, b, degenerate: str) -> str:
    """Why two edges do not span a usable plane: parallel, or an area float64 cannot hold."""
    c = _cross(a, b)
    area_squared = c[0] * c[0] + c[1] * c[1] + c[2] * c[2]
    if not math.isfinite(area_squared):
        return f"{kind} too large: its area squared overflows float64 (keep edges below about 1e77)"
    if area_squared == 0.0 and math.hypot(*c) > 0.0:
        return f"{kind} too small: its area squared underflows float64 (keep edges above about 1e-77)"
    return degenerate


def _spans_a_plane(a, b) -> bool:
    """Whether ``a`` and ``b`` are far enough from parallel to span a plane,
    with ``|a x b|^2`` (what the ray tests compute) neither underflowing to 0
    nor overflowing: edges of 1e-266 are not parallel, but their area is 0
    in float64."""
    c = _cross(a, b)
    area_squared = c[0] * c[0] + c[1] * c[1] + c[2] * c[2]
    return (math.isfinite(area_squared) and area_squared > 0.0
            and math.sqrt(area_squared) > 1e-12 * math.hypot(*a) * math.hypot(*b))


@dataclass(frozen=True)
class Box:
    """An axis-aligned box in object space, ``min < max`` on every axis, made
    of six quads with outward normals (:meth:`quads`)."""

    min: Vec3
    max: Vec3
    material: str | int
    transform: Transform | None = None

    def __post_init__(self):
        set_field = object.__setattr__
        set_field(self, "min", position(self, self.min, "min"))
        set_field(self, "max", position(self, self.max, "max"))
        set_field(self, "material", material_field(self, self.material))
        set_field(self, "transform", transform_field(self, self.transform, "transform"))
        if not all(a < b for a, b in zip(self.min, self.max)):
            fail(self, "max", f"must exceed min on every axis (min {list(self.min)}, max {list(self.max)})")
        if self.transform is not None:
            for face in self.quads():
                check_world_flat(self, np.stack(face.world()), "box")

    def quads(self) -> list[Quad]:
        return box_quads(self.min, self.max, self.material, self.transform)


def box_quads(lo, hi, material, transform: Transform | None = None) -> list[Quad]:
    """The six faces of the box ``[lo, hi]``, each ``cross(u, v)`` pointing out
    (RTOW book 2's ``box``, with the faces' orientations made outward)."""
    (x0, y0, z0), (x1, y1, z1) = lo, hi
    dx, dy, dz = (x1 - x0, 0.0, 0.0), (0.0, y1 - y0, 0.0), (0.0, 0.0, z1 - z0)
    neg = lambda a: tuple(-c for c in a)  # noqa: E731
    faces = [
        ((x0, y0, z1), dx, dy),  # front (+z)
        ((x1, y0, z1), neg(dz), dy),  # right (+x)
        ((x1, y0, z0), neg(dx), dy),  # back (-z)
        ((x0, y0, z0), dz, dy),  # left (-x)
        ((x0, y1, z1), dx, neg(dz)),  # top (+y)
        ((x0, y0, z0), dx, dz),  # bottom (-y)
    ]
    # A mirroring transform (negative determinant) would turn every cross(u, v)
    # inwards; each face's Quad.world() swaps u and v then, so the faces stay
    # outward in world space (an emissive box lights its outside, a box of fog
    # is entered from outside).
    return [Quad(corner, u, v, material, transform) for corner, u, v in faces]


class QuadSet(ShapeKind):
    """Quads as arrays, at the render's precision: ``corner, u, v, normal (3, M)``, ``offset (M,)``.

    RTOW's planar coordinates are ``a = w . (q x v)`` and ``b = w . (u x q)``
    with ``w = n / (n . n)`` and ``q`` the hit point less the corner; by the
    scalar triple product they are ``q . (v x w)`` and ``q . (w x u)``, so
    ``alpha_axis = v x w`` and ``beta_axis = w x u`` are computed once per quad
    and a ray needs two dot products instead of two cross products (the quad
    test was ~80 % of the Cornell box's render).
    """

    FIELDS = ("corner", "normal", "offset", "alpha_axis", "beta_axis", "box_lo", "box_hi")
    name = "quad"

    def __init__(self, corner, u, v, material_idx, dtype=np.float64, extent: float = 1.0):
        corner, u, v = (np.asarray(a, dtype=np.float64).reshape(3, -1) for a in (corner, u, v))
        n = np.cross(u, v, axis=0)
        area = np.linalg.norm(n, axis=0)
        if (area <= 0).any() or not np.isfinite(area).all():
            raise ValueError("a quad's u and v must not be parallel")
        normal = n / area
        corners = np.stack((corner, corner + u, corner + v, corner + u + v))
        pad = exact_pad(dtype, extent)
        self.dtype = np.dtype(dtype)
        self.pad = pad
        # derived terms in float64 first, then stored at the render's precision
        store = lambda a: np.ascontiguousarray(a, dtype=dtype)  # noqa: E731
        self.corner, self.u, self.v, self.normal = store(corner), store(u), store(v), store(normal)
        self.offset = store((normal * corner).sum(axis=0))  # the plane is normal . p = offset
        w = n / (area * area)  # RTOW's w = n / (n . n)
        self.alpha_axis = store(np.cross(v, w, axis=0))
        self.beta_axis = store(np.cross(w, u, axis=0))
        self.bounds_lo, self.bounds_hi = corners.min(axis=0), corners.max(axis=0)
        self.box_lo, self.box_hi = store(self.bounds_lo - pad), store(self.bounds_hi + pad)
        self.material_idx = np.ascontiguousarray(material_idx, dtype=np.int32)
        # The exact test's fields as 19 rows of one array (each field a view of
        # its rows), so the (ray, quad) pairs of brute force's filter and of the
        # BVH gather them in one call: 4,309 pairs of the Cornell box took 42 us
        # so, 154 us as seven gathers (in isolation; whole renders ~2 % faster).
        self._set_rows(np.concatenate([np.atleast_2d(getattr(self, f)) for f in self.FIELDS]))

    def _set_rows(self, rows: np.ndarray) -> None:
        """Hold ``rows`` (19, M) contiguous and make each field a view of its rows."""
        self.field_rows = np.ascontiguousarray(rows)
        (self.corner, self.normal, self.offset, self.alpha_axis, self.beta_axis, self.box_lo,
         self.box_hi) = self._split(self.field_rows)

    @staticmethod
    def _split(rows):
        """``corner, normal, offset, alpha_axis, beta_axis, box_lo, box_hi`` (``FIELDS``) from their 19 rows."""
        return rows[0:3], rows[3:6], rows[6], rows[7:10], rows[10:13], rows[13:16], rows[16:19]

    def gather(self, idx: np.ndarray) -> list:
        return list(self._split(self.field_rows.take(idx, axis=1)))  # (19, P)

    def subset(self, idx: np.ndarray):
        part = super().subset(idx)
        part._set_rows(np.take(self.field_rows, idx, axis=-1))
        return part

    @classmethod
    def build(cls, quads: list[Quad], material_idx, dtype, extent) -> QuadSet:
        world = [q.world() for q in quads]  # per scene object, at compile time
        corner, u, v = (np.array([w[k] for w in world], dtype=np.float64).reshape(-1, 3).T for k in range(3))
        return cls(corner, u, v, material_idx, dtype, extent)

    def bounds(self):
        return self.bounds_lo, self.bounds_hi

    def bounding_sphere(self):
        return box_bounding_sphere(self.box_lo.astype(np.float64), self.box_hi.astype(np.float64))

    @staticmethod
    def planar(corner, alpha_axis, beta_axis, px, py, pz):
        """RTOW's planar coordinates (a, b) of points in the quad's plane."""
        qx, qy, qz = px - corner[0], py - corner[1], pz - corner[2]
        a = qx * alpha_axis[0] + qy * alpha_axis[1] + qz * alpha_axis[2]
        b = qx * beta_axis[0] + qy * beta_axis[1] + qz * beta_axis[2]
        return a, b

    @staticmethod
    def exact_t(corner, normal, offset, alpha_axis, beta_axis, box_lo, box_hi, origin, direction):
        """RTOW's ray-quad test, plus the hit point inside the quad's padded
        box (see :func:`wavefront.shapes.base.exact_pad`); ``inf`` for a miss.

        The sums run in place but in the order of the textbook expressions
        (``n . d = (n0 d0 + n1 d1) + n2 d2``, ``t = (offset - n . o) / (n . d)``,
        ``p = o + t d``, ``a = (p - corner) . alpha_axis``), so every result is
        the same bit for bit (``tests/test_primitives.py`` checks it against
        the textbook expressions).  Fewer temporaries: on the Cornell box's
        4,309 exact pairs of one batch 73-99 -> 65 us, on a block of its 18
        quads x 4,096 rays 2.9 -> 2.1 ms.
        """
        t = QuadSet.plane_t(normal, offset, origin, direction)
        return QuadSet.accept(t, corner, alpha_axis, beta_axis, box_lo, box_hi, origin, direction)

    @staticmethod
    def plane_t(normal, offset, origin, direction):
        """Where the rays meet the quads' planes: the first half of :meth:`exact_t`."""
        denom = normal[0] * direction[0]
        denom += normal[1] * direction[1]
        denom += normal[2] * direction[2]
        t = normal[0] * origin[0]
        t += normal[1] * origin[1]
        t += normal[2] * origin[2]
        np.subtract(offset, t, out=t)
        # a ray in (or all but in) the plane gives inf or NaN, and fails every test of accept()
        with np.errstate(divide="ignore", invalid="ignore", over="ignore"):
            t /= denom
        return t

    @staticmethod
    def accept(t, corner, alpha_axis, beta_axis, box_lo, box_hi, origin, direction):
        """``t`` where it is past ``T_MIN`` and the point there inside the quad
        and its padded box, else ``inf``: the second half of :meth:`exact_t`."""
        with np.errstate(invalid="ignore", over="ignore"):
            ok = t > T_MIN
            axes = []
            for k in range(3):
                p = t * direction[k]
                p += origin[k]
                ok &= p >= box_lo[k]
                ok &= p <= box_hi[k]
                p -= corner[k]  # now q = p - corner
                axes.append(p)
            qx, qy, qz = axes
            for axis in (alpha_axis, beta_axis):
                c = qx * axis[0]
                c += qy * axis[1]
                c += qz * axis[2]
                ok &= c >= 0
                ok &= c <= 1
        return np.where(ok, t, np.inf)

    def t_pairs(self, idx, origin, direction, time=None):
        """:meth:`exact_t` pair by pair, the point-in-quad half only where the
        plane is met past ``T_MIN`` (elsewhere it would answer ``inf`` too).
        A ray leaving a surface meets that surface's plane at ``t`` ~ 0: in the
        Cornell box ~0.9 of the ~2.2 quads per ray that brute force's filter
        keeps (~1.0 of ~1.7 for shadow rays) are its own quad's plane."""
        rows = self.field_rows
        t = self.plane_t(rows[3:6].take(idx, axis=1), rows[6].take(idx), origin, direction)
        past = np.flatnonzero(t > T_MIN)  # NaN compares false
        if past.size == t.size:
            return self.accept(t, *self._accept_fields(idx), origin, direction)
        out = np.full(t.shape, np.inf, dtype=t.dtype)
        if past.size:
            out[past] = self.accept(t.take(past), *self._accept_fields(idx.take(past)), origin.take(past, axis=1),
                                    direction.take(past, axis=1))
        return out

    def _accept_fields(self, idx):
        corner, _, _, alpha_axis, beta_axis, box_lo, box_hi = self.gather(idx)
        return corner, alpha_axis, beta_axis, box_lo, box_hi

    def surface(self, idx, origin, direction, t, uv: bool, time=None):
        point = origin + t * direction
        outward = gather(self.normal, idx)
        coords = None
        if uv:
            a, b = self.planar(gather(self.corner, idx), gather(self.alpha_axis, idx), gather(self.beta_axis, idx),
                               *point)
            coords = np.stack((a, b))
        return point, outward, outward, coords

"""Triangles, from a scene's ``triangles:`` list or from mesh files.

Their exact test is Möller and Trumbore's ("Fast, Minimum Storage Ray/Triangle
Intersection", 1997) at the render's precision, float64 for any scene with
flat shapes (see :func:`wavefront.scene.precision_of`), with the hit point
required inside the triangle's padded box so that the BVH can never cull a
hit that brute force finds.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from ..geometry import T_MIN, check_world_flat, material_field, position
from ..transform import Transform, transform_field
from ..validation import describe, fail
from ..vecmath import gather, normalize
from .base import ShapeKind, box_bounding_sphere, exact_pad, in_box

Vec3 = tuple[float, float, float]


@dataclass(frozen=True)
class Triangle:
    """A triangle; its front side is that of ``cross(v1 - v0, v2 - v0)``.

    ``vertices`` are three points, not collinear; ``material`` a name or
    index; ``transform`` any steps.  Invalid values raise
    :class:`~wavefront.validation.SceneError` naming the field.
    """

    vertices: tuple[Vec3, Vec3, Vec3]
    material: str | int
    transform: Transform | None = None

    def __post_init__(self):
        from .quad import _flat_problem, _spans_a_plane

        set_field = object.__setattr__
        vertices = self.vertices
        if not isinstance(vertices, (list, tuple)) or len(vertices) != 3:
            fail(self, "vertices", f"expected a list of 3 points, got {describe(vertices)}")
        v0, v1, v2 = (position(self, p, f"vertices[{k}]") for k, p in enumerate(vertices))
        set_field(self, "vertices", (v0, v1, v2))
        set_field(self, "material", material_field(self, self.material))
        set_field(self, "transform", transform_field(self, self.transform, "transform"))
        e1, e2 = tuple(b - a for a, b in zip(v0, v1)), tuple(b - a for a, b in zip(v0, v2))
        if not _spans_a_plane(e1, e2):
            fail(self, "vertices", _flat_problem("triangle", e1, e2,
                                                 "zero-area triangle (its vertices are collinear or repeated)"))
        if self.transform is not None:
            w = self.world()
            check_world_flat(self, np.stack((w[0], w[1] - w[0], w[2] - w[0])), "triangle")

    def world(self) -> np.ndarray:
        """The vertices in world space, shape (3 vertices, 3 coordinates); a
        mirroring transform swaps ``v1`` and ``v2``, so that the front side
        stays the mirror image of the object's front side (pbrt's
        ``transformSwapsHandedness``), as a mirrored box's faces stay outward."""
        v = np.asarray(self.vertices, dtype=np.float64)
        if self.transform is None:
            return v
        w = self.transform.points(v.T).T
        return w[[0, 2, 1]] if np.linalg.det(self.transform.array[:3, :3]) < 0 else w


def twice_area(v0, v1, v2) -> np.ndarray:
    """``|cross(v1 - v0, v2 - v0)|`` of ``(3, M)`` vertex arrays."""
    return np.linalg.norm(np.cross(v1 - v0, v2 - v0, axis=0), axis=0)


class TriangleSet(ShapeKind):
    """Triangles as arrays: ``v0, e1 = v1 - v0, e2 = v2 - v0 (3, M)``.

    ``vertex_normal (3 vertices, 3, M)`` holds per-vertex shading normals
    (None: every triangle flat); ``vertex_uv (3 vertices, 2, M)`` the file's
    texture coordinates (None: the barycentrics are the uv).
    """

    FIELDS = ("v0", "e1", "e2", "box_lo", "box_hi")
    name = "triangle"

    def __init__(self, v0, v1, v2, material_idx, dtype=np.float64, extent: float = 1.0,
                 vertex_normal=None, vertex_uv=None):
        v0, v1, v2 = (np.asarray(a, dtype=np.float64).reshape(3, -1) for a in (v0, v1, v2))
        n = np.cross(v1 - v0, v2 - v0, axis=0)
        area = np.linalg.norm(n, axis=0)
        if (area <= 0).any() or not np.isfinite(area).all():
            raise ValueError("a triangle has zero area")
        pad = exact_pad(dtype, extent)
        store = lambda a: np.ascontiguousarray(a, dtype=dtype)  # noqa: E731
        self.dtype = np.dtype(dtype)
        self.pad = pad
        self.normal = store(n / area)
        self.bounds_lo = np.minimum(np.minimum(v0, v1), v2)
        self.bounds_hi = np.maximum(np.maximum(v0, v1), v2)
        self._set_packed(np.concatenate((v0, v1 - v0, v2 - v0, self.bounds_lo - pad, self.bounds_hi + pad)).T
                         .astype(dtype))
        self.vertex_normal = None if vertex_normal is None else store(vertex_normal)
        self.vertex_uv = None if vertex_uv is None else store(vertex_uv)
        self.material_idx = np.ascontiguousarray(material_idx, dtype=np.int32)

    def _set_packed(self, packed: np.ndarray) -> None:
        """The exact test's fields, one row of 15 per triangle (v0, e1, e2,
        box_lo, box_hi): the BVH gathers a candidate's fields from one or two
        cache lines instead of fifteen rows megabytes apart.  ``v0`` etc. are
        ``(3, M)`` views of it, for brute force's blocks."""
        self.packed = np.ascontiguousarray(packed)
        self.v0, self.e1, self.e2, self.box_lo, self.box_hi = (self.packed[:, i:i + 3].T for i in range(0, 15, 3))

    def gather(self, idx: np.ndarray) -> list:
        # whole rows (one or two cache lines each), then one transposed copy: the exact test's
        # ~50 operations ran ~10 % faster on contiguous fields than on the rows' strided view
        rows = np.take(self.packed, idx, axis=0)
        fields = np.empty(rows.shape[::-1], dtype=rows.dtype)  # (15, P)
        np.copyto(fields, rows.T)
        return [fields[i:i + 3] for i in range(0, 15, 3)]

    def subset(self, idx: np.ndarray):
        part = super().subset(idx)
        part._set_packed(np.take(self.packed, idx, axis=0))
        return part

    def bounds(self):
        return self.bounds_lo, self.bounds_hi

    def bounding_sphere(self):
        return box_bounding_sphere(self.box_lo.astype(np.float64), self.box_hi.astype(np.float64))

    @staticmethod
    def moller_trumbore(v0, e1, e2, origin, direction):
        """``(t, b1, b2)``: the ray parameter and the barycentrics of v1 and v2."""
        dx, dy, dz = direction[0], direction[1], direction[2]
        px = dy * e2[2] - dz * e2[1]
        py = dz * e2[0] - dx * e2[2]
        pz = dx * e2[1] - dy * e2[0]
        det = e1[0] * px + e1[1] * py + e1[2] * pz
        with np.errstate(divide="ignore", invalid="ignore"):
            inv = 1.0 / det  # a ray in the triangle's plane: inf, and NaN below, which fails every test
            sx, sy, sz = origin[0] - v0[0], origin[1] - v0[1], origin[2] - v0[2]
            b1 = (sx * px + sy * py + sz * pz) * inv
            qx = sy * e1[2] - sz * e1[1]
            qy = sz * e1[0] - sx * e1[2]
            qz = sx * e1[1] - sy * e1[0]
            b2 = (dx * qx + dy * qy + dz * qz) * inv
            t = (e2[0] * qx + e2[1] * qy + e2[2] * qz) * inv
        return t, b1, b2

    @staticmethod
    def exact_t(v0, e1, e2, box_lo, box_hi, origin, direction):
        t, b1, b2 = TriangleSet.moller_trumbore(v0, e1, e2, origin, direction)
        with np.errstate(invalid="ignore"):
            p = (origin[0] + t * direction[0], origin[1] + t * direction[1], origin[2] + t * direction[2])
            ok = (t > T_MIN) & (b1 >= 0) & (b2 >= 0) & (b1 + b2 <= 1) & in_box(p, box_lo, box_hi)
        return np.where(ok, t, np.inf)

    def surface(self, idx, origin, direction, t, uv: bool, time=None):
        point = origin + t * direction
        outward = gather(self.normal, idx)
        shading = outward
        b1 = b2 = None
        if self.vertex_normal is not None or uv:
            _, b1, b2 = self.moller_trumbore(gather(self.v0, idx), gather(self.e1, idx), gather(self.e2, idx),
                                             origin, direction)
            b0 = 1.0 - b1 - b2
        if self.vertex_normal is not None:
            vn = np.take(self.vertex_normal, idx, axis=-1)
            shading = normalize(b0 * vn[0] + b1 * vn[1] + b2 * vn[2])
            # A file's normals opposite its winding (or vertices disagreeing) would shade the
            # surface's other side, black under a lamp: turned into the face's hemisphere, as
            # pbrt keeps the two normals together; none left (they cancel), the face's own.
            cos = shading[0] * outward[0] + shading[1] * outward[1] + shading[2] * outward[2]
            turn = np.flatnonzero(~(cos > 0))
            if turn.size:
                shading[:, turn] = np.where(cos[turn] < 0, -shading[:, turn], outward[:, turn])
        coords = None
        if uv:
            if self.vertex_uv is None:
                coords = np.stack((b1, b2))
            else:
                vt = np.take(self.vertex_uv, idx, axis=-1)
                coords = b0 * vt[0] + b1 * vt[1] + b2 * vt[2]
        return point, outward, shading, coords

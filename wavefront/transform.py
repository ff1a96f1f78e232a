"""Affine transforms from object space to world space (``world_from_object``).

A scene file gives a shape's transform as a list of steps applied first to
last (``translate``, ``rotate`` about an axis by degrees, ``scale``); they
compose into one 4x4 matrix, applied once when the scene is compiled, so the
wavefront only ever sees world-space shapes.  Names follow pbrt-v4:
``world_from_object`` maps object-space points to world space.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field

import numpy as np

from .validation import SceneError, number, vec3


def _identity() -> tuple:
    return tuple(tuple(float(i == j) for j in range(4)) for i in range(4))


@dataclass(frozen=True)
class Transform:
    """An affine map, stored as its 4x4 matrix (row-major tuples, so the
    object stays hashable and comparable like the rest of a :class:`Scene`)."""

    matrix: tuple = field(default_factory=_identity)

    def __post_init__(self):
        if np.shape(self.matrix) != (4, 4):  # the rest of the class reads a 4x4 matrix
            raise SceneError("<Transform>", "matrix", f"expected a 4x4 matrix, got shape {np.shape(self.matrix)}")

    @staticmethod
    def from_array(m: np.ndarray) -> Transform:
        """The transform of a 4x4 matrix (not checked for NaN or infinity:
        :meth:`then` reports overflow through the shape that uses it)."""
        return Transform(tuple(tuple(float(x) for x in row) for row in np.asarray(m, dtype=np.float64)))

    @property
    def array(self) -> np.ndarray:
        return np.array(self.matrix, dtype=np.float64)

    @staticmethod
    def translate(offset) -> Transform:
        """Translation by ``offset``, three finite numbers."""
        m = np.eye(4)
        m[:3, 3] = _argument("translate", vec3, offset, "offset")
        return Transform.from_array(m)

    @staticmethod
    def scale(factor) -> Transform:
        """Scale by ``factor``: one number (uniform) or three, finite and non-zero."""
        if isinstance(factor, np.ndarray) and factor.ndim == 0:
            factor = factor.item()
        if isinstance(factor, (list, tuple)) or np.ndim(factor) > 0:
            factor = _argument("scale", vec3, factor, "factor")
        else:
            factor = (_argument("scale", number, factor, "factor"),) * 3
        if 0.0 in factor:
            raise SceneError("<Transform.scale>", "factor", "must not be zero (it would flatten the shape)")
        m = np.eye(4)
        m[:3, :3] = np.diag(factor)
        return Transform.from_array(m)

    @staticmethod
    def rotate(axis, angle_degrees: float) -> Transform:
        """Rotation by ``angle_degrees`` (finite) about ``axis`` (three finite
        numbers, not all zero), right-hand rule: ``rotate([0, 1, 0], a)`` is
        RTOW's ``rotate_y(a)``."""
        a = np.array(_argument("rotate", vec3, axis, "axis"), dtype=np.float64)
        if not np.abs(a).max() > 0:  # a zero axis has no direction: it gave a matrix of NaN
            raise SceneError("<Transform.rotate>", "axis", "must not be zero")
        angle_degrees = _argument("rotate", number, angle_degrees, "angle_degrees")
        a = a / np.abs(a).max()  # first to about 1, so the norm of a huge axis does not overflow
        a = a / np.linalg.norm(a)
        theta = math.radians(angle_degrees)
        c, s = math.cos(theta), math.sin(theta)
        x, y, z = a
        # Rodrigues' formula as a matrix: c I + s [a]x + (1 - c) a a^T
        r = np.array([[c + x * x * (1 - c), x * y * (1 - c) - z * s, x * z * (1 - c) + y * s],
                      [y * x * (1 - c) + z * s, c + y * y * (1 - c), y * z * (1 - c) - x * s],
                      [z * x * (1 - c) - y * s, z * y * (1 - c) + x * s, c + z * z * (1 - c)]])
        m = np.eye(4)
        m[:3, :3] = r
        return Transform.from_array(m)

    def then(self, other: Transform) -> Transform:
        """``self`` first, then ``other``.  Overflow gives inf, which the
        scene loader reports with the shape's YAML path."""
        with np.errstate(over="ignore", invalid="ignore"):
            return Transform.from_array(other.array @ self.array)

    @property
    def is_identity(self) -> bool:
        return self.matrix == _identity()

    def points(self, p: np.ndarray) -> np.ndarray:
        """Points ``(3, N)`` mapped to world space."""
        m = self.array
        with np.errstate(over="ignore", invalid="ignore"):  # checked by the caller
            return m[:3, :3] @ np.asarray(p, dtype=np.float64) + m[:3, 3:4]

    def vectors(self, v: np.ndarray) -> np.ndarray:
        """Directions ``(3, N)`` (edges, offsets): no translation."""
        with np.errstate(over="ignore", invalid="ignore"):  # checked by the caller
            return self.array[:3, :3] @ np.asarray(v, dtype=np.float64)

    def normals(self, n: np.ndarray) -> np.ndarray:
        """Surface normals ``(3, N)``: the inverse transpose keeps them
        perpendicular under non-uniform scale (not normalised)."""
        return np.linalg.inv(self.array[:3, :3]).T @ np.asarray(n, dtype=np.float64)

    def uniform_scale(self) -> float | None:
        """The scale factor if this is a similarity (rotation, uniform scale
        and translation only), else ``None``: what a sphere may undergo."""
        linear = self.array[:3, :3]
        size = float(np.abs(linear).max())
        if not (size > 0 and math.isfinite(size)):
            return None
        unit = linear / size  # the test is scale-free, so a huge or tiny scale neither overflows nor underflows
        gram = unit.T @ unit
        s2 = gram[0, 0]
        if s2 <= 0 or not np.allclose(gram, s2 * np.eye(3), rtol=1e-9, atol=1e-12 * s2):
            return None
        return math.sqrt(s2) * size


IDENTITY = Transform()


def _argument(method: str, check, value, name: str):
    """``check(None, value, name)`` (a :mod:`~wavefront.validation` rule), its
    SceneError naming the constructor and argument: ``<Transform.rotate>: axis: ...``."""
    try:
        return check(None, value, name)
    except SceneError as e:
        raise SceneError(f"<Transform.{method}>", e.path, e.problem) from None


def transform_field(obj, value, path: str, *, similarity_only: bool = False) -> Transform | None:
    """A shape's ``transform``: ``None``, a :class:`Transform`, or the scene
    file's list of steps applied first to last: ``{translate: [x, y, z]}``,
    ``{rotate: {axis: [x, y, z], angle: degrees}}``, ``{scale: s}`` or
    ``{scale: [sx, sy, sz]}``.  ``similarity_only`` (spheres) refuses any step
    that could make the shape other than a sphere (non-uniform scale).

    Raises :class:`~wavefront.validation.SceneError` naming ``path`` and the step.
    """
    from .validation import describe, fail

    if value is None:
        return None
    if isinstance(value, Transform):
        total = value
    else:
        if not isinstance(value, (list, tuple)):
            fail(obj, path, f"expected a list of steps (translate, rotate, scale), got {describe(value)}")
        total = Transform()
        for i, step in enumerate(value):
            here = f"{path}[{i}]"
            if not isinstance(step, dict) or len(step) != 1:
                fail(obj, here, f"each step is a mapping with exactly one of: rotate, scale, translate; "
                                f"got {describe(step)}")
            (kind, arg), = step.items()
            where = f"{here}.{kind}"
            if kind not in ("translate", "rotate", "scale"):
                fail(obj, where, "unknown key (expected one of: rotate, scale, translate)")
            if kind == "translate":
                total = total.then(Transform.translate(vec3(obj, arg, where)))
            elif kind == "rotate":
                if not isinstance(arg, dict):
                    fail(obj, where, f"expected {{axis: [x, y, z], angle: degrees}}, got {describe(arg)}")
                for key in arg:
                    if key not in ("axis", "angle"):
                        fail(obj, f"{where}.{key}", "unknown key (expected one of: angle, axis)")
                for key in ("angle", "axis"):
                    if key not in arg:
                        fail(obj, f"{where}.{key}", "required key is missing")
                axis = vec3(obj, arg["axis"], f"{where}.axis")
                if not max(map(abs, axis)) > 0:  # a huge axis ([1e308, 1e308, 0]) is fine: rotate scales it first
                    fail(obj, f"{where}.axis", "must not be zero")
                total = total.then(Transform.rotate(axis, number(obj, arg["angle"], f"{where}.angle")))
            elif kind == "scale":
                factor = vec3(obj, arg, where) if isinstance(arg, (list, tuple)) else (number(obj, arg, where),) * 3
                if 0.0 in factor:
                    fail(obj, where, "must not be zero (it would flatten the shape)")
                if similarity_only and not factor[0] == factor[1] == factor[2]:
                    fail(obj, where, "a sphere can only be scaled uniformly (translate, rotate and uniform "
                                     "scale only)")
                total = total.then(Transform.scale(factor))
    if not np.isfinite(total.array).all():
        fail(obj, path, "the transform overflows")
    if similarity_only and total.uniform_scale() is None:
        fail(obj, path, "a sphere can only be translated, rotated and scaled uniformly")
    return total

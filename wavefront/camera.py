"""A positionable thin-lens camera (RTIOW 1, "Positionable Camera", "Defocus Blur").

Public settings with their defaults come first; everything derived from them
is computed once in :meth:`Camera.frame` for a given image size.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from .geometry import MAX_COORDINATE, position
from .sampling import random_in_unit_disk
from .validation import fail, number, vec3
from .vecmath import normalize

# A pixel at the focus distance must span at least this many representable
# float64 positions at the camera's coordinates, or neighbouring pixels'
# rays (and the jitter within a pixel) collapse onto the same directions.
STEPS_PER_PIXEL = 4
# Camera rays are made this many at a time, so a block's float64 rows and
# temporaries stay in a core's cache while a refill's (up to 64 Ki rays, ~5
# MiB) would not: measured inside W1's render (interleaved, same rays),
# 45-51 ns a ray whole against 34-38 in blocks of 8-16 Ki.
RAY_BLOCK = 1 << 13
# A camera ray's direction is normalised through the squares of its
# components, a pixel's width apart at the focus plane: below the square root
# of float64's smallest normal number (~1.49e-154) their squares are subnormal
# or zero, lose their precision, and the rays collapse.
MIN_PIXEL = math.sqrt(np.finfo(np.float64).tiny)

Vec3 = tuple[float, float, float]


@dataclass(frozen=True)
class Camera:
    """Camera settings.

    =================  ============  ===========================================
    parameter          default       meaning
    =================  ============  ===========================================
    ``look_from``      (0, 0, 0)     eye position
    ``look_at``        (0, 0, -1)    point the camera looks at
    ``vup``            (0, 1, 0)     "up" direction, must not be parallel to
                                     the view direction
    ``vfov``           90            vertical field of view, degrees (0, 180)
    ``defocus_angle``  0             cone angle of rays through each pixel,
                                     degrees; 0 is a pinhole
    ``focus_dist``     |look_at -    distance to the plane in perfect focus
                       look_from|
    =================  ============  ===========================================
    """

    look_from: Vec3 = (0.0, 0.0, 0.0)
    look_at: Vec3 = (0.0, 0.0, -1.0)
    vup: Vec3 = (0.0, 1.0, 0.0)
    vfov: float = 90.0
    defocus_angle: float = 0.0
    focus_dist: float | None = None

    def __post_init__(self):
        set_field = object.__setattr__
        set_field(self, "look_from", position(self, self.look_from, "look_from"))
        set_field(self, "look_at", position(self, self.look_at, "look_at"))
        set_field(self, "vup", vec3(self, self.vup, "vup"))
        set_field(self, "vfov", number(self, self.vfov, "vfov", low=0.0, low_open=True, high=180.0, high_open=True))
        set_field(self, "defocus_angle", number(self, self.defocus_angle, "defocus_angle",
                                                low=0.0, high=180.0, high_open=True))
        if self.focus_dist is not None:
            set_field(self, "focus_dist", number(self, self.focus_dist, "focus_dist",
                                                 low=0.0, low_open=True, high=MAX_COORDINATE))
        forward = [b - a for a, b in zip(self.look_from, self.look_at)]
        if not any(forward):
            fail(self, "look_at", f"must differ from look_from (both are {list(self.look_from)}): "
                                  "the camera has no view direction")
        # compare directions at unit scale so huge or tiny vectors neither overflow nor underflow
        f = _unit(forward)
        up = _unit(self.vup) if any(self.vup) else (0.0, 0.0, 0.0)
        cross = (up[1] * f[2] - up[2] * f[1], up[2] * f[0] - up[0] * f[2], up[0] * f[1] - up[1] * f[0])
        if math.hypot(*cross) <= 1e-9:
            fail(self, "vup", "must not be zero or parallel to the view direction (look_at - look_from)")

    def check_resolution(self, width: int, height: int) -> None:
        """Refuse a view that float64 cannot resolve at this image size.

        The test is the one that matters, not whether look_from and look_at
        are "close": a camera at 1e12 looking at a point one unit away renders
        fine (positions there are 1.2e-4 apart, a pixel of a 225-row image is
        0.009 wide), while the same camera at 1e15 cannot (positions 0.125
        apart).
        """
        forward = [b - a for a, b in zip(self.look_from, self.look_at)]
        focus = self.focus_dist if self.focus_dist is not None else math.hypot(*forward)
        pixel = 2.0 * math.tan(math.radians(self.vfov) / 2.0) * focus / height
        magnitude = max(abs(x) for x in (*self.look_from, *self.look_at))
        # the focus plane lies up to focus + half the viewport from look_from
        magnitude = max(magnitude, max(map(abs, self.look_from)) + focus + pixel * max(width, height))
        spacing = math.ulp(magnitude)
        if not pixel >= MIN_PIXEL:
            fail(self, "look_at", f"the view is too small to render in float64: a pixel at the focus distance "
                                  f"{focus:.3g} is {pixel:.3g} wide, and ray directions are normalised through "
                                  f"their squares, which underflow below about {MIN_PIXEL:.3g}; "
                                  + ("increase focus_dist" if self.focus_dist is not None else
                                     "move look_at farther from look_from, or set focus_dist"))
        if not pixel >= STEPS_PER_PIXEL * spacing:
            hint = "increase focus_dist" if self.focus_dist is not None else "move look_at farther from look_from"
            # named look_at, as every problem of the view's geometry is (the
            # file's reader looks there first); the message says which values
            fail(self, "look_at", f"the view cannot be resolved in float64: at coordinates of magnitude {magnitude:.3g} "
                                  f"positions are {spacing:.3g} apart, but a pixel at the focus distance {focus:.3g} "
                                  f"is {pixel:.3g} wide (at least {STEPS_PER_PIXEL} positions per pixel are needed); "
                                  f"{hint}, use a smaller image, or bring the camera nearer the origin")

    def frame(self, width: int, height: int) -> CameraFrame:
        """Derived per-image state: pixel grid and lens basis."""
        center = np.asarray(self.look_from, dtype=np.float64)
        forward = np.asarray(self.look_at, dtype=np.float64) - center
        focus = float(self.focus_dist) if self.focus_dist is not None else length(forward)
        w = -direction(forward)
        u = direction(np.cross(direction(np.asarray(self.vup, dtype=np.float64), keep_safe=True), w))
        v = np.cross(w, u)
        viewport_height = 2.0 * math.tan(math.radians(self.vfov) / 2.0) * focus
        viewport_width = viewport_height * width / height
        viewport_u = viewport_width * u  # across the image, left to right
        viewport_v = -viewport_height * v  # down the image, row 0 at the top
        pixel_delta_u = viewport_u / width
        pixel_delta_v = viewport_v / height
        upper_left = center - focus * w - viewport_u / 2 - viewport_v / 2
        defocus_radius = focus * math.tan(math.radians(self.defocus_angle / 2.0))
        return CameraFrame(
            width=width,
            center=center,
            upper_left=upper_left,
            pixel_delta_u=pixel_delta_u,
            pixel_delta_v=pixel_delta_v,
            defocus_u=u * defocus_radius,
            defocus_v=v * defocus_radius,
            has_defocus=self.defocus_angle > 0,
        )


def _unit(v) -> tuple[float, float, float]:
    scale = max(map(abs, v))
    v = [x / scale for x in v]
    length = math.hypot(*v)
    return tuple(x / length for x in v)


# Vectors whose length is within these bounds have squares float64 holds
# (NumPy's norm squares them): they are normalised as they always were, bit
# for bit; others (a vup of 1e200 or 1e-200) at unit scale, as the validator does.
_SAFE_LENGTH = (1e-150, 1e150)


def length(v: np.ndarray) -> float:
    """``|v|`` of a (3,) vector, without overflow or underflow."""
    with np.errstate(over="ignore", under="ignore"):
        n = float(np.linalg.norm(v))
    return n if _SAFE_LENGTH[0] < n < _SAFE_LENGTH[1] else math.hypot(*map(float, v))


def direction(v: np.ndarray, keep_safe: bool = False) -> np.ndarray:
    """``v / |v|`` for a non-zero (3,) vector, at any scale; with ``keep_safe``,
    ``v`` itself when its length is safe (it only gives a direction)."""
    with np.errstate(over="ignore", under="ignore"):
        n = float(np.linalg.norm(v))
    if _SAFE_LENGTH[0] < n < _SAFE_LENGTH[1]:
        return v if keep_safe else v / n
    return np.array(_unit([float(x) for x in v]))


@dataclass(frozen=True)
class CameraFrame:
    width: int
    center: np.ndarray
    upper_left: np.ndarray
    pixel_delta_u: np.ndarray
    pixel_delta_v: np.ndarray
    defocus_u: np.ndarray
    defocus_v: np.ndarray
    has_defocus: bool

    def generate_rays(self, pixel: np.ndarray, u: np.ndarray, lens: np.ndarray | None = None, dtype=np.float64,
                      out: tuple[np.ndarray, np.ndarray] | None = None):
        """Primary rays for flat pixel indices, jittered over the pixel square.

        Parameters
        ----------
        pixel : ndarray of shape (N,)
            ``row * width + column``.
        u : ndarray of shape (4, N), or (2, N) without defocus
            Uniforms: pixel jitter x, y and lens sample u, v (read only
            with defocus).
        lens : ndarray of shape (2, N), optional
            The lens sample, if not in ``u`` (then (2, N)): the sampler's
            two pairs are not copied into one array.
        dtype : float32 or float64
            The results' type.  The rays are always made in float64; float32
            results are those rounded, block by block while the block is in
            cache (not a float64 copy of the whole batch rounded later).
        out : (origin, direction), optional
            Arrays of shape (3, N) and type ``dtype`` (views, say, of a
            batch's new columns) to write the rays into, and return.

        Returns
        -------
        origin, direction : ndarray of shape (3, N); directions are unit.
        """
        n = pixel.shape[0]
        origin, direction = (np.empty((3, n), dtype=dtype), np.empty((3, n), dtype=dtype)) if out is None else out
        rounded = np.dtype(dtype) != np.float64
        if rounded:
            block = min(n, RAY_BLOCK)
            origin64, direction64 = np.empty((3, block)), np.empty((3, block))
        for i in range(0, n, RAY_BLOCK):
            j = min(n, i + RAY_BLOCK)
            o, d = (origin64[:, :j - i], direction64[:, :j - i]) if rounded else (origin[:, i:j], direction[:, i:j])
            self._rays(pixel[i:j], u[:, i:j], o, d, u[2:, i:j] if lens is None else lens[:, i:j])
            if rounded:
                np.copyto(origin[:, i:j], o, casting="same_kind")
                np.copyto(direction[:, i:j], d, casting="same_kind")
        return origin, direction

    def _rays(self, pixel, u, origin, target, lens) -> None:
        """:meth:`generate_rays` for one block of rays, written into ``origin``
        and ``target`` (views of the results; ``target`` ends as the unit
        direction)."""
        # row and column in float64: exact (pixel < MAX_PIXELS = 2^28, so the
        # quotient cannot round up to the next integer), and 2.7 ns a ray
        # cheaper than an int64 divmod; x and y are then what ``col + u[0]``
        # gave from the integers (the same conversion, the same add)
        y = pixel.astype(np.float64)
        x = np.divide(y, self.width)
        np.floor(x, out=x)
        y, x = x, y  # y is the row; x becomes the column: pixel - row * width
        x -= y * self.width
        x += u[0]
        y += u[1]
        # target = upper_left + delta_u x + delta_v y, in that order, written
        # in place, the three rows in each call (a (3, 1) column times a row:
        # the same products; 16 calls fewer a block of 8 Ki rays with
        # defocus, 12 without: generate_rays on 32 Ki rays -6 %)
        scratch = np.empty(target.shape)
        np.multiply(self.pixel_delta_u[:, None], x, out=target)
        target += self.upper_left[:, None]
        target += np.multiply(self.pixel_delta_v[:, None], y, out=scratch)
        if self.has_defocus:
            disk = random_in_unit_disk(lens[0], lens[1])
            np.multiply(self.defocus_u[:, None], disk[0], out=origin)
            origin += self.center[:, None]
            origin += np.multiply(self.defocus_v[:, None], disk[1], out=scratch)
            target -= origin
        else:
            origin[...] = self.center[:, None]
            target -= self.center[:, None]
        _normalize_in_place(target)


def _normalize_in_place(v: np.ndarray) -> np.ndarray:
    """:func:`wavefront.vecmath.normalize` (the same operations in the same
    order, so the same bits) without its (3, N) temporaries; returns ``v``."""
    n = v[0] * v[0]
    n += np.multiply(v[1], v[1], out=(t := np.empty_like(n)))
    n += np.multiply(v[2], v[2], out=t)
    np.sqrt(n, out=n)
    np.maximum(n, np.finfo(n.dtype).tiny, out=n)
    np.divide(1.0, n, out=n)
    v *= n
    return v

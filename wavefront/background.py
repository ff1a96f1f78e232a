"""What escaped rays see: a vertical sky gradient or one solid colour."""

from __future__ import annotations

from dataclasses import dataclass
from typing import ClassVar

import numpy as np

from .validation import color
from .vecmath import gather

RGB = tuple[float, float, float]


@dataclass(frozen=True)
class Sky:
    """``lerp(bottom, top, a)`` with ``a = 0.5 (unit_direction.y + 1)``.

    ==========  ===============  ================================
    parameter   default          meaning
    ==========  ===============  ================================
    ``bottom``  (1, 1, 1)        colour looking straight down
    ``top``     (0.5, 0.7, 1.0)  colour looking straight up
    ==========  ===============  ================================
    """

    bottom: RGB = (1.0, 1.0, 1.0)
    top: RGB = (0.5, 0.7, 1.0)
    type: ClassVar[str] = "sky"

    def __post_init__(self):
        object.__setattr__(self, "bottom", color(self, self.bottom, "bottom"))
        object.__setattr__(self, "top", color(self, self.top, "top"))

    def radiance(self, direction: np.ndarray) -> np.ndarray:
        """Colour seen along unit ``direction`` (3, N); returns (3, N)."""
        return self._lerp(direction[1] + 1.0)

    def radiance_at(self, direction: np.ndarray, rows: np.ndarray) -> np.ndarray:
        """:meth:`radiance` of columns ``rows`` (indices) of ``direction``,
        from their y alone: only that row is gathered (W1's bounces lose 1-55 Ki
        of their paths to the sky; a bounce of 55 Ki escapes 157 us against 226
        gathering the three rows)."""
        y1 = gather(direction[1], rows)
        y1 += 1.0
        return self._lerp(y1)

    def _lerp(self, a: np.ndarray) -> np.ndarray:
        """``bottom + 0.5 a (top - bottom)`` for ``a = y + 1`` (R,), a
        temporary taken over: each product and sum in place, in the order
        ``0.5 * (y + 1)`` then ``bottom + a * (top - bottom)`` (a sum and a
        product commute exactly)."""
        a *= 0.5
        bottom = np.asarray(self.bottom, dtype=a.dtype)[:, None]
        light = np.multiply(np.asarray(self.top, dtype=a.dtype)[:, None] - bottom, a)
        light += bottom
        return light


@dataclass(frozen=True)
class Solid:
    """One colour in every direction (black for scenes lit by lamps alone).

    =========  =========  ==========
    parameter  default    meaning
    =========  =========  ==========
    ``color``  (0, 0, 0)  the colour
    =========  =========  ==========
    """

    color: RGB = (0.0, 0.0, 0.0)
    type: ClassVar[str] = "solid"

    def __post_init__(self):
        object.__setattr__(self, "color", color(self, self.color, "color"))

    def radiance(self, direction: np.ndarray) -> np.ndarray:
        return np.broadcast_to(np.asarray(self.color, dtype=direction.dtype)[:, None], direction.shape)

    def radiance_at(self, direction: np.ndarray, rows: np.ndarray) -> np.ndarray:
        """:meth:`radiance` of columns ``rows`` of ``direction``."""
        return np.broadcast_to(np.asarray(self.color, dtype=direction.dtype)[:, None], (3, len(rows)))


Background = Sky | Solid

"""What escaped rays see: a vertical sky gradient or one solid colour."""

from __future__ import annotations

from dataclasses import dataclass
from typing import ClassVar

import numpy as np

from .validation import color

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
        a = 0.5 * (direction[1] + 1.0)
        bottom = np.asarray(self.bottom, dtype=direction.dtype)[:, None]
        top = np.asarray(self.top, dtype=direction.dtype)[:, None]
        return bottom + a * (top - bottom)


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


Background = Sky | Solid

"""Work units, and how their samples become pixels.

The image is cut into units of work: a tile of at most ``TILE`` x ``TILE``
pixels times a pass of at most ``PASS_SAMPLES`` samples per pixel.  Units are
a fixed function of the image size and sample count, never of the chunk size
or the number of workers, and:

* every sample's random numbers depend only on its (pixel, sample index),
  so a unit's samples come out the same wherever it runs;
* each unit reduces its samples per pixel with one ``sum`` over an array of a
  fixed shape, so the floating-point summation order is fixed too;
* unit results are added to the film in unit order.

Together these make the image bit-identical for any chunk size or worker
count.  A unit's samples are numbered by *slot* ``pixel_in_tile * S + s``, so
the reduction is a reshape to ``(3, P, S)`` and a sum over the last axis.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

TILE = 64
PASS_SAMPLES = 16


@dataclass(frozen=True)
class Unit:
    index: int  # position in the render's fixed unit order
    x0: int
    y0: int
    x1: int
    y1: int
    sample_start: int
    sample_stop: int

    @property
    def pixels(self) -> int:
        return (self.x1 - self.x0) * (self.y1 - self.y0)

    @property
    def samples_per_pixel(self) -> int:
        return self.sample_stop - self.sample_start

    @property
    def size(self) -> int:
        return self.pixels * self.samples_per_pixel

    def pixel_index(self, width: int) -> np.ndarray:
        """Flat image indices of the tile's pixels, row-major; shape (P,)."""
        ys = np.arange(self.y0, self.y1)
        xs = np.arange(self.x0, self.x1)
        return (ys[:, None] * width + xs[None, :]).ravel()


def plan_units(width: int, height: int, samples_per_pixel: int) -> list[Unit]:
    """All units of a render in their fixed order: pass-major, then tiles.

    Pass-major order means that after any prefix of units every pixel has
    about the same number of samples, so an interrupted render is a uniformly
    noisier image rather than a half-finished one.
    """
    units = []
    for s0 in range(0, samples_per_pixel, PASS_SAMPLES):
        s1 = min(samples_per_pixel, s0 + PASS_SAMPLES)
        for y0 in range(0, height, TILE):
            for x0 in range(0, width, TILE):
                units.append(Unit(len(units), x0, y0, min(width, x0 + TILE),
                                  min(height, y0 + TILE), s0, s1))
    return units


class Job:
    """The samples of consecutive units, numbered by one run of slots."""

    def __init__(self, units: list[Unit], width: int, samples_per_pixel: int):
        self.units = units
        self.width = width
        self.samples_per_pixel = samples_per_pixel
        sizes = np.array([u.size for u in units], dtype=np.int64)
        self.offsets = np.concatenate(([0], np.cumsum(sizes)))
        self.size = int(self.offsets[-1])
        # per-unit geometry as arrays, so any run of slots maps to pixels in one pass
        self._x0 = np.array([u.x0 for u in units], dtype=np.int64)
        self._y0 = np.array([u.y0 for u in units], dtype=np.int64)
        self._tile_width = np.array([u.x1 - u.x0 for u in units], dtype=np.int64)
        self._pass_size = np.array([u.samples_per_pixel for u in units], dtype=np.int64)
        self._pass_start = np.array([u.sample_start for u in units], dtype=np.int64)

    def samples(self, start: int, stop: int):
        """Pixel index and global sample id of slots ``start:stop``."""
        slots = np.arange(start, stop, dtype=np.int64)
        which = np.searchsorted(self.offsets, slots, side="right") - 1
        p, s = np.divmod(slots - self.offsets.take(which), self._pass_size.take(which))
        row, col = np.divmod(p, self._tile_width.take(which))
        pixel = (self._y0.take(which) + row) * self.width + self._x0.take(which) + col
        sample = self._pass_start.take(which) + s
        sample_id = pixel.astype(np.uint64) * np.uint64(self.samples_per_pixel) + sample.astype(np.uint64)
        return pixel, sample_id

    def reduce(self, radiance: np.ndarray):
        """Per-unit pixel sums and valid-sample counts, in unit order.

        Samples that are not finite in every channel are dropped (and
        counted) instead of poisoning the pixel.

        Returns
        -------
        list of (unit, sum (3, P) float64, count (P,) int64, dropped int)
        """
        out = []
        for k, unit in enumerate(self.units):
            block = radiance[:, self.offsets[k]:self.offsets[k + 1]]
            block = block.reshape(3, unit.pixels, unit.samples_per_pixel)
            finite = np.isfinite(block).all(axis=0)
            # almost always all finite: skip the (slow) where over every sample
            total = (block if finite.all() else np.where(finite, block, 0.0)).sum(axis=2)
            count = finite.sum(axis=1)
            out.append((unit, total, count, int(finite.size - count.sum())))
        return out

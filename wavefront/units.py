"""Units of work: which samples of which pixels, in a fixed order.

The image is cut into units: a tile of at most ``TILE`` x ``TILE`` pixels
times a *pass*, a run of consecutive sample indices.  The plan is a fixed
function of the image size and sample count, never of the chunk size or the
number of workers, and:

* every sample's random numbers depend only on its (pixel, sample index),
  so a unit's samples come out the same wherever it runs;
* each unit reduces its samples per pixel with one ``sum`` over an array of a
  fixed shape, so the floating-point summation order is fixed too;
* unit results are added to the film in unit order.

Together these make the image bit-identical for any chunk size or worker
count.  A unit's samples are numbered by *slot* ``pixel_in_tile * S + s``, so
the reduction is a reshape to ``(3, P, S)`` and a sum over the last axis.

Passes grow from one sample per pixel: 1, 1, 2, 4, 8, then ``pass_cap``
each (16 for full tiles; more for images too small to fill a unit).  Units
are ordered pass-major, so after the first pass every pixel has a sample and
an interrupted render is a uniformly noisier image, never one with missing
tiles.  The plan is arithmetic (:class:`UnitPlan` computes unit ``i`` on
demand), so its memory does not grow with the sample count.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

TILE = 64
PASS_SAMPLES = 16  # samples per pixel of a full pass over full tiles
# A pass over tiny images grows until a unit holds about this many samples,
# so a 1x1 image at 2^24 spp is not a million units of 16 samples.
UNIT_SAMPLES = TILE * TILE * PASS_SAMPLES


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


class UnitPlan:
    """All units of a render in their fixed order, computed on demand.

    ``plan[i]`` is unit ``i``; ``len(plan)`` their number.  Pass-major: unit
    ``i`` is tile ``i % tiles`` of pass ``i // tiles``.
    """

    def __init__(self, width: int, height: int, samples_per_pixel: int):
        self.width, self.height, self.samples_per_pixel = width, height, samples_per_pixel
        self.tiles_x = -(-width // TILE)
        self.tiles = self.tiles_x * -(-height // TILE)
        full_tile = min(TILE, width) * min(TILE, height)
        cap = PASS_SAMPLES
        while cap * full_tile < UNIT_SAMPLES:
            cap *= 2
        self.pass_cap = cap
        self._doubling = cap.bit_length()  # passes 0..log2(cap) are 1, 1, 2, ..., cap / 2
        k = 0
        if samples_per_pixel > cap:
            k = self._doubling + -(-(samples_per_pixel - cap) // cap)
        else:
            while self.pass_start(k) < samples_per_pixel:
                k += 1
        self.passes = k

    def pass_start(self, k: int) -> int:
        """First sample index of pass ``k``: 0, 1, 2, 4, ..., cap, 2 cap, 3 cap, ..."""
        if k == 0:
            return 0
        if k < self._doubling:
            return 1 << (k - 1)
        return self.pass_cap * (k - self._doubling + 1)

    def __len__(self) -> int:
        return self.passes * self.tiles

    def __getitem__(self, i: int) -> Unit:
        if not 0 <= i < len(self):
            raise IndexError(i)
        k, tile = divmod(i, self.tiles)
        ty, tx = divmod(tile, self.tiles_x)
        x0, y0 = tx * TILE, ty * TILE
        s0 = self.pass_start(k)
        s1 = min(self.samples_per_pixel, self.pass_start(k + 1))
        return Unit(i, x0, y0, min(self.width, x0 + TILE), min(self.height, y0 + TILE), s0, s1)

    def __iter__(self):
        return (self[i] for i in range(len(self)))

    def samples_by_region(self, i: int) -> list[tuple[slice, slice, int]]:
        """How many samples each pixel has from units ``0 .. i - 1``, as
        ``(rows, columns, samples)`` rectangles that cover the image."""
        k, tile = divmod(i, self.tiles)
        base = min(self.samples_per_pixel, self.pass_start(k))
        more = min(self.samples_per_pixel, self.pass_start(k + 1))  # tiles already done in pass k
        ty, tx = divmod(tile, self.tiles_x)
        y0, y1, x0 = min(self.height, ty * TILE), min(self.height, (ty + 1) * TILE), min(self.width, tx * TILE)
        every = slice(0, self.width)
        return [(slice(0, y0), every, more), (slice(y0, y1), slice(0, x0), more),
                (slice(y0, y1), slice(x0, self.width), base), (slice(y1, self.height), every, base)]

    def samples_before(self, i: int) -> int:
        """Samples in units ``0 .. i - 1``, without visiting them."""
        k, tile = divmod(i, self.tiles)
        done = self.width * self.height * min(self.samples_per_pixel, self.pass_start(k))
        if tile:
            partial = Unit(0, 0, 0, 0, 0, self.pass_start(k), min(self.samples_per_pixel, self.pass_start(k + 1)))
            ty, tx = divmod(tile, self.tiles_x)
            # whole rows of tiles, then the tiles of the current row
            rows = min(self.height, ty * TILE) * self.width
            cols = min(self.width, tx * TILE) * (min(self.height, (ty + 1) * TILE) - ty * TILE)
            done += (rows + cols) * partial.samples_per_pixel
        return done

    @property
    def total_samples(self) -> int:
        return self.width * self.height * self.samples_per_pixel


def plan_units(width: int, height: int, samples_per_pixel: int) -> UnitPlan:
    """All units of a render in their fixed order (see :class:`UnitPlan`)."""
    return UnitPlan(width, height, samples_per_pixel)


@dataclass(frozen=True, slots=True)
class SampleBlock:
    """Consecutive slots of one unit: the grid of its pixels ``pixel`` (P,)
    int64 (flat image indices, in slot order) times the sample indices
    ``sample_start:sample_stop`` (S of them), pixel-major (slot ``p * S + s``
    is sample ``sample_start + s`` of pixel ``p``), cut to the slots
    ``cut`` of its ``P * S``: the first and last pixels may have only some
    of their samples among the slots."""

    pixel: np.ndarray
    sample_start: int
    sample_stop: int
    cut: slice

    @property
    def size(self) -> int:
        """The slots: ``cut``'s length."""
        return self.cut.stop - self.cut.start

    def repeated(self, per_pixel: np.ndarray) -> np.ndarray:
        """Per-slot values ``(size,)`` of per-pixel values ``(P,)``."""
        return np.repeat(per_pixel, self.sample_stop - self.sample_start)[self.cut]

    def flattened(self, grid: np.ndarray) -> np.ndarray:
        """Per-slot values ``(..., size)`` of a grid ``(..., P, S)`` (a view)."""
        return grid.reshape(grid.shape[:-2] + (-1,))[..., self.cut]


class Job:
    """The samples of consecutive units, numbered by one run of slots."""

    def __init__(self, units: list[Unit], width: int, samples_per_pixel: int):
        self.units = units
        self.width = width
        self.samples_per_pixel = samples_per_pixel
        sizes = np.array([u.size for u in units], dtype=np.int64)
        self.offsets = np.concatenate(([0], np.cumsum(sizes)))
        self.size = int(self.offsets[-1])

    def blocks(self, start: int, stop: int) -> list[SampleBlock]:
        """Slots ``start:stop`` unit by unit (a refill spans a few units), as
        :class:`SampleBlock` grids: a unit's slots are its tile's pixels, each
        repeated for the pass's samples, so a run of them is the pixels it
        touches times the pass's samples, cut at both ends."""
        out = []
        n = stop - start
        k = int(np.searchsorted(self.offsets, start, side="right")) - 1
        pos = 0
        while pos < n:
            unit, base = self.units[k], int(self.offsets[k])
            a, b = start + pos - base, min(stop - base, unit.size)  # the unit's slots a:b
            per = unit.samples_per_pixel
            p0, p1 = a // per, -(-b // per)  # the tile's pixels that a:b touches
            tile_width = unit.x1 - unit.x0
            r0 = p0 // tile_width  # their rows of the tile, as image indices
            ys = np.arange(unit.y0 + r0, unit.y0 + -(-p1 // tile_width), dtype=np.int64)
            xs = np.arange(unit.x0, unit.x1, dtype=np.int64)
            pix = (ys[:, None] * self.width + xs).ravel()[p0 - r0 * tile_width:p1 - r0 * tile_width]
            out.append(SampleBlock(pix, unit.sample_start, unit.sample_stop, slice(a - p0 * per, b - p0 * per)))
            pos += b - a
            k += 1
        return out

    def samples(self, start: int, stop: int):
        """Pixel index (int64) and global sample id (uint64) of slots
        ``start:stop``, from :meth:`blocks`.  (A search, two divisions and
        five gathers per slot cost 14 ns a slot; this, 2.)"""
        n = stop - start
        pixel = np.empty(n, dtype=np.int64)
        sample_id = np.empty(n, dtype=np.uint64)
        pos = 0
        for block in self.blocks(start, stop):
            rows = slice(pos, pos + block.size)
            pixel[rows] = block.repeated(block.pixel)
            ids = block.pixel.astype(np.uint64)[:, None] * np.uint64(self.samples_per_pixel)
            sample_id[rows] = block.flattened(ids + np.arange(block.sample_start, block.sample_stop, dtype=np.uint64))
            pos = rows.stop
        return pixel, sample_id

    def reduce(self, radiance: np.ndarray):
        """Per-unit pixel sums and valid-sample counts, in unit order.

        Samples that are not finite in every channel are dropped (and
        counted) instead of poisoning the pixel.

        Returns
        -------
        list of (unit, sum (3, P) float64, count, dropped int)
            ``count`` is (P,) int64, or an int when every pixel kept all its
            samples (almost always: a fifth less to send back to the parent).
        """
        out = []
        for k, unit in enumerate(self.units):
            block = radiance[:, self.offsets[k]:self.offsets[k + 1]]
            block = block.reshape(3, unit.pixels, unit.samples_per_pixel)
            # Almost always every sample is finite, and then so is every sum
            # (a NaN or infinity among the terms makes the sum NaN or
            # infinite): checking the (3, P) sums skips three passes over
            # every sample, 40 % of this.  Sums that are not finite (a bad
            # sample, or finite ones overflowing) take the per-sample path.
            total = block.sum(axis=2)
            if np.isfinite(total).all():
                out.append((unit, total, unit.samples_per_pixel, 0))
                continue
            finite = np.isfinite(block).all(axis=0)
            total = np.where(finite, block, 0.0).sum(axis=2)
            count = finite.sum(axis=1)
            out.append((unit, total, count, int(finite.size - count.sum())))
        return out

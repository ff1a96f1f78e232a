"""The structure-of-arrays record of paths in flight."""

from __future__ import annotations

from dataclasses import dataclass, fields

import numpy as np

from .vecmath import TAKE_MODE, gather, true_rows


@dataclass(slots=True)
class PathBatch:
    """Live paths of a wavefront, one column (or element) per path.

    ``slot`` says where the path's radiance goes in the job's per-sample
    buffer, ``state`` is what its sampler draws its numbers from (see
    :class:`wavefront.sampling.Sampler`) and ``depth`` counts the segments traced so
    far; paths of different depths share a batch once it has been refilled.
    """

    origin: np.ndarray  # (3, N) float64
    direction: np.ndarray  # (3, N) float64, unit
    throughput: np.ndarray  # (3, N) float64
    slot: np.ndarray  # (N,) int64
    state: np.ndarray  # (N,) uint64
    depth: np.ndarray  # (N,) int32
    # What multiple importance sampling and roulette need from the vertex the
    # path last left: the solid-angle pdf of the direction it sampled there,
    # whether that sampling was a delta (mirror, glass, camera: its emission
    # hits count in full; the pdf is then not read, and may hold anything),
    # and eta^2 accumulated over refractions.  None in integrators that need
    # none of it (Whitted).
    bsdf_pdf: np.ndarray | None = None  # (N,) float64
    specular: np.ndarray | None = None  # (N,) bool
    eta_scale: np.ndarray | None = None  # (N,) float64
    # The path's time in [0, 1) for motion blur (None in a scene where nothing moves).
    time: np.ndarray | None = None  # (N,) float64
    # The media the path is in, as bits (see wavefront.media); None in a
    # scene without media.
    media_mask: np.ndarray | None = None  # (N,) uint64

    def __len__(self) -> int:
        return self.slot.shape[0]

    def take(self, idx: np.ndarray) -> PathBatch:
        """The paths at ``idx`` (indices or a mask), every field compacted alike.

        ``take`` rather than fancy indexing, and in its mode: see
        :func:`wavefront.vecmath.gather`.
        """
        if idx.dtype == bool:
            idx = true_rows(idx)
        # the field names and ``gather`` (the method ``take``, not ``np.take``'s
        # Python wrapper, or (3, N) views row by row): a few microseconds of
        # every call, a bounce's fixed cost when only a handful of paths are left
        return PathBatch(*[None if (a := getattr(self, name)) is None else gather(a, idx)
                           for name in _PATH_FIELDS])

    def fill(self, holes: np.ndarray, movers: np.ndarray, size: int) -> PathBatch:
        """The batch cut to its first ``size`` paths after the paths at
        ``movers`` (all at or past ``size``) have moved into the rows
        ``holes`` (below ``size``, as many), in place: the order of the
        paths changes.  Where few paths ended, this copies their few rows
        where :meth:`take` gathers every row (56 us against 324 for 32 Ki
        paths, 1.3 % ended).

        Every field becomes a view of its first ``size`` columns (or
        elements): a (3, N) field is then not contiguous, which
        :func:`wavefront.vecmath.gather` (the next compaction's, and the
        escaped paths') reads row by row; making it contiguous here copied
        9 rows a bounce (100 us of 32 Ki paths).
        """
        for name in _PATH_FIELDS:
            a = getattr(self, name)
            if a is None:
                continue
            for row in (a if a.ndim == 2 else (a,)):  # a (3, N) field row by row: see vecmath.scatter
                row[holes] = row.take(movers, mode=TAKE_MODE)
            setattr(self, name, a[:size] if a.ndim == 1 else a[:, :size])
        return self

    @staticmethod
    def concat(a: PathBatch, b: PathBatch) -> PathBatch:
        if len(a) == 0:
            return b
        return PathBatch(*[None if (x := getattr(a, name)) is None or (y := getattr(b, name)) is None else
                           np.concatenate((x, y), axis=-1) for name in _PATH_FIELDS])


_PATH_FIELDS = tuple(f.name for f in fields(PathBatch))


@dataclass(slots=True)
class ShadowBatch:
    """Shadow rays of next-event estimation: each adds ``contribution`` to its
    sample's radiance unless something lies between ``origin`` and ``t_max``
    (times the transmittance of the media it passes through)."""

    origin: np.ndarray  # (3, S)
    direction: np.ndarray  # (3, S), unit
    t_max: np.ndarray  # (S,)
    contribution: np.ndarray  # (3, S), MIS-weighted, throughput included
    slot: np.ndarray  # (S,) int64
    time: np.ndarray | None = None  # (S,) the path's time (motion blur), or None
    media_mask: np.ndarray | None = None  # (S,) uint64: the media at the origin (None: no media)

    def __len__(self) -> int:
        return self.slot.shape[0]

    @staticmethod
    def concat(a: ShadowBatch | None, b: ShadowBatch) -> ShadowBatch:
        """``a``'s rays then ``b``'s (``a`` may be None or empty)."""
        if a is None or len(a) == 0:
            return b
        return ShadowBatch(*[None if (x := getattr(a, name)) is None or (y := getattr(b, name)) is None else
                             np.concatenate((x, y), axis=-1) for name in _SHADOW_FIELDS])


_SHADOW_FIELDS = tuple(f.name for f in fields(ShadowBatch))

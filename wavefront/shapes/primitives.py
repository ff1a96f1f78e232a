"""Every primitive of a scene, of every kind, under one scene-wide index.

Kinds come in a fixed order (spheres, quads, triangles); primitive ``i`` of
kind ``k`` has the scene-wide index ``offsets[k] + i``.  :class:`Primitives`
is also the brute-force intersector: each kind's primitives are tested in
blocks broadcast against all rays, so the Python loop runs over a few kinds
and blocks, never over rays.  The BVH (:mod:`wavefront.bvh`) has the same
interface and finds exactly the same primitive at exactly the same ``t``.
"""

from __future__ import annotations

import numpy as np

from ..geometry import BLOCK_ELEMENTS, escaped_at_inf
from .base import Hits, ShapeKind, SurfaceHits

# Rays tested together by brute force.  Each of the exact tests' ~40
# operations makes a (primitives, rays) temporary: with a few thousand rays
# they stay in L2 instead of streaming through memory.  Whole Cornell box
# renders (128x128, 64 spp, one core, interleaved in one process): 4.41 s with
# the whole wavefront at once, 4.17 s at 4096, 4.44 s at 2048.
BRUTE_FORCE_RAYS = 4096


class Primitives:
    """The scene's shape sets, in kind order, with one index space.

    Parameters
    ----------
    kinds : list of ShapeKind
        Empty kinds may be left out; order defines the index space.
    """

    def __init__(self, kinds: list[ShapeKind], dtype=np.float64, pad: float = 0.0):
        self.kinds = [k for k in kinds if len(k)]
        self.dtype = np.dtype(dtype)
        self.pad = pad  # how far outside its box a flat primitive may be hit (see shapes.base.exact_pad)
        sizes = [len(k) for k in self.kinds]
        self.offsets = np.concatenate(([0], np.cumsum(sizes))).astype(np.int64)
        self.material_idx = (np.concatenate([k.material_idx for k in self.kinds]) if self.kinds
                             else np.zeros(0, dtype=np.int32))

    def __len__(self) -> int:
        return int(self.offsets[-1])

    @property
    def moving(self) -> bool:
        """Whether some primitive moves (rays then carry a time)."""
        return any(getattr(k, "moving", False) for k in self.kinds)

    def kind_of(self, idx: np.ndarray) -> np.ndarray:
        """Which of ``self.kinds`` each scene-wide index belongs to."""
        return np.searchsorted(self.offsets, idx, side="right") - 1

    def bounds(self) -> tuple[np.ndarray, np.ndarray]:
        """Each primitive's box, ``lo, hi (3, M)`` float64."""
        parts = [k.bounds() for k in self.kinds]
        return (np.concatenate([p[0] for p in parts], axis=1).astype(np.float64),
                np.concatenate([p[1] for p in parts], axis=1).astype(np.float64))

    def bounding_sphere(self) -> tuple[np.ndarray, np.ndarray]:
        """Each primitive's bounding sphere: ``center (3, M)``, ``radius (M,)`` float64."""
        parts = [k.bounding_sphere() for k in self.kinds]
        return (np.concatenate([p[0] for p in parts], axis=1).astype(np.float64),
                np.concatenate([p[1] for p in parts]).astype(np.float64))

    def subset(self, idx: np.ndarray) -> Primitives:
        """The primitives ``idx`` (sorted scene-wide indices), renumbered from 0
        in the same order, so ties still go to the lower scene-wide index."""
        idx = np.asarray(idx, dtype=np.int64)
        kind = self.kind_of(idx)
        part = Primitives([self.kinds[k].subset(idx[kind == k] - self.offsets[k]) for k in range(len(self.kinds))],
                          self.dtype, self.pad)
        return part

    # -- queries ---------------------------------------------------------------

    def _blocks(self, n: int):
        """(kind, scene-wide offset of the block, start, stop) over every primitive."""
        for kind, offset in zip(self.kinds, self.offsets):
            m = len(kind)
            block = max(1, min(m, BLOCK_ELEMENTS // max(n, 1)))
            for start in range(0, m, block):
                yield kind, int(offset), start, min(m, start + block)

    def intersect(self, origin, direction, t_max=np.inf, time=None) -> Hits:
        """Nearest hit with ``T_MIN < t < t_max`` for every ray, by brute force,
        :data:`BRUTE_FORCE_RAYS` rays at a time (see :meth:`_intersect`)."""
        return self._in_chunks(self._intersect, origin, direction, t_max, time)

    def occluded(self, origin, direction, t_max, time=None) -> np.ndarray:
        """Any hit with ``T_MIN < t < t_max`` (a shadow ray's question), by
        brute force, :data:`BRUTE_FORCE_RAYS` rays at a time.  Shape ``(N,)`` bool."""
        return self._in_chunks(self._occluded, origin, direction, t_max, time)

    @staticmethod
    def _in_chunks(query, origin, direction, t_max, time):
        n = origin.shape[1]
        step = BRUTE_FORCE_RAYS
        if n <= step:
            return query(origin, direction, t_max, time)
        # a scalar t_max stays one: escaped_at_inf then skips a pass over the rays
        limit = (lambda a: t_max) if np.ndim(t_max) == 0 else (lambda a: t_max[a:a + step])  # noqa: E731
        parts = [query(origin[:, a:a + step], direction[:, a:a + step], limit(a),
                       None if time is None else time[a:a + step]) for a in range(0, n, step)]
        if isinstance(parts[0], Hits):
            return Hits(np.concatenate([h.t for h in parts]), np.concatenate([h.primitive_idx for h in parts]))
        return np.concatenate(parts)

    def _intersect(self, origin, direction, t_max=np.inf, time=None) -> Hits:
        """Nearest hit with ``T_MIN < t < t_max`` for every ray, by brute force.

        The nearest primitive of a block is found with a ``min`` reduction and
        an integer blend (lowest index wins a tie) rather than ``argmin``, a
        slow, branchy loop along the first axis.

        Parameters
        ----------
        origin, direction : ndarray of shape (3, N)
            ``direction`` must be unit length.
        t_max : float or ndarray of shape (N,)
        time : None or ndarray of shape (N,)
            Each ray's time in [0, 1), for moving spheres.
        """
        n = origin.shape[1]
        best_t = np.broadcast_to(np.asarray(t_max, dtype=origin.dtype), (n,)).copy()
        best_idx = np.full(n, -1, dtype=np.int64)
        for kind, offset, start, stop in self._blocks(n):
            t = kind.t_block(start, stop, origin, direction, time)
            t_block = np.fmin.reduce(t, axis=0)  # fmin: a miss may be NaN
            # strict: an earlier block keeps a tie; false where nothing was hit
            closer = t_block < best_t
            for j in range(stop - start - 1, -1, -1):  # downwards, so the lowest index is written last
                take = closer & (t[j] == t_block)
                best_idx += take * (offset + start + j - best_idx)
            best_t = np.fmin(best_t, t_block)
        return Hits(escaped_at_inf(best_t, best_idx >= 0, t_max), best_idx.astype(np.int32))

    def _occluded(self, origin, direction, t_max, time=None) -> np.ndarray:
        """Any hit with ``T_MIN < t < t_max`` (a shadow ray's question); rays
        stop being tested at their first hit.  Shape ``(N,)`` bool."""
        n = origin.shape[1]
        limit = np.broadcast_to(np.asarray(t_max, dtype=origin.dtype), (n,))
        blocked = np.zeros(n, dtype=bool)
        live = np.arange(n)
        o, d, lim, tm = origin, direction, limit, time
        for kind, _, start, stop in self._blocks(n):
            if live.size == 0:
                break
            hit = (kind.t_block(start, stop, o, d, tm) < lim).any(axis=0)  # NaN compares false
            if hit.any():
                blocked[live[hit]] = True
                keep = np.flatnonzero(~hit)
                live, o, d, lim = live.take(keep), o.take(keep, axis=1), d.take(keep, axis=1), lim.take(keep)
                tm = None if tm is None else tm.take(keep)
        return blocked

    def t_pairs(self, idx: np.ndarray, origin, direction, time=None) -> np.ndarray:
        """Exact ``t`` of ray ``p`` (column ``p`` of ``origin``, at ``time[p]``)
        against primitive ``idx[p]``: the arithmetic of :meth:`intersect`, pair by pair."""
        if len(self.kinds) == 1:
            return self.kinds[0].t_pairs(idx, origin, direction, time)
        t = np.empty(idx.shape, dtype=np.result_type(origin.dtype, self.dtype))
        kind = self.kind_of(idx)
        for k, shapes in enumerate(self.kinds):
            sel = np.flatnonzero(kind == k)
            if sel.size:
                t[sel] = shapes.t_pairs(idx.take(sel) - self.offsets[k], origin.take(sel, axis=1),
                                        direction.take(sel, axis=1), None if time is None else time.take(sel))
        return t

    def surface(self, origin, direction, t, idx, uv: bool = False, time=None) -> SurfaceHits:
        """What rays that hit primitives ``idx`` at ``t`` (at ``time``) hit (hitting rows only).

        ``uv`` computes surface coordinates too (only image textures read
        them, and for spheres they cost two transcendental functions per hit).
        """
        if len(self.kinds) == 1:
            point, outward, shading, coords = self.kinds[0].surface(idx, origin, direction, t, uv, time)
        else:
            n = idx.shape[0]
            point = np.empty((3, n), dtype=origin.dtype)
            outward = np.empty((3, n), dtype=origin.dtype)
            shading = np.empty((3, n), dtype=origin.dtype)
            coords = np.empty((2, n), dtype=origin.dtype) if uv else None
            kind = self.kind_of(idx)
            for k, shapes in enumerate(self.kinds):
                sel = np.flatnonzero(kind == k)
                if sel.size == 0:
                    continue
                p, g, s, c = shapes.surface(idx.take(sel) - self.offsets[k], origin.take(sel, axis=1),
                                            direction.take(sel, axis=1), t.take(sel), uv,
                                            None if time is None else time.take(sel))
                point[:, sel], outward[:, sel], shading[:, sel] = p, g, s
                if uv:
                    coords[:, sel] = c
        cos = direction[0] * outward[0] + direction[1] * outward[1] + direction[2] * outward[2]
        front_face = cos < 0.0
        sign = 2 * front_face.astype(outward.dtype) - 1  # flip to face the ray; cheaper than a (3, N) where
        geometric = outward * sign
        normal = geometric if shading is outward else shading * sign
        return SurfaceHits(point=point, normal=normal, geometric_normal=geometric, front_face=front_face,
                           material_idx=self.material_idx.take(idx), primitive_idx=idx, uv=coords)

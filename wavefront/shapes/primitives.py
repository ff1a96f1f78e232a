"""Every primitive of a scene, of every kind, under one scene-wide index.

Kinds come in a fixed order (spheres, quads, triangles); primitive ``i`` of
kind ``k`` has the scene-wide index ``offsets[k] + i``.  :class:`Primitives`
is also the brute-force intersector: each kind's primitives are tested in
blocks broadcast against all rays, so the Python loop runs over a few kinds
and blocks, never over rays; quads and triangles pass a float32 slab test
(:class:`SlabFilter`) first and only the pairs it keeps get the exact test.
The BVH (:mod:`wavefront.bvh`) has the same interface and finds exactly the
same primitive at exactly the same ``t``.
"""

from __future__ import annotations

import functools

import numpy as np

from ..geometry import BLOCK_ELEMENTS, escaped_at_inf, key_root
from ..vecmath import dot, gather, true_rows
from .base import Hits, ShapeKind, SurfaceHits, float32_down, float32_up, pad_extent

# Rays tested together by brute force.  Each of the exact tests' ~40
# operations makes a (primitives, rays) temporary: with a few thousand rays
# they stay in L2 instead of streaming through memory.  Whole Cornell box
# renders (128x128, 64 spp, one core, interleaved in one process): 4.41 s with
# the whole wavefront at once, 4.17 s at 4096, 4.44 s at 2048.  Re-measured
# since the allocator keeps freed temporaries (render.tune_allocator), per
# 32 Ki path render (128x64 or 128x128 2 spp, one core, medians of 5-7, CPU
# ms at 4096 / 8192 / 12288 / 16384 rays): cornell_spheres 64 / 63 / 63 / 65
# (its nearest-hit query 2.09 -> 1.73 ms a bounce from 4096 to 8192, the
# shadow rays' 1.13 -> 0.89), the Cornell box 70 / 67 / 67 / 69, three_spheres
# (400x225, 1 spp) 53 / 51 / 52 / 53.  Session 12, replaying recorded
# queries (each call's least time of 7-9, interleaved, summed; sphere keys
# still go through KEY_BLOCK_BYTES's chunks of rays, which bound the exact
# test's temporaries), ns a ray at 8192 / 16384 / 32768 rays: W1's nearest
# hits 21.7 / 21.0 / 20.0 (65536: 20.8), cornell_spheres' 55.7 / 46.3 / 45.2
# and its shadow rays' 47.4 / 41.3 / 40.9, the Cornell box's 189 / 167 / 170
# and 183 / 185 / 155: each chunk's ~40 NumPy calls and their Python cost
# fewer.  Whole renders (CPU of one worker, medians of interleaved runs):
# W1 400x225x30 0.963 of 8192 (9 runs, per-run ratios 0.89-1.17); against
# session 11's tree, so with session 12's other brute-force and hit-record
# changes, cornell_spheres 160x160x8 0.974 (9 runs, 0.95-1.12) and the
# Cornell box 0.967 (5 runs, 0.95-1.00).
BRUTE_FORCE_RAYS = 32768

# The float32 slab pre-filter of flat primitives (see SlabFilter) grows each
# primitive's padded box by this much of the scene's extent E: far more than
# its own rounding, a few float32 epsilons (2**-24) of E, plus the exact
# test's few float64 epsilons of E by which its hit point may stray from the
# ray.  In the Cornell box it is 0.009 of a 555-unit room.
FILTER_PAD = 2.0 ** -17
# Beyond this extent float32 coordinates cannot carry the filter's pad: flat
# primitives are then tested exactly against every ray.
FILTER_MAX_EXTENT = 1e30
# Elements of one (primitives x rays) block of the slab filter, which bounds
# its five float32 temporaries.  Splitting the Cornell box's 18 quads x 4096
# rays into smaller blocks of rays measured no faster in whole renders.  Brute
# force tests at most FILTER_PRIMITIVES primitives per block, and rays
# FILTER_MIN_RAYS or more at a time.
FILTER_BLOCK_ELEMENTS = 1 << 17
FILTER_PRIMITIVES = 128
FILTER_MIN_RAYS = 256


class SlabFilter:
    """A conservative float32 test of every (ray, primitive) pair before the exact one.

    The quad and triangle tests accept a hit only at a computed point inside
    the primitive's padded box (``box_lo``, ``box_hi``; see
    :func:`~wavefront.shapes.base.exact_pad`), so a ray that does not enter
    that box, grown by :data:`FILTER_PAD`, between 0 and its ``t_max`` cannot
    have an exact hit: the slab test against the grown box, in float32 from
    rays whose origins lie within the extent, rounds by far less than the
    growth.  Only the pairs it keeps are tested exactly, pair by pair, with
    the same arithmetic as the broadcast test (each kind's ``t_pairs``), so
    the hits are bit for bit those of testing every pair.  In the Cornell box
    it keeps ~2.2 of 18 quads per camera or bounce ray and ~1.7 per shadow
    ray (about one of them the quad the ray leaves), where every primitive's
    plane is crossed by half the rays.
    """

    def __init__(self, kind: ShapeKind):
        extent = max(pad_extent(kind.dtype, kind.pad), float(np.abs(kind.box_lo).max(initial=0.0)),
                     float(np.abs(kind.box_hi).max(initial=0.0)))
        self.reach = extent  # rays must start within this distance of the origin (per coordinate)
        grow = FILTER_PAD * extent
        self.lo = np.ascontiguousarray(float32_down(kind.box_lo.astype(np.float64) - grow))
        self.hi = np.ascontiguousarray(float32_up(kind.box_hi.astype(np.float64) + grow))

    @staticmethod
    def usable(kind: ShapeKind) -> bool:
        """Whether ``kind`` has padded boxes (quads, triangles) within an extent float32 can carry."""
        return (hasattr(kind, "box_lo") and hasattr(kind, "pad")
                and pad_extent(kind.dtype, kind.pad) <= FILTER_MAX_EXTENT)

    @staticmethod
    def rays(origin, direction, t_max):
        """The rays in float32: ``origin``, ``1 / direction`` (3, N) and ``t_max``
        rounded up (scalar or (N,)); 1 / d beyond float32 becomes inf, which the
        slab test handles (the ray is then parallel to those planes)."""
        with np.errstate(divide="ignore", over="ignore"):
            inverse = (1.0 / direction).astype(np.float32)
            limit = float32_up(t_max)
        return origin.astype(np.float32), inverse, limit

    def pairs(self, start: int, stop: int, rays, ray_major: bool = True) -> tuple[np.ndarray, np.ndarray]:
        """``(ray, primitive)`` index pairs (primitives ``start:stop``, numbered
        from 0) the exact test must see; with ``ray_major`` sorted by ray and
        by primitive within a ray (what finding the nearest needs, not any-hit)."""
        origin, inverse, limit = rays
        m, n = stop - start, origin.shape[1]
        step = max(FILTER_MIN_RAYS, FILTER_BLOCK_ELEMENTS // m)
        if n <= step:
            return self._pairs(start, stop, origin, inverse, limit, ray_major)
        step = -(-n // -(-n // step))  # blocks of equal size
        found = [self._pairs(start, stop, origin[:, a:a + step], inverse[:, a:a + step],
                             limit[a:a + step] if np.ndim(limit) else limit, ray_major) for a in range(0, n, step)]
        return (np.concatenate([ray + a for (ray, _), a in zip(found, range(0, n, step))]),
                np.concatenate([j for _, j in found]))

    def _pairs(self, start, stop, origin, inverse, limit, ray_major):
        m, n = stop - start, origin.shape[1]
        # one axis at a time, so the temporaries are (m, n) and stay in cache
        entry, leave, t_lo, t_hi, t_far = (np.empty((m, n), np.float32) for _ in range(5))
        # 0 * inf is NaN (an origin on a plane the ray is parallel to), a huge
        # quotient overflows to inf: both are handled below, not errors
        with np.errstate(invalid="ignore", over="ignore"):
            for axis in range(3):
                o, inv = origin[axis], inverse[axis]
                np.subtract(self.lo[axis, start:stop, None], o, out=t_lo)
                t_lo *= inv
                np.subtract(self.hi[axis, start:stop, None], o, out=t_hi)
                t_hi *= inv
                # fmin/fmax: a 0 * inf NaN (an origin on a plane the ray is parallel to) drops out
                if axis == 0:
                    np.fmin(t_lo, t_hi, out=entry)
                    np.fmax(t_lo, t_hi, out=leave)
                else:
                    np.fmin(leave, np.fmax(t_lo, t_hi, out=t_far), out=leave)
                    np.fmax(entry, np.fmin(t_lo, t_hi, out=t_lo), out=entry)
        np.fmax(entry, np.float32(0.0), out=entry)
        if np.ndim(limit) or limit < np.inf:
            np.fmin(leave, limit, out=leave)
        if not ray_major:
            slot = np.flatnonzero(entry <= leave)  # primitive * n + ray
            j = slot // n
            return slot - j * n, j
        slot = np.flatnonzero((entry <= leave).T)  # ray * m + primitive
        ray = slot // m
        return ray, slot - ray * m


@functools.lru_cache(maxsize=64)
def _row_scores(m: int) -> np.ndarray:
    """``(m, 1)``: ``m - row`` for each row of a block of ``m`` primitives, in
    the narrowest unsigned type that holds ``m`` (brute force's scores: the
    greatest score at a ray's minimum is its lowest row there)."""
    score_type = np.uint8 if m <= 255 else np.uint16 if m <= 65535 else np.uint32
    scores = np.arange(m, 0, -1, dtype=score_type)[:, None]
    scores.flags.writeable = False  # shared by every call
    return scores


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
        # the float32 pre-filter of each flat kind (None: every pair is tested exactly)
        self.filters = [SlabFilter(k) if SlabFilter.usable(k) else None for k in self.kinds]

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

    def _blocks(self, n: int):
        """(kind, its filter, scene-wide offset of the block, start, stop) over every primitive."""
        for kind, slab, offset in zip(self.kinds, self.filters, self.offsets):
            m = len(kind)
            block = FILTER_PRIMITIVES if slab is not None else max(1, min(m, BLOCK_ELEMENTS // max(n, 1)))
            for start in range(0, m, block):
                yield kind, slab, int(offset), start, min(m, start + block)

    def _filtered(self, origin) -> bool:
        """Whether the slab filters may be used for rays from ``origin`` (all
        within every filter's reach; they are, from any point of the scene)."""
        reach = min((f.reach for f in self.filters if f is not None), default=0.0)
        return bool(reach) and origin.shape[1] > 0 and float(np.abs(origin).max()) <= reach

    def _intersect(self, origin, direction, t_max=np.inf, time=None, escaped_inf: bool = True) -> Hits:
        """Nearest hit with ``T_MIN < t < t_max`` for every ray, by brute force.

        The nearest primitive of a block is found with a ``min`` reduction and
        a greatest score (lowest index wins a tie) rather than ``argmin``, a
        slow, branchy loop along the first axis.  Flat primitives are tested
        exactly only where their :class:`SlabFilter` lets a pair through.

        Parameters
        ----------
        origin, direction : ndarray of shape (3, N)
            ``direction`` must be unit length.
        t_max : float or ndarray of shape (N,)
        time : None or ndarray of shape (N,)
            Each ray's time in [0, 1), for moving spheres.
        escaped_inf : bool
            False leaves ``t_max`` (not ``inf``) where nothing was hit, saving a
            pass for callers that read ``t`` only where ``primitive_idx >= 0``
            (the BVH's outsized primitives).
        """
        n = origin.shape[1]
        scalar_limit = np.ndim(t_max) == 0
        # t_max in the rays' type: a scalar as np.full would cast it, or an (N,) copy
        limit = origin.dtype.type(t_max) if scalar_limit else np.array(t_max, dtype=origin.dtype).reshape(n)
        # Nothing lies in (T_MIN, NaN): a NaN limit becomes -inf, which no t is
        # below.  (fmin below would take the first block's hit in its place, and
        # a later block's nearer sphere was then accepted, beyond any limit.)
        if scalar_limit:
            if np.isnan(limit):
                limit = origin.dtype.type(-np.inf)
        elif np.isnan(limit).any():  # one pass over the limits (~3 us for 16 Ki)
            limit[np.isnan(limit)] = -np.inf
        # Until a block has hit, best_t is the limit and best_idx -1 everywhere:
        # both are made when first needed (the first keyed block writes them
        # whole, with no np.full, no fmin against the limit, and no masked add).
        best_t = best_idx = None

        def nothing_hit():
            # the same numbers as broadcasting t_max (np.full casts a scalar as asarray
            # would); int32 indices, what Hits holds
            return np.full(n, limit) if scalar_limit else limit, np.full(n, -1, dtype=np.int32)

        rays32 = SlabFilter.rays(origin, direction, t_max) if self._filtered(origin) else None
        for kind, slab, offset, start, stop in self._blocks(n):
            if slab is not None and rays32 is not None:
                ray, j = slab.pairs(start, stop, rays32)
                if ray.size == 0:
                    continue
                if best_t is None:
                    best_t, best_idx = nothing_hit()
                t = kind.t_pairs(start + j, gather(origin, ray), gather(direction, ray),
                                 None if time is None else time.take(ray))
                # strict, as below: an earlier block keeps a tie
                keep = true_rows(t < best_t.take(ray))
                if keep.size == 0:
                    continue
                ray, j, t = ray.take(keep), j.take(keep), t.take(keep)
                if not (ray[1:] == ray[:-1]).any():  # one pair per ray (the usual case)
                    best_t[ray] = t
                    best_idx[ray] = offset + start + j
                    continue
                np.minimum.at(best_t, ray, t)
                # a ray's pairs come by primitive, so its first at its minimum has the lowest index
                won = true_rows(t == best_t.take(ray))
                ray_won = ray.take(won)
                first = won[np.concatenate(([True], ray_won[1:] != ray_won[:-1]))]
                best_idx[ray.take(first)] = offset + start + j.take(first)
                continue
            # a kind with keyed roots (spheres): the least key is the nearest
            # hit, and the keys rank the primitives as their roots would
            t = kind.key_block(start, stop, origin, direction, time)
            keyed = t is not None
            if keyed:
                nearest = np.minimum.reduce(t, axis=0)
                t_block = key_root(nearest)  # inf where nothing is hit, never NaN
            else:
                t = kind.t_block(start, stop, origin, direction, time)
                t_block = nearest = np.fmin.reduce(t, axis=0)  # fmin: a miss may be NaN
            # strict: an earlier block keeps a tie; false where nothing was hit
            closer = t_block < (limit if best_t is None else best_t)
            # Each ray's lowest primitive at its minimum (there is one where
            # closer): score every primitive m - row where it is at the
            # minimum, 0 elsewhere, and take the greatest score.  Three passes
            # over the block in bytes where a masked write per primitive (2 ns
            # an element) or argmax along the first axis (a branchy loop) took
            # ~70 us of a ~320 us 8 x 4096 block; a least rank (the row, plus m
            # where not at the minimum) took four: 16.6 against 14.7 us on
            # W1's 5 x 8192 float32 keys.
            m = stop - start
            top = np.maximum.reduce(np.multiply(np.equal(t, nearest).view(np.uint8), _row_scores(m)), axis=0)
            if best_idx is None:
                # every index still -1: (row + index + 1) * closer - 1, exact
                # in int32, where the masked subtraction below took ~13 us of
                # an 8192-ray block (row = m - top)
                best_idx = np.subtract(offset + start + m + 1, top, dtype=np.int32)
                best_idx *= closer
                best_idx -= 1
            else:
                np.subtract(offset + start + m, top, out=best_idx, where=closer, dtype=np.int32)
            if best_t is not None:
                best_t = np.fmin(best_t, t_block)
            elif not (keyed and scalar_limit and limit == np.inf):
                best_t = np.fmin(limit, t_block)
            else:  # fmin(inf, t_block) is t_block, which is never NaN here: no pass
                best_t = t_block
        if best_t is None:  # no block could hit
            best_t, best_idx = nothing_hit()
        if escaped_inf and not (scalar_limit and t_max == np.inf):  # else escaped_at_inf returns best_t
            best_t = escaped_at_inf(best_t, best_idx >= 0, t_max)
        return Hits(best_t, best_idx)

    def _occluded(self, origin, direction, t_max, time=None) -> np.ndarray:
        """Any hit with ``T_MIN < t < t_max`` (a shadow ray's question); rays
        stop being tested at their first hit.  Shape ``(N,)`` bool."""
        n = origin.shape[1]
        if isinstance(t_max, np.ndarray) and t_max.shape == (n,) and t_max.dtype == origin.dtype:
            limit = t_max  # what broadcast_to would return (a view of it), without its Python
        else:
            limit = np.broadcast_to(np.asarray(t_max, dtype=origin.dtype), (n,))
        blocks = list(self._blocks(n))
        if n and len(blocks) == 1 and (blocks[0][1] is None or not self._filtered(origin)):
            # one block tested whole (cornell_spheres' eight spheres): its
            # answer is the answer, with no live rays to track
            kind, _, _, start, stop = blocks[0]
            return kind.any_hit_block(start, stop, origin, direction, limit, time)
        blocked = np.zeros(n, dtype=bool)
        live = np.arange(n)
        o, d, lim, tm = origin, direction, limit, time
        rays32 = SlabFilter.rays(origin, direction, limit) if self._filtered(origin) else None
        for b, (kind, slab, _, start, stop) in enumerate(blocks):
            if live.size == 0:
                break
            if slab is not None and rays32 is not None:
                ray, j = slab.pairs(start, stop, rays32, ray_major=False)
                if ray.size == 0:
                    continue
                t = kind.t_pairs(start + j, gather(o, ray), gather(d, ray),
                                 None if tm is None else tm.take(ray))
                hit = np.zeros(live.size, dtype=bool)
                hit[ray[t < lim.take(ray)]] = True  # NaN compares false
            else:
                hit = kind.any_hit_block(start, stop, o, d, lim, tm)
            if b == len(blocks) - 1:  # the last block: no rays left to compact for
                blocked[live[hit]] = True
                break
            if hit.any():
                blocked[live[hit]] = True
                keep = true_rows(~hit)
                live, o, d, lim = live.take(keep), o.take(keep, axis=1), d.take(keep, axis=1), lim.take(keep)
                tm = None if tm is None else tm.take(keep)
                if rays32 is not None:
                    rays32 = (rays32[0].take(keep, axis=1), rays32[1].take(keep, axis=1), rays32[2].take(keep))
        return blocked

    def t_pairs(self, idx: np.ndarray, origin, direction, time=None) -> np.ndarray:
        """Exact ``t`` of ray ``p`` (column ``p`` of ``origin``, at ``time[p]``)
        against primitive ``idx[p]``: the arithmetic of :meth:`intersect`, pair by pair."""
        if len(self.kinds) == 1:
            return self.kinds[0].t_pairs(idx, origin, direction, time)
        t = np.empty(idx.shape, dtype=np.result_type(origin.dtype, self.dtype))
        kind = self.kind_of(idx)
        for k, shapes in enumerate(self.kinds):
            sel = true_rows(kind == k)
            if sel.size:
                t[sel] = shapes.t_pairs(idx.take(sel) - self.offsets[k], gather(origin, sel),
                                        gather(direction, sel), None if time is None else time.take(sel))
        return t

    def surface(self, origin, direction, t, idx, uv: bool = False, time=None) -> SurfaceHits:
        """What rays that hit primitives ``idx`` at ``t`` (at ``time``) hit (hitting rows only).

        ``uv`` computes surface coordinates too (only image textures read
        them, and for spheres they cost two transcendental functions per hit).
        """
        # the tables' gathers below want intp indices: cast once, not in each
        # take; hits' indices are in range, so the gathers skip bounds checks
        # (vecmath.gather): a 64 Ki hit record of W1 ~7 % faster
        rows = idx.astype(np.intp, copy=False)
        if len(self.kinds) == 1:
            point, outward, shading, coords = self.kinds[0].surface(rows, origin, direction, t, uv, time)
        else:
            n = idx.shape[0]
            point = np.empty((3, n), dtype=origin.dtype)
            outward = np.empty((3, n), dtype=origin.dtype)
            shading = np.empty((3, n), dtype=origin.dtype)
            coords = np.empty((2, n), dtype=origin.dtype) if uv else None
            kind = self.kind_of(idx)
            for k, shapes in enumerate(self.kinds):
                sel = true_rows(kind == k)
                if sel.size == 0:
                    continue
                p, g, s, c = shapes.surface(idx.take(sel) - self.offsets[k], gather(origin, sel),
                                            gather(direction, sel), t.take(sel), uv,
                                            None if time is None else time.take(sel))
                point[:, sel], outward[:, sel], shading[:, sel] = p, g, s
                if uv:
                    coords[:, sel] = c
        front_face = dot(direction, outward) < 0.0
        # 1 or -1, to flip the normals to face the ray (cheaper than a (3, N) where), in place
        sign = front_face.astype(outward.dtype)
        sign *= 2
        sign -= 1
        normal = None if shading is outward else shading * sign
        # flipped in place: every kind's outward normals are a new array of
        # its own (gathered from its table or computed), as is the one above
        geometric = np.multiply(outward, sign, out=outward)
        normal = geometric if normal is None else normal
        return SurfaceHits(point=point, normal=normal, geometric_normal=geometric, front_face=front_face,
                           material_idx=gather(self.material_idx, rows), primitive_idx=idx, uv=coords)

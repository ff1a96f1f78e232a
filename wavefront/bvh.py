"""A bounding volume hierarchy over spheres, traversed breadth-first for whole batches.

Depth-first traversal with a stack per ray does not vectorise.  Instead the
unit of work is a (ray, node) *pair*: every pair whose box the ray enters
before its best hit so far survives, interior nodes expand to two child
pairs, and leaves expand to (ray, sphere) pairs that are tested with exactly
the arithmetic of the brute-force intersector (:func:`sphere_roots`), so both
find the same sphere for every ray, bit for bit.  Each level is a handful of
NumPy calls over all pairs of that level; the Python loop runs over the
tree's depth, never over rays.

The tree is built top-down by median split along the widest axis of the
sphere centres, with at most ``LEAF_SIZE`` spheres per leaf.
"""

from __future__ import annotations

import numpy as np

from .vecmath import dot
from .geometry import T_MIN, Hits, SphereSet, nearest_root, sphere_roots

LEAF_SIZE = 4


class SphereBVH:
    """Same interface as :class:`~wavefront.geometry.SphereSet`."""

    def __init__(self, spheres: SphereSet):
        self.spheres = spheres
        self.center, self.radius = spheres.center, spheres.radius
        self.material_idx = spheres.material_idx
        self._build()

    def __len__(self) -> int:
        return len(self.spheres)

    def surface(self, origin, direction, t, sphere):
        return self.spheres.surface(origin, direction, t, sphere)

    def occluded(self, origin, direction, t_max) -> np.ndarray:
        return self.intersect(origin, direction, t_max).sphere_idx >= 0

    # -- construction ------------------------------------------------------

    def _build(self) -> None:
        c, r = self.center, self.radius
        lo_s, hi_s = c - r, c + r
        lo, hi, child, first, count, order = [], [], [], [], [], []

        def allocate(count_nodes: int) -> int:
            k = len(lo)
            for lst in (lo, hi):
                lst.extend([None] * count_nodes)
            child.extend([-1] * count_nodes), first.extend([0] * count_nodes), count.extend([0] * count_nodes)
            return k

        def _fill(k: int, idx: np.ndarray) -> None:
            lo[k] = lo_s[:, idx].min(axis=1)
            hi[k] = hi_s[:, idx].max(axis=1)
            if idx.size <= LEAF_SIZE:
                first[k], count[k] = len(order), idx.size
                order.extend(idx.tolist())
                return
            cen = c[:, idx]
            axis = int(np.argmax(cen.max(axis=1) - cen.min(axis=1)))
            ranked = idx[np.argsort(cen[axis], kind="stable")]
            half = ranked.size // 2
            left = allocate(2)  # siblings are adjacent: right = left + 1
            child[k] = left
            _fill(left, ranked[:half])
            _fill(left + 1, ranked[half:])

        _fill(allocate(1), np.arange(len(self.spheres)))
        self.lo = np.array(lo).T.copy()
        self.hi = np.array(hi).T.copy()
        self.child = np.array(child, dtype=np.int64)
        self.first = np.array(first, dtype=np.int64)
        self.count = np.array(count, dtype=np.int64)
        self.order = np.array(order, dtype=np.int64)

    # -- traversal -----------------------------------------------------------

    def intersect(self, origin, direction, t_max=np.inf) -> Hits:
        n = origin.shape[1]
        limit = np.broadcast_to(np.asarray(t_max, dtype=np.float64), (n,))
        best_t = limit.copy()
        with np.errstate(divide="ignore"):
            inv = 1.0 / direction
        d_dot_o = dot(direction, origin)
        o_dot_o = dot(origin, origin)
        ray = np.arange(n)
        node = np.zeros(n, dtype=np.int64)
        found_ray, found_t, found_sphere = [], [], []
        while ray.size:
            # slab test against the boxes, culled by the best hit so far
            o, iv = origin[:, ray], inv[:, ray]
            with np.errstate(invalid="ignore"):
                t0 = (self.lo[:, node] - o) * iv
                t1 = (self.hi[:, node] - o) * iv
            near = np.fmax(np.fmax(np.fmin(t0[0], t1[0]), np.fmin(t0[1], t1[1])), np.fmin(t0[2], t1[2]))
            far = np.fmin(np.fmin(np.fmax(t0[0], t1[0]), np.fmax(t0[1], t1[1])), np.fmax(t0[2], t1[2]))
            keep = (near <= far) & (far > T_MIN) & (near < best_t[ray])
            ray, node = ray[keep], node[keep]

            leaf = self.count[node] > 0
            if leaf.any():
                lr, ln = ray[leaf], node[leaf]
                reps = self.count[ln]
                pr = np.repeat(lr, reps)
                start = np.repeat(self.first[ln] - np.cumsum(reps) + reps, reps)
                sphere = self.order[start + np.arange(pr.size)]
                t = nearest_root(*sphere_roots(self.center[:, sphere], self.spheres.cc_minus_r2[sphere],
                                               origin[:, pr], direction[:, pr], d_dot_o[pr], o_dot_o[pr]))
                ok = (t < limit[pr])
                pr, t, sphere = pr[ok], t[ok], sphere[ok]
                np.minimum.at(best_t, pr, t)
                found_ray.append(pr), found_t.append(t), found_sphere.append(sphere)
            inner = ~leaf
            ir, left = ray[inner], self.child[node[inner]]
            ray = np.concatenate((ir, ir))
            node = np.concatenate((left, left + 1))

        best_idx = np.full(n, np.iinfo(np.int32).max, dtype=np.int64)
        if found_ray:
            pr, t, sphere = (np.concatenate(a) for a in (found_ray, found_t, found_sphere))
            winner = t == best_t[pr]
            # ties go to the lowest sphere index, as in brute force
            np.minimum.at(best_idx, pr[winner], sphere[winner])
        hit = best_idx != np.iinfo(np.int32).max
        return Hits(np.where(hit, best_t, np.inf), np.where(hit, best_idx, -1).astype(np.int32))

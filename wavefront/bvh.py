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
sphere centres, with at most ``LEAF_SIZE`` spheres per leaf.  Outsized
spheres (a ground of radius 1000 among balls of 0.2) are kept out of the tree
and tested by brute force first: inside the tree their boxes would cover
every node, and testing them first gives most rays a nearby hit that prunes
every box beyond it.
"""

from __future__ import annotations

import numpy as np

from .geometry import T_MIN, Hits, SphereSet, intersect_brute_force, is_hit, nearest_root, sphere_roots
from .vecmath import dot, gather

LEAF_SIZE = 4
LEAF_WAVES = 2  # nearest-first passes over a level's leaves before testing the rest at once
OUTSIZED = 8.0  # radius above this many times the median: tested outside the tree
MAX_OUTSIZED = 16


class SphereBVH:
    """Same interface as :class:`~wavefront.geometry.SphereSet`."""

    def __init__(self, spheres: SphereSet):
        self.spheres = spheres
        self.center, self.radius = spheres.center, spheres.radius
        self.material_idx = spheres.material_idx
        order = np.argsort(-spheres.radius, kind="stable")[:MAX_OUTSIZED]
        self.outsized = np.sort(order[spheres.radius[order] > OUTSIZED * np.median(spheres.radius)])
        inside = np.ones(len(spheres), dtype=bool)
        inside[self.outsized] = False
        self.outsized_set = SphereSet(spheres.center[:, self.outsized], spheres.radius[self.outsized],
                                      spheres.material_idx[self.outsized], spheres.dtype)
        self._build(np.flatnonzero(inside))

    def __len__(self) -> int:
        return len(self.spheres)

    def surface(self, origin, direction, t, sphere):
        return self.spheres.surface(origin, direction, t, sphere)

    def occluded(self, origin, direction, t_max) -> np.ndarray:
        return self.intersect(origin, direction, t_max).sphere_idx >= 0

    # -- construction ------------------------------------------------------

    def _build(self, members: np.ndarray) -> None:
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

        _fill(allocate(1), members)
        boxes = np.concatenate((np.array(lo).T, np.array(hi).T))  # (6, K): lo xyz, hi xyz
        self.root_box = boxes[:, :1].copy()
        self.child = np.array(child, dtype=np.int64)
        self.first = np.array(first, dtype=np.int64)
        self.count = np.array(count, dtype=np.int64)
        self.order = np.array(order, dtype=np.int64)
        # each leaf's spheres in a fixed-width table, padded with unhittable NaN spheres
        k = self.child.size
        self.leaf_slot = np.full((LEAF_SIZE, k), -1, dtype=np.int64)
        for j in range(LEAF_SIZE):
            has = self.count > j
            self.leaf_slot[j, has] = self.order[self.first[has] + j]
        real = np.maximum(self.leaf_slot, 0)
        self.leaf_center = np.where(self.leaf_slot >= 0, self.center[:, real], np.nan)  # (3, LEAF_SIZE, K)
        self.leaf_cc_minus_r2 = np.where(self.leaf_slot >= 0, self.spheres.cc_minus_r2[real], np.nan)  # (LEAF_SIZE, K)
        # for each interior node its two children's boxes, side by side (12, K)
        left = np.maximum(self.child, 0)
        self.child_boxes = np.concatenate((boxes[:, left], boxes[:, left + (self.child >= 0)]))


    # -- traversal -----------------------------------------------------------

    def intersect(self, origin, direction, t_max=np.inf) -> Hits:
        n = origin.shape[1]
        limit = np.broadcast_to(np.asarray(t_max, dtype=origin.dtype), (n,))
        # outsized spheres first: their hits bound the traversal
        first = intersect_brute_force(self.outsized_set, origin, direction, t_max)
        best_t = np.minimum(first.t, limit)
        d_dot_o = dot(direction, origin)
        o_dot_o = dot(origin, origin)
        with np.errstate(divide="ignore"):
            inv = 1.0 / direction
        # one table per side so each level gathers once: rows o, 1/d and lo, hi
        rays = np.concatenate((origin, inv))
        found_ray, found_t, found_sphere = [], [], []

        def test_leaves(ray, node):
            """Test (ray, leaf) pairs against all of each leaf's spheres at once.

            The leaf table is padded to LEAF_SIZE with spheres that cannot be
            hit (NaN), so one gather of the ray per pair and a (LEAF_SIZE, P)
            broadcast replace a ragged expansion to (ray, sphere) pairs.
            """
            slot = np.take(self.leaf_slot, node, axis=1)  # (LEAF_SIZE, P) sphere indices, -1 = padding
            sphere = np.maximum(slot, 0)
            t = nearest_root(*sphere_roots(
                np.take(self.leaf_center, node, axis=2), np.take(self.leaf_cc_minus_r2, node, axis=1),
                gather(origin, ray)[:, None, :], gather(direction, ray)[:, None, :],
                d_dot_o.take(ray), o_dot_o.take(ray)))
            t_leaf = t.min(axis=0)  # padding spheres are NaN: their roots come out inf
            # lowest sphere index among equal nearest roots, as brute force picks
            s_leaf = np.full(ray.size, np.iinfo(np.int64).max)
            for j in range(LEAF_SIZE):
                s_leaf = np.minimum(s_leaf, sphere[j] + (t[j] != t_leaf) * np.iinfo(np.int32).max)
            ok = np.flatnonzero(is_hit(t_leaf) & (t_leaf < limit.take(ray)) & (t_leaf <= best_t.take(ray)))
            pr, t_leaf, s_leaf = ray.take(ok), t_leaf.take(ok), s_leaf.take(ok)
            np.minimum.at(best_t, pr, t_leaf)
            found_ray.append(pr), found_t.append(t_leaf), found_sphere.append(s_leaf)

        def test_leaves_nearest_first(ray, node, near):
            """Leaves in waves: each ray's nearest leaf box first, then only the
            leaves that still start before the best hit.  Breadth-first order
            reaches all leaves of a level at once, so without this a ray would
            test every leaf its line crosses, not just those before its hit."""
            for _ in range(LEAF_WAVES - 1):
                if ray.size == 0:
                    return
                nearest = np.full(n, np.inf, dtype=near.dtype)
                np.minimum.at(nearest, ray, near)
                first = near == nearest.take(ray)
                now = np.flatnonzero(first)
                test_leaves(ray.take(now), node.take(now))
                later = np.flatnonzero(~first)
                ray, node, near = ray.take(later), node.take(later), near.take(later)
                still = np.flatnonzero(near <= best_t.take(ray))
                ray, node, near = ray.take(still), node.take(still), near.take(still)
            if ray.size:
                test_leaves(ray, node)

        if self.child[0] < 0:  # the whole tree is one leaf: test its box, then its spheres
            with np.errstate(invalid="ignore"):
                t0 = (self.root_box[:3] - origin) * inv
                t1 = (self.root_box[3:] - origin) * inv
            lo, hi = np.fmin(t0, t1), np.fmax(t0, t1)
            near = np.fmax(np.fmax(lo[0], lo[1]), lo[2])
            far = np.fmin(np.fmin(hi[0], hi[1]), hi[2])
            entered = np.flatnonzero((near <= far) & (far > T_MIN) & (near <= best_t))
            test_leaves(entered, np.zeros(entered.size, dtype=np.int64))
            ray = np.empty(0, dtype=np.int64)
        else:
            ray, node = np.arange(n), np.zeros(n, dtype=np.int64)
        # (ray, interior node) pairs whose box the ray enters; both children's
        # boxes are tested at once so each level gathers the ray data once
        while ray.size:
            r, boxes = np.take(rays, ray, axis=1), np.take(self.child_boxes, node, axis=1)
            best = best_t.take(ray)
            entered, entry = [], []
            for side in (0, 1):
                b = boxes[6 * side:6 * side + 6]
                with np.errstate(invalid="ignore"):
                    t0 = (b[:3] - r[:3]) * r[3:]
                    t1 = (b[3:] - r[:3]) * r[3:]
                lo, hi = np.fmin(t0, t1), np.fmax(t0, t1)
                near = np.fmax(np.fmax(lo[0], lo[1]), lo[2])
                far = np.fmin(np.fmin(hi[0], hi[1]), hi[2])
                keep = np.flatnonzero((near <= far) & (far > T_MIN) & (near <= best))  # <=: keep ties
                entered.append(keep)
                entry.append(near.take(keep))
            left = self.child.take(node)
            ray = np.concatenate((ray.take(entered[0]), ray.take(entered[1])))
            node = np.concatenate((left.take(entered[0]), left.take(entered[1]) + 1))
            near = np.concatenate(entry)
            is_leaf = self.count.take(node) > 0
            leaf_idx = np.flatnonzero(is_leaf)
            if leaf_idx.size:
                test_leaves_nearest_first(ray.take(leaf_idx), node.take(leaf_idx), near.take(leaf_idx))
            inner = np.flatnonzero(~is_leaf)
            ray, node = ray.take(inner), node.take(inner)

        best_idx = np.full(n, np.iinfo(np.int32).max, dtype=np.int64)
        from_first = np.flatnonzero((first.sphere_idx >= 0) & (first.t == best_t))
        best_idx[from_first] = self.outsized.take(first.sphere_idx.take(from_first))
        if found_ray:
            pr, t, sphere = (np.concatenate(a) for a in (found_ray, found_t, found_sphere))
            winner = np.flatnonzero(t == best_t.take(pr))
            # ties go to the lowest sphere index, as in brute force
            np.minimum.at(best_idx, pr.take(winner), sphere.take(winner))
        hit = best_idx != np.iinfo(np.int32).max
        return Hits(np.where(hit, best_t, np.inf), np.where(hit, best_idx, -1).astype(np.int32))

"""The BVH finds exactly the primitive brute force finds, for any scene and ray."""

import contextlib
import gc
import time

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from wavefront import bvh as bvh_module
from wavefront.accel import BVH_THRESHOLD, build_intersector
from wavefront.bvh import LEAF_SIZE, BVH, build_levels
from wavefront.geometry import FLOAT32_EXTENT, T_MIN, precision_for
from wavefront.shapes import Primitives, QuadSet, SphereSet, TriangleSet
from wavefront.shapes.base import exact_pad
from wavefront.shapes.triangle import twice_area
from wavefront.vecmath import normalize


def random_spheres(rng, m, spread, dtype=np.float64, scale=1.0):
    center = rng.uniform(-spread, spread, (3, m)) * scale
    radius = rng.uniform(0.01, 1.0, m) * rng.choice([1, 1, 1, 20], m) * scale  # a few large ones
    if m > 1:
        center[:, 1] = center[:, 0]  # a duplicated sphere: ties go to the lower index
        radius[1] = radius[0]
    return SphereSet(center, radius, np.zeros(m, dtype=np.int32), dtype)


def sphere_scene(rng, m, spread, dtype=np.float64, scale=1.0):
    return Primitives([random_spheres(rng, m, spread, dtype, scale)], dtype)


def mixed_scene(rng, counts, spread, extent):
    """Spheres, quads and triangles of all sizes, with exact duplicates and shared edges."""
    ns, nq, nt = counts
    spheres = random_spheres(rng, ns, spread)
    corner = rng.uniform(-spread, spread, (3, nq))
    u = rng.normal(size=(3, nq)) * rng.choice([0.3, 1.0, 8.0], nq)
    v = rng.normal(size=(3, nq)) * rng.choice([0.3, 1.0, 8.0], nq)
    quads = QuadSet(corner, u, v, np.zeros(nq, np.int32), np.float64, extent)
    v0 = rng.uniform(-spread, spread, (3, nt))
    v1 = v0 + rng.normal(size=(3, nt)) * rng.choice([0.2, 1.0, 5.0], nt)
    v2 = v0 + rng.normal(size=(3, nt)) * rng.choice([0.2, 1.0, 5.0], nt)
    if nt > 3:  # a triangle sharing an edge with the first, and a duplicate
        v0[:, 1], v1[:, 1], v2[:, 1] = v1[:, 0], v0[:, 0], 2 * v1[:, 0] - v2[:, 0] + 0.3
        v0[:, 2], v1[:, 2], v2[:, 2] = v0[:, 0], v1[:, 0], v2[:, 0]
    triangles = TriangleSet(v0, v1, v2, np.zeros(nt, np.int32), np.float64, extent)
    return Primitives([spheres, quads, triangles], np.float64, exact_pad(np.float64, extent))


def node_major_bvh(prims, extent, top_nodes=None):
    """A BVH with its tables stored node-major and leaves of BIG_LEAF_SIZE, as
    big trees have, and testing leaves in nearest-first rounds, as when rays
    reach many leaves, whatever its size.  ``top_nodes``: how many of its first
    nodes are also stored as columns (default TOP_NODES: all of a small tree's,
    so its walk never gathers rows; 3 walks the first two levels from the
    columns and the rest from gathered rows, as a big tree does)."""
    saved = bvh_module.NODE_MAJOR_NODES, bvh_module.BIG_TREE, bvh_module.TOP_NODES
    bvh_module.NODE_MAJOR_NODES = bvh_module.BIG_TREE = 0  # and with big trees' wider leaves
    if top_nodes is not None:
        bvh_module.TOP_NODES = top_nodes
    try:
        bvh = BVH(prims, extent)
    finally:
        bvh_module.NODE_MAJOR_NODES, bvh_module.BIG_TREE, bvh_module.TOP_NODES = saved
    bvh.leaf_rounds_above = 0
    bvh.subtree_depth = 1  # and walking subtrees nearest-first from depth 1
    return bvh


def subtree_rounds_bvh(prims, extent):
    """A BVH (rows layout) walking subtrees nearest-first from depth 2, as big trees do below the top."""
    bvh = BVH(prims, extent)
    bvh.subtree_depth = 2
    return bvh


@contextlib.contextmanager
def walked_in_parts():
    """The traversal's memory bounds (WALK_PAIRS, WALK_PART, LEAF_SLOTS) made
    tiny, so that every level and every leaf stage is walked in many parts, and
    its batches too (a scalar t_max stays a scalar in each, an array is cut)."""
    names = ("WALK_PAIRS", "WALK_PART", "LEAF_SLOTS", "TRAVERSAL_BATCH", "TRAVERSAL_BATCH_BIG")
    saved = [getattr(bvh_module, name) for name in names]
    for name, value in zip(names, (24, 7, 40, 97, 97)):
        setattr(bvh_module, name, value)
    try:
        yield
    finally:
        for name, value in zip(names, saved):
            setattr(bvh_module, name, value)


def assert_same_hits(prims, origin, direction, t_max, extent=None):
    brute = prims.intersect(origin, direction, t_max)
    if extent is None:
        lo, hi = prims.bounds()
        extent = max(np.abs(origin).max(), np.abs(lo).max(), np.abs(hi).max()) * np.sqrt(3)
    trees = (BVH(prims, extent), node_major_bvh(prims, extent), subtree_rounds_bvh(prims, extent),
             node_major_bvh(prims, extent, top_nodes=3))
    for bvh, parted in [(tree, False) for tree in trees] + [(trees[0], True), (trees[1], True), (trees[3], True)]:
        with walked_in_parts() if parted else contextlib.nullcontext():
            hits = bvh.intersect(origin, direction, t_max)
            blocked = bvh.occluded(origin, direction, t_max)
        np.testing.assert_array_equal(hits.primitive_idx, brute.primitive_idx)
        np.testing.assert_array_equal(hits.t, brute.t)
        # any-hit agrees with the existence of a nearest hit
        np.testing.assert_array_equal(blocked, brute.primitive_idx >= 0)
    np.testing.assert_array_equal(prims.occluded(origin, direction, t_max), brute.primitive_idx >= 0)
    return brute


@given(st.integers(1, 300), st.integers(0, 2**32 - 1), st.floats(1.0, 50.0), st.sampled_from([np.inf, 5.0]))
def test_bvh_agrees_exactly_with_brute_force_on_spheres(m, seed, spread, t_max):
    rng = np.random.default_rng(seed)
    prims = sphere_scene(rng, m, spread)
    n = 400
    origin = rng.uniform(-spread, spread, (3, n))
    direction = normalize(rng.normal(size=(3, n)))
    direction[:, :5] = np.eye(3)[:, [0, 1, 2, 2, 0]] * np.array([1, 1, -1, 1, -1])  # axis-aligned rays
    center, radius = prims.kinds[0].center, prims.kinds[0].radius
    origin[:, -3:] = center[:, :1] + np.array([[0.0], [0.0], [1.0]]) * radius[0]  # start on a surface
    assert_same_hits(prims, origin, direction, t_max)


@settings(deadline=None)
@given(st.tuples(st.integers(0, 80), st.integers(0, 80), st.integers(0, 300)), st.integers(0, 2**32 - 1),
       st.floats(1.0, 30.0), st.sampled_from([np.inf, 5.0]))
def test_bvh_agrees_exactly_with_brute_force_on_mixed_scenes(counts, seed, spread, t_max):
    """Spheres, quads and triangles in one tree: same primitive, same t, and
    the any-hit query agrees with the nearest hit's existence."""
    if sum(counts) == 0:
        counts = (0, 0, 1)
    rng = np.random.default_rng(seed)
    extent = 4 * spread
    prims = mixed_scene(rng, counts, spread, extent)
    n = 500
    origin = rng.uniform(-spread, spread, (3, n))
    direction = normalize(rng.normal(size=(3, n)))
    direction[:, :6] = np.eye(3)[:, [0, 1, 2, 2, 0, 1]] * np.array([1, 1, -1, 1, -1, -1])  # axis-aligned rays
    lo, hi = prims.bounds()
    # rays aimed at random points of primitives' boxes, and at triangle vertices and edges
    target = lo + rng.uniform(0, 1, lo.shape) * (hi - lo)
    pick = rng.integers(0, len(prims), n // 2)
    direction[:, 6:n // 2 + 6] = normalize(target[:, pick] - origin[:, 6:n // 2 + 6])[:, :n // 2]
    if counts[2]:
        tri = prims.kinds[-1]
        k = rng.integers(0, len(tri), 40)
        edge_point = tri.v0[:, k] + rng.uniform(0, 1, 40) * tri.e1[:, k]  # on an edge
        direction[:, -40:] = normalize(edge_point - origin[:, -40:])
    assert_same_hits(prims, origin, direction, t_max, extent)


@settings(deadline=None)
@given(st.integers(1, 200), st.integers(0, 2**32 - 1), st.booleans(),
       st.sampled_from([1e-3, 1.0, 1e3]), st.sampled_from([1.0, 30.0, 1e4]))
def test_bvh_agrees_on_grazing_rays_from_far_away(m, seed, prefer_float32, scale, distance):
    """The float32 traversal is conservative at any scale and distance.

    Rays start up to 10^4 scene sizes away and aim at points on sphere
    surfaces, many of them silhouettes, where a box test that rounds the
    wrong way would lose the hit.  Scenes run in float32 where the renderer
    would choose it (:func:`precision_for`), else in float64.
    """
    rng = np.random.default_rng(seed)
    spheres = random_spheres(rng, m, 10.0, np.float64, scale)
    extent = 10.0 * scale * max(distance, 4.0)
    if prefer_float32 and precision_for(spheres.radius, extent) == np.float32:
        spheres = random_spheres(np.random.default_rng(seed), m, 10.0, np.float32, scale)
    dtype = spheres.dtype
    n = 300
    target_sphere = rng.integers(0, m, n)
    on_surface = spheres.center.astype(np.float64)[:, target_sphere] + \
        normalize(rng.normal(size=(3, n))) * spheres.radius.astype(np.float64)[target_sphere]
    origin = normalize(rng.normal(size=(3, n))) * 10.0 * scale * distance
    direction = normalize(on_surface - origin)
    # a third of the rays run exactly along an axis through a target point
    axis = rng.integers(0, 3, n // 3)
    direction[:, : n // 3] = 0.0
    direction[axis, np.arange(n // 3)] = rng.choice([-1.0, 1.0], n // 3)
    origin[:, : n // 3] = on_surface[:, : n // 3] - direction[:, : n // 3] * 10.0 * scale * distance
    origin, direction = origin.astype(dtype), direction.astype(dtype)
    lo = np.abs(spheres.center.astype(np.float64)) + spheres.radius.astype(np.float64)
    brute = assert_same_hits(Primitives([spheres], dtype), origin, direction, np.inf,
                             max(np.abs(origin).max(), lo.max()) * np.sqrt(3))
    assert (brute.primitive_idx >= 0).mean() > 0.3  # the rays do find spheres


def test_bvh_with_a_ground_far_below_tiny_spheres():
    """Outsized spheres are tested outside the tree; rays start on the ground far from the tree."""
    rng = np.random.default_rng(3)
    m = 300
    center = np.vstack((rng.uniform(-5, 5, m), np.full(m, 0.2), rng.uniform(-5, 5, m)))
    radius = np.full(m, 0.2)
    center[:, 0], radius[0] = (0.0, -1000.0, 0.0), 1000.0
    prims = Primitives([SphereSet(center, radius, np.zeros(m, dtype=np.int32))])
    n = 2000
    origin = np.vstack((rng.uniform(-60, 60, n), np.zeros(n), rng.uniform(-60, 60, n)))
    origin[1] = np.sqrt(1000.0**2 - origin[0] ** 2 - origin[2] ** 2) - 1000.0  # on the ground
    target = center[:, rng.integers(1, m, n)] + rng.normal(0, 0.2, (3, n))
    direction = normalize(target - origin)
    brute = assert_same_hits(prims, origin, direction, np.inf)
    assert (brute.primitive_idx > 0).sum() > 100  # rays reach the small spheres
    assert (brute.primitive_idx == 0).sum() > 10  # and some hit the ground first


@settings(deadline=None, max_examples=30)
@given(st.integers(2, 24), st.integers(0, 2**32 - 1), st.sampled_from([0.0, 1e-3, 0.05]))
def test_bvh_agrees_on_rays_leaving_a_surface(n, seed, bumps):
    """Rays that start where rays hit a height field (bounce rays, shift 0 in the
    traversal) and leave in every direction, many grazing: the boxes they leave
    before T_MIN are culled, which must never lose a hit past T_MIN."""
    rng = np.random.default_rng(seed)
    x, z = np.meshgrid(np.linspace(-1, 1, n + 1), np.linspace(-1, 1, n + 1))
    y = bumps * rng.normal(size=x.shape)
    grid = np.stack((x, y, z)).reshape(3, -1)
    i = (np.arange(n)[:, None] * (n + 1) + np.arange(n)[None, :]).ravel()
    quads = np.stack((i, i + 1, i + n + 2, i + n + 1))
    faces = np.concatenate((quads[[0, 1, 2]], quads[[0, 2, 3]]), axis=1)
    # and one tall triangle to the side, so that the rays start inside the tree's box
    v0, v1, v2 = (np.hstack((grid[:, faces[j]], corner)) for j, corner in
                  enumerate(([[3.0], [-1.0], [0.0]], [[3.5], [1.0], [0.0]], [[3.0], [1.0], [0.5]])))
    tris = TriangleSet(v0, v1, v2, np.zeros(v0.shape[1], np.int32), np.float64, 4.0)
    prims = Primitives([tris], np.float64, exact_pad(np.float64, 4.0))
    m = 600
    origin = np.vstack((rng.uniform(-1, 1, m), np.full(m, 1.0), rng.uniform(-1, 1, m)))
    down = normalize(rng.normal(size=(3, m)) * np.array([[0.3], [0.0], [0.3]]) - np.array([[0], [1], [0]]))
    first = prims.intersect(origin, down)
    on = np.flatnonzero(first.primitive_idx >= 0)
    origin = origin[:, on] + first.t[on] * down[:, on]  # on the surface, as a bounce ray's origin
    direction = normalize(rng.normal(size=(3, on.size)))
    k = on.size // 3  # a third nearly along the surface
    direction[1, :k] *= rng.choice([1e-3, 1e-2, 0.1], k)
    direction[:, :k] = normalize(direction[:, :k])
    # and a third start just over T_MIN from the surface, aimed back at it: hits just past T_MIN
    back = slice(k, 2 * k)
    away = T_MIN * (1 + rng.choice([1e-9, 1e-6, 1e-3, 0.05, 1.0], k))  # brute force takes those past T_MIN
    origin[:, back] = origin[:, back] - away * direction[:, back]
    assert_same_hits(prims, origin, direction, np.inf, 4.0)
    # on their own too, as a batch whose rays all start inside the tree's box
    brute = assert_same_hits(prims, origin[:, back], direction[:, back], np.inf, 4.0)
    assert (brute.t < 1.5 * T_MIN).sum() > k // 10


@settings(deadline=None, max_examples=40)
@given(st.integers(1, 300), st.integers(0, 2**32 - 1), st.sampled_from([np.float32, np.float64]),
       st.sampled_from([1e-3, 1.0, 1e3]))
def test_bvh_agrees_on_triangles_hit_at_grazing_angles(m, seed, dtype, scale):
    """Rays nearly in the planes of triangles, slivers among them, in either
    precision: the plane pass's margin must hold every hit the exact test accepts,
    however far off its plane rounding puts it."""
    rng = np.random.default_rng(seed)
    v0 = rng.uniform(-1, 1, (3, m))
    e1 = rng.normal(size=(3, m)) * rng.choice([0.05, 0.5], m)
    e2 = rng.normal(size=(3, m)) * rng.choice([0.05, 0.5], m)
    sliver = rng.random(m) < 0.3  # nearly collinear edges
    e2[:, sliver] = e1[:, sliver] * rng.uniform(0.2, 2, sliver.sum()) + \
        rng.normal(size=(3, sliver.sum())) * rng.choice([1e-2, 1e-4, 1e-6], sliver.sum())
    v0, e1, e2 = v0 * scale, e1 * scale, e2 * scale
    keep = twice_area(v0, v0 + e1, v0 + e2) > 0
    tris = TriangleSet(v0[:, keep], (v0 + e1)[:, keep], (v0 + e2)[:, keep], np.zeros(keep.sum(), np.int32),
                       dtype, 4.0 * scale)
    prims = Primitives([tris], dtype, exact_pad(dtype, 4.0 * scale))
    n = 400
    k = rng.integers(0, len(tris), n)
    b = rng.dirichlet((1, 1, 1), n).T * rng.choice([1.0, 1.0 + 1e-6, 1.0 - 1e-6], n)  # some just off an edge
    target = tris.v0[:, k].astype(np.float64) + b[1] * tris.e1[:, k] + b[2] * tris.e2[:, k]
    normal = tris.normal[:, k].astype(np.float64)
    along = normalize(np.cross(normal, rng.normal(size=(3, n)), axis=0))  # in the plane
    tilt = rng.choice([0.0, 1e-7, 1e-5, 1e-3, 1e-1], n) * rng.choice([-1, 1], n)
    direction = normalize(along + tilt * normal)
    origin = target - direction * rng.uniform(0.01, 2.0, n) * scale
    origin, direction = origin.astype(dtype), direction.astype(dtype)
    assert_same_hits(prims, origin, direction, np.inf, 4.0 * scale)


def test_switch_is_automatic():
    rng = np.random.default_rng(0)
    assert isinstance(build_intersector(sphere_scene(rng, BVH_THRESHOLD, 10)), BVH)
    assert isinstance(build_intersector(sphere_scene(rng, BVH_THRESHOLD - 1, 10)), Primitives)


def test_level_by_level_build_is_a_valid_median_split_tree():
    """Every primitive is in exactly one leaf, leaves hold at most LEAF_SIZE,
    children's boxes lie in their parent's, siblings split their parent's run."""
    rng = np.random.default_rng(5)
    m = 1003
    lo = rng.uniform(-10, 10, (3, m))
    hi = lo + rng.uniform(0, 1, (3, m))
    tree = build_levels(lo, hi, np.arange(m))
    child, first, count, order = tree["child"], tree["first"], tree["count"], tree["order"]
    leaf = child < 0
    assert count[leaf].max() <= LEAF_SIZE and count[leaf].min() >= 1
    covered = np.concatenate([order[f:f + c] for f, c in zip(first[leaf], count[leaf])])
    np.testing.assert_array_equal(np.sort(covered), np.arange(m))
    inner = np.flatnonzero(~leaf)
    for side in (0, 1):  # children's boxes inside their parent's
        assert (tree["lo"][:, child[inner] + side] >= tree["lo"][:, inner]).all()
        assert (tree["hi"][:, child[inner] + side] <= tree["hi"][:, inner]).all()
    assert tree["first_leaf_depth"] >= 1
    # above the first leaves every level is full and node n's left child is 2n + 1 (the walk relies on it)
    above = np.arange(2 ** tree["first_leaf_depth"] - 1)
    np.testing.assert_array_equal(child[above], 2 * above + 1)


def test_queries_leave_no_reference_cycles():
    """A query's arrays are freed when it returns, not at the garbage
    collector's next pass: the traversal's closures once referred to
    themselves, which kept every array of every call alive until then (W2
    rendered ~10 % slower).  Every tree shape: rows, node-major, subtree rounds."""
    rng = np.random.default_rng(3)
    prims = mixed_scene(rng, (40, 40, 200), 5.0, 20.0)
    origin = rng.uniform(-6, 6, (3, 500))
    direction = normalize(rng.normal(size=(3, 500)))
    trees = (BVH(prims, 20.0), node_major_bvh(prims, 20.0), subtree_rounds_bvh(prims, 20.0))
    gc.collect()
    gc.disable()
    try:
        for tree in trees:
            tree.intersect(origin, direction)
            tree.occluded(origin, direction, 3.0)
        with walked_in_parts():
            trees[0].intersect(origin, direction)
        assert gc.collect() == 0
    finally:
        gc.enable()


def test_a_million_triangles_build():
    """A 1M-triangle mesh builds (not a timing test: performance is measured in
    benchmarks/, never asserted); the timing is printed for the curious."""
    n = 708  # 2 n^2 ~ 1M triangles
    rng = np.random.default_rng(0)
    x, z = np.meshgrid(np.linspace(-1, 1, n + 1), np.linspace(-1, 1, n + 1))
    y = 0.05 * rng.normal(size=x.shape)
    grid = np.stack((x, y, z)).reshape(3, -1)
    i = (np.arange(n)[:, None] * (n + 1) + np.arange(n)[None, :]).ravel()
    quads = np.stack((i, i + 1, i + n + 2, i + n + 1))
    faces = np.concatenate((quads[[0, 1, 2]], quads[[0, 2, 3]]), axis=1)
    tris = TriangleSet(grid[:, faces[0]], grid[:, faces[1]], grid[:, faces[2]],
                       np.zeros(faces.shape[1], np.int32), np.float64, 4.0)
    prims = Primitives([tris], np.float64, exact_pad(np.float64, 4.0))
    start = time.perf_counter()
    bvh = BVH(prims, 4.0)
    print(f"BVH over {len(prims)} triangles built in {time.perf_counter() - start:.2f} s")
    origin = np.tile(np.array([[0.0], [2.0], [0.0]]), (1, 2000)) + rng.uniform(-0.5, 0.5, (3, 2000))
    direction = normalize(rng.uniform(-1, 1, (3, 2000)) * np.array([[0.2], [0.0], [0.2]]) - np.array([[0], [1], [0]]))
    hits = bvh.intersect(origin, direction)
    assert (hits.primitive_idx >= 0).all()  # every ray down onto the grid finds it
    sample = np.arange(0, 2000, 400)  # brute force over 1M triangles is slow: a few rays suffice
    brute = prims.intersect(origin[:, sample], direction[:, sample])
    np.testing.assert_array_equal(hits.primitive_idx[sample], brute.primitive_idx)
    np.testing.assert_array_equal(hits.t[sample], brute.t)


@settings(deadline=None, max_examples=20)
@given(st.integers(2, 24), st.integers(0, 2**32 - 1), st.sampled_from([0.0, 0.3]))
def test_bvh_agrees_on_a_flat_carpet(n, seed, height):
    """A tree whose every box shares the root's planes on an axis (a flat grid of triangles,
    or of triangles all spanning the same height) walks without that axis: rays leaving the
    grid, grazing it, parallel to it (direction exactly +-0 on that axis, some from on its
    plane) and crossing it from far away all find brute force's hits."""
    rng = np.random.default_rng(seed)
    x, z = np.meshgrid(np.linspace(-1, 1, n + 1), np.linspace(-1, 1, n + 1))
    grid = np.stack((x, np.zeros_like(x), z)).reshape(3, -1)
    i = (np.arange(n)[:, None] * (n + 1) + np.arange(n)[None, :]).ravel()
    quads = np.stack((i, i + 1, i + n + 2, i + n + 1))
    faces = np.concatenate((quads[[0, 1, 2]], quads[[0, 2, 3]]), axis=1)
    v0, v1, v2 = (grid[:, faces[j]].copy() for j in range(3))
    v2[1] += height  # every triangle from y = 0 up to the same height: still one shared slab
    tris = TriangleSet(v0, v1, v2, np.zeros(v0.shape[1], np.int32), np.float64, 4.0)
    prims = Primitives([tris], np.float64, exact_pad(np.float64, 4.0))
    assert 1 in BVH(prims, 4.0).shared_axes  # (a tree of few leaves may share z as well)
    m = 600
    origin = np.vstack((rng.uniform(-1.5, 1.5, m), rng.choice([-2.0, 1.0, 3.0], m), rng.uniform(-1.5, 1.5, m)))
    target = np.vstack((rng.uniform(-1.2, 1.2, m), rng.uniform(-0.1, 0.1 + height, m), rng.uniform(-1.2, 1.2, m)))
    down = normalize(target - origin)
    first = prims.intersect(origin, down)
    on = np.flatnonzero(first.primitive_idx >= 0)
    start = origin[:, on] + first.t[on] * down[:, on]  # on the surface, as a bounce ray's origin
    direction = normalize(rng.normal(size=(3, on.size)))
    k = on.size // 4
    direction[1, :k] *= rng.choice([1e-3, 1e-2, 0.1], k)  # grazing
    direction[:, :k] = normalize(direction[:, :k])
    direction[1, k:2 * k] = rng.choice([0.0, -0.0], k)  # parallel to the slab
    direction[:, k:2 * k] = normalize(direction[:, k:2 * k])
    start[1, k:k + k // 2] = rng.choice([0.0, height, 0.05], k // 2)  # some on its planes
    assert_same_hits(prims, np.hstack((origin, start)), np.hstack((down, direction)), np.inf, 4.0)


@settings(deadline=None, max_examples=30)
@given(st.integers(64, 400), st.integers(0, 2**32 - 1), st.sampled_from([np.float32, np.float64]),
       st.sampled_from([1e-2, 1.0, 1e2]), st.booleans(), st.booleans())
def test_bvh_agrees_on_rays_leaving_spheres(m, seed, dtype, scale, carpet, moving):
    """Rays that start where rays hit spheres (bounce rays) and leave them outwards,
    inwards (refraction) and along their surface, and rays that start just over T_MIN
    from a sphere aimed back at it, with half the spheres moving (each ray at its own
    time) or none: the sphere pass drops a ray's slot where it leaves the padded
    (bounding) sphere before T_MIN, which must never lose a hit past T_MIN."""
    rng = np.random.default_rng(seed)
    if carpet:  # W2's carpet of equal balls, every one touching the ground
        center = np.vstack((rng.uniform(-11, 11, m), np.full(m, 0.2), rng.uniform(-11, 11, m))) * scale
        radius = np.full(m, 0.2 * scale)
    else:
        center = rng.uniform(-10, 10, (3, m)) * scale
        radius = rng.uniform(0.05, 1.0, m) * scale
    velocity = rng.uniform(-1, 1, (3, m)) * scale * (rng.random(m) < 0.5) if moving else None
    spheres = SphereSet(center, radius, np.zeros(m, np.int32), dtype, velocity)
    prims = Primitives([spheres], dtype)
    n = 1200
    sphere = rng.integers(0, m, n)
    time = rng.random(n) if moving else None
    c, r = spheres.center_at(sphere, time).astype(np.float64), spheres.radius.astype(np.float64)[sphere]
    origin = c + normalize(rng.normal(size=(3, n))) * 30.0 * scale
    first = prims.intersect(origin.astype(dtype), normalize(c - origin).astype(dtype), time=time)
    on = np.flatnonzero(first.primitive_idx >= 0)
    time = None if time is None else time[on]
    inward = normalize(c - origin)[:, on]
    start = origin[:, on] + first.t[on].astype(np.float64) * inward  # on a sphere, as a bounce ray's origin
    normal = normalize(start - spheres.center_at(first.primitive_idx[on], time).astype(np.float64))
    direction = normalize(rng.normal(size=(3, on.size)))
    third = on.size // 3
    outwards = np.sign((direction[:, :third] * normal[:, :third]).sum(axis=0))
    direction[:, :third] *= outwards * rng.choice([1.0, 1.0, -1.0], third)  # a third of them inwards
    along = normalize(np.cross(normal[:, third:2 * third], rng.normal(size=(3, third)), axis=0))
    direction[:, third:2 * third] = normalize(along + rng.choice([-1e-3, 0.0, 1e-3], third) * normal[:, third:2 * third])
    back = slice(2 * third, on.size)  # just over T_MIN out along the normal, aimed back
    away = T_MIN * (1 + rng.choice([1e-9, 1e-6, 1e-3, 0.05, 1.0], on.size - 2 * third))
    direction[:, back] = -normal[:, back]
    start[:, back] = start[:, back] + away * normal[:, back]
    bvh = BVH(prims, 40.0 * scale)
    assert bvh.sphere_leaves
    if carpet and not moving:  # every ball as tall as the others: the walk leaves the y planes out
        assert bvh.shared_axes == [1]
    origin, direction = start.astype(dtype), normalize(direction).astype(dtype)
    if moving:
        brute = prims.intersect(origin, direction, time=time)
        for tree in (bvh, node_major_bvh(prims, 40.0 * scale)):
            hits = tree.intersect(origin, direction, time=time)
            np.testing.assert_array_equal(hits.primitive_idx, brute.primitive_idx)
            np.testing.assert_array_equal(hits.t, brute.t)
    else:
        brute = assert_same_hits(prims, origin, direction, np.inf, 40.0 * scale)
    assert (brute.primitive_idx >= 0).mean() > 0.2


@pytest.mark.parametrize("scale", [1e18, 3e19, 1e20])
def test_bvh_agrees_on_spheres_whose_squares_overflow_float32(scale):
    """A reviewer's case: past a radius of ~1.8e19 the sphere pass's float32 squares
    are inf and its far root inf - inf, NaN; the pass must keep such a slot (the
    exact test, in float64, decides), not drop it as behind the ray's floor."""
    rng = np.random.default_rng(0)
    m, n = 60, 2000
    center = rng.uniform(-10, 10, (3, m)) * scale
    prims = Primitives([SphereSet(center, rng.uniform(0.5, 1.5, m) * scale, np.zeros(m, np.int32), np.float64)],
                       np.float64)
    origin = rng.uniform(-15, 15, (3, n)) * scale
    direction = normalize(rng.normal(size=(3, n)))
    with np.errstate(over="ignore", invalid="ignore"):
        brute = assert_same_hits(prims, origin, direction, np.inf, 40.0 * scale)
    assert (brute.primitive_idx >= 0).sum() > 100


def test_far_rays_take_the_far_tables():
    """Rays starting beyond NEAR_EXTENT / 2 on some axis walk a copy of the tree padded for
    the whole extent (``BVH.far``), the others tables padded for NEAR_EXTENT.  A forced
    float32 carpet of balls seen from a million units away, at silhouettes to within a few
    float32 epsilons of the distance: the hits are brute force's, and the negative control
    (every ray through the near tables) loses some of them, so the split is what keeps them."""
    disagree = 0
    for seed in range(4):
        rng = np.random.default_rng(seed)
        m, n = 300, 4000
        center = np.vstack((rng.uniform(-10, 10, m), rng.uniform(0, 0.4, m), rng.uniform(-10, 10, m)))
        spheres = SphereSet(center, rng.uniform(0.05, 0.3, m), np.zeros(m, np.int32), np.float32)
        prims = Primitives([spheres], np.float32)
        c64, r64 = spheres.center.astype(np.float64), spheres.radius.astype(np.float64)
        aim = rng.integers(0, m, n)
        eye = c64[:, aim] + normalize(rng.normal(size=(3, n))) * 1e6 * rng.uniform(0.3, 1.0, n)
        eye[:, :n // 4] = rng.uniform(-15, 15, (3, n // 4))  # near rays share the calls
        side = normalize(np.cross(c64[:, aim] - eye, rng.normal(size=(3, n)), axis=0))
        distance = np.linalg.norm(c64[:, aim] - eye, axis=0)
        miss = rng.choice([0.0, 1.0, 4.0, 16.0, 64.0], n) * rng.choice([-1.0, 1.0], n) * 2.0 ** -23 * distance
        origin = eye.astype(np.float32)
        direction = normalize(c64[:, aim] + side * (r64[aim] + miss) - eye).astype(np.float32)
        extent = float(np.abs(origin).max()) * np.sqrt(3)
        bvh = BVH(prims, extent)
        assert bvh.far is not None and bvh.far.leaf_reach32[0, -1] > bvh.leaf_reach32[0, -1]
        brute = prims.intersect(origin, direction)
        assert (brute.primitive_idx >= 0).sum() > n // 4
        hits = bvh.intersect(origin, direction)
        np.testing.assert_array_equal(hits.primitive_idx, brute.primitive_idx)
        np.testing.assert_array_equal(hits.t, brute.t)
        blocked = bvh.occluded(origin, direction, np.full(n, np.inf, np.float32))
        np.testing.assert_array_equal(blocked, brute.primitive_idx >= 0)
        bvh._far_rays = lambda origin: None  # the control
        disagree += np.count_nonzero(bvh.intersect(origin, direction).primitive_idx != brute.primitive_idx)
    assert disagree > 0


def test_float32_floor_is_float32_down_of_t_min_less_shift():
    """The ray floors' integer arithmetic gives np.nextafter's numbers, at every sign,
    at zero (shift == T_MIN), near T_MIN, and past float32's range."""
    f32_max = float(np.finfo(np.float32).max)
    edges = [0.0, 5e-324, 1e-300, T_MIN, np.nextafter(T_MIN, 0.0), np.nextafter(T_MIN, 1.0), 2 * T_MIN, 0.5,
             1.0, 1e3, 1e30, f32_max, np.nextafter(f32_max, np.inf), 2 * f32_max, 1e300]
    rng = np.random.default_rng(7)
    shift = np.concatenate((edges, rng.uniform(0, 2 * T_MIN, 500), 10.0 ** rng.uniform(-8, 8, 500)))
    with np.errstate(over="ignore"):  # both casts overflow past float32's range, as in a render
        expected = bvh_module.float32_down(T_MIN - shift)
        actual = bvh_module.float32_floor(shift)
    np.testing.assert_array_equal(actual.view(np.int32), expected.view(np.int32))


def anchored_scene(rng, m, ground_radius, huge_in_tree, scale=1.0):
    """A float32 cover-like scene whose spheres are anchored (``SphereSet.anchored``):
    a huge ground of ``ground_radius`` touching y = 0 (its reach twice that, beyond
    FLOAT32_EXTENT), three balls of radius 1, a carpet of small balls around them
    (some duplicated: ties go to the lower index), and with ``huge_in_tree`` twenty
    huge walls more than the BVH tests outside its tree (MAX_OUTSIZED), so that
    anchored huge spheres sit in its leaves too.  Returns the primitives and the
    scene's extent (every sphere's reach)."""
    k = m - 4
    center = np.vstack((rng.uniform(-11, 11, k), rng.uniform(0.0, 0.4, k), rng.uniform(-11, 11, k))) * scale
    radius = rng.uniform(0.05, 0.3, k) * rng.choice([1.0, 1.0, 1.0, 0.2, 0.02], k) * scale
    center[:, 1], radius[1] = center[:, 0], radius[0]  # a duplicate
    center = np.hstack(([[0.0], [-ground_radius], [0.0]], center, [[0.0, -4.0, 4.0], [1.0, 1.0, 1.0], [0.0, 0.0, 0.0]]))
    radius = np.concatenate(([ground_radius], radius, [1.0, 1.0, 1.0]))
    if huge_in_tree:
        n_walls = bvh_module.MAX_OUTSIZED + 4
        toward = normalize(rng.normal(size=(3, n_walls)))
        wall_radius = rng.uniform(300.0, 1500.0, n_walls)
        center = np.hstack((center, toward * (wall_radius + rng.uniform(15.0, 40.0, n_walls))))
        radius = np.concatenate((radius, wall_radius))
    spheres = SphereSet(center, radius, np.zeros(radius.size, np.int32), np.float32)
    assert spheres.anchored
    reach = np.linalg.norm(center, axis=0) + radius
    return Primitives([spheres], np.float32), float(reach.max())


def rays_in_an_anchored_scene(rng, prims, n, extent):
    """Hostile float32 rays (origins within ``extent``): from a camera's region at
    the carpet's silhouettes, from far out (beyond FLOAT32_EXTENT: a relative
    t_min each) at sphere surfaces, and rays leaving where those hit (bounce
    rays) outwards, inwards, along the surface to within 1e-9 of tangent (where
    the anchored roots' product form is ill-conditioned), and from just over
    T_MIN aimed back; and rays leaving the huge ground far out at grazing angles."""
    spheres = prims.kinds[0]
    c64, r64 = spheres.center.astype(np.float64), spheres.radius.astype(np.float64)
    small = np.flatnonzero(r64 < 2.0)
    target = small[rng.integers(0, small.size, n)]
    on_surface = c64[:, target] + normalize(rng.normal(size=(3, n))) * r64[target]
    origin = rng.uniform(-15, 15, (3, n)) + np.array([[0.0], [3.0], [0.0]])
    far = rng.random(n) < 0.3
    origin[:, far] = on_surface[:, far] + normalize(rng.normal(size=(3, far.sum()))) * \
        rng.uniform(0.3, 1.0, far.sum()) * extent * 0.9
    direction = normalize(on_surface - origin)
    origin, direction = origin.astype(np.float32), direction.astype(np.float32)
    first = prims.intersect(origin, direction)
    on = np.flatnonzero(first.primitive_idx >= 0)
    hit_sphere = first.primitive_idx[on]
    start = origin[:, on].astype(np.float64) + first.t[on].astype(np.float64) * direction[:, on].astype(np.float64)
    start = start.astype(np.float32)  # where the renderer's float32 bounce rays start
    normal = normalize(start.astype(np.float64) - c64[:, hit_sphere])
    leave = normalize(rng.normal(size=(3, on.size)))
    third = on.size // 3
    leave[:, :third] *= np.sign((leave[:, :third] * normal[:, :third]).sum(axis=0)) * \
        rng.choice([1.0, 1.0, -1.0], third)  # outwards, a third of them inwards
    along = normalize(np.cross(normal[:, third:2 * third], rng.normal(size=(3, third)), axis=0))
    tilt = rng.choice([0.0, 1e-9, 1e-7, 1e-5, 1e-3], third) * rng.choice([-1.0, 1.0], third)
    leave[:, third:2 * third] = normalize(along + tilt * normal[:, third:2 * third])
    back = slice(2 * third, on.size)  # just over T_MIN out along the normal, aimed back
    away = T_MIN * (1 + rng.choice([1e-6, 1e-3, 0.05, 1.0], on.size - 2 * third))
    leave[:, back] = -normal[:, back]
    start = start.astype(np.float64)
    start[:, back] = start[:, back] + away * normal[:, back]
    # the huge ground far out (up to a tenth of its radius from the carpet), rays leaving it grazing
    g = n // 4
    ground_radius = float(r64[0])
    xz = rng.uniform(-0.1, 0.1, (2, g)) * ground_radius
    ground = np.vstack((xz[0], np.sqrt(ground_radius ** 2 - (xz ** 2).sum(axis=0)) - ground_radius, xz[1]))
    up = normalize(ground - c64[:, :1])
    graze = normalize(np.cross(up, rng.normal(size=(3, g)), axis=0) + rng.choice([0.0, 1e-6, 1e-3, 0.05], g) * up)
    # from far out at silhouettes: lines passing the centre at the radius, give or take
    # a few float32 epsilons of the distance (where rounding decides hit or miss)
    s = n // 4
    aim = small[rng.integers(0, small.size, s)]
    eye = c64[:, aim] + normalize(rng.normal(size=(3, s))) * rng.uniform(0.2, 0.9, s) * extent
    view = normalize(c64[:, aim] - eye)
    side = normalize(np.cross(view, rng.normal(size=(3, s)), axis=0))
    distance = np.linalg.norm(c64[:, aim] - eye, axis=0)
    miss = rng.choice([0.0, 1.0, 4.0, 16.0, 64.0], s) * rng.choice([-1.0, 1.0], s) * 2.0 ** -23 * distance
    edge = c64[:, aim] + side * (r64[aim] + miss)
    all_origin = np.hstack((origin.astype(np.float64), start, ground, eye))
    all_direction = np.hstack((direction.astype(np.float64), leave, graze, edge - eye))
    return all_origin.astype(np.float32), normalize(all_direction).astype(np.float32)


@settings(deadline=None, max_examples=25)
@given(st.integers(BVH_THRESHOLD, 500), st.integers(0, 2**32 - 1), st.sampled_from([300.0, 1000.0, 2000.0]),
       st.booleans(), st.sampled_from(["inf", "finite", "nan"]))
def test_bvh_agrees_on_anchored_float32_spheres(m, seed, ground_radius, huge_in_tree, limits):
    """Float32 scenes with huge spheres run anchored (geometry.FLOAT32_MAX_REACH):
    the exact test of every sphere reaching past FLOAT32_EXTENT is
    anchored_roots, with a relative t_min for rays from beyond it, and the
    others' Haines' keyed roots (blocks and leaves of both kinds).  The BVH must still give brute force's hits and
    any-hits exactly: huge spheres outside the tree (the ground, the balls) and in
    its leaves, rays from far out, grazing rays, rays leaving surfaces (to within
    1e-9 of tangent, where the anchored small root is ill-conditioned and may
    land far from the sphere), and t_max of inf, finite per ray, or with NaN and
    -inf among finite ones."""
    rng = np.random.default_rng(seed)
    prims, reach = anchored_scene(rng, m, ground_radius, huge_in_tree)
    origin, direction = rays_in_an_anchored_scene(rng, prims, 1500, reach)
    n = origin.shape[1]
    if limits == "inf":
        t_max = np.inf
    else:
        t_max = rng.uniform(0.0, 30.0, n).astype(np.float32) * rng.choice([1.0, 1.0, 100.0], n).astype(np.float32)
        if limits == "nan":
            t_max[rng.random(n) < 0.1] = np.nan
            t_max[rng.random(n) < 0.05] = -np.inf
            t_max[rng.random(n) < 0.05] = T_MIN
    extent = max(reach, float(np.abs(origin).max()) * np.sqrt(3))
    bvh = BVH(prims, extent)
    huge = np.flatnonzero(prims.kinds[0].radius > FLOAT32_EXTENT)
    assert np.isin(huge, bvh.outsized).all() != huge_in_tree  # huge spheres in the leaves, or none there
    assert (np.abs(origin).max(axis=0) > FLOAT32_EXTENT).any()  # some rays have a t_min of their own
    brute = assert_same_hits(prims, origin, direction, t_max, extent)
    assert (brute.primitive_idx > 0).sum() > n // 10
    # and without an extent (the tree's own, a few units): an anchored set's pads stay wide
    hits = BVH(prims).intersect(origin, direction, t_max)
    np.testing.assert_array_equal(hits.primitive_idx, brute.primitive_idx)
    np.testing.assert_array_equal(hits.t, brute.t)

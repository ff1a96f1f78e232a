"""Brute force's float32 slab filter changes no hit: every query answers
exactly as testing every (ray, primitive) pair with the exact test does."""

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from wavefront import Transform
from wavefront.shapes import Primitives, QuadSet, SphereSet, TriangleSet
from wavefront.shapes import primitives as primitives_module
from wavefront.geometry import T_MIN
from wavefront.shapes.base import exact_pad, in_box
from wavefront.shapes.quad import box_quads
from wavefront.vecmath import normalize

# every kind of transform a box may carry (a mirror turns its faces' order of u and v)
SHEAR = np.array([[1.0, 0.6, 0.0, 0.0], [0.0, 1.0, -0.4, 0.0], [0.3, 0.0, 1.0, 0.0], [0.0, 0.0, 0.0, 1.0]])
TRANSFORMS = {
    "none": lambda s: None,
    "translate": lambda s: Transform.translate((1.5 * s, -2.0 * s, 0.5 * s)),
    "rotate": lambda s: Transform.rotate((1.0, 2.0, -0.5), 40.0),
    "rotate_y": lambda s: Transform.rotate((0, 1, 0), 15.0).then(Transform.translate((2.65 * s, 0, 2.95 * s))),
    "scale": lambda s: Transform.scale(1.7),
    "stretch": lambda s: Transform.scale((0.5, 2.0, 1.25)),
    "mirror": lambda s: Transform.scale((-1.0, 1.0, 1.0)).then(Transform.rotate((0, 0, 1), 30.0)),
    "shear": lambda s: Transform.from_array(SHEAR),
}


def exact_only(prims: Primitives) -> Primitives:
    """The same primitives tested the way brute force tested them before the
    filter: every pair, broadcast, with the exact test."""
    twin = Primitives(prims.kinds, prims.dtype, prims.pad)
    twin.filters = [None] * len(twin.kinds)
    return twin


def scene(rng, scale, n_boxes, n_quads, n_triangles, n_spheres, transform_names, dtype=np.float64):
    """A room of axis-aligned walls, boxes under the given transforms, loose
    quads and triangles of every orientation, and a few spheres, all within
    about 4 * scale of the origin."""
    s = scale
    lo, hi = -3 * s, 3 * s
    walls = [((lo, lo, hi), (hi - lo, 0, 0), (0, hi - lo, 0)),  # back
             ((lo, lo, lo), (0, 0, hi - lo), (0, hi - lo, 0)),  # left
             ((hi, lo, hi), (0, 0, lo - hi), (0, hi - lo, 0)),  # right
             ((lo, lo, lo), (hi - lo, 0, 0), (0, 0, hi - lo)),  # floor
             ((lo, hi, lo), (0, 0, hi - lo), (hi - lo, 0, 0)),  # ceiling
             ((-0.5 * s, hi - 0.01 * s, -0.4 * s), (s, 0, 0), (0, 0, 0.8 * s))]  # a light under it
    corners, us, vs = ([np.array(w[k], dtype=np.float64) for w in walls] for k in range(3))
    for b in range(n_boxes):
        size = rng.uniform(0.3, 1.5, 3) * s
        start = rng.uniform(-2, 1, 3) * s
        name = transform_names[b % len(transform_names)]
        for q in box_quads(tuple(start), tuple(start + size), 0, TRANSFORMS[name](s)):
            c, u, v = q.world()
            corners.append(c)
            us.append(u)
            vs.append(v)
    for _ in range(n_quads):
        corners.append(rng.uniform(-2.5, 2.5, 3) * s)
        us.append(rng.normal(size=3) * s * rng.choice([0.05, 0.5, 2.0]))
        vs.append(rng.normal(size=3) * s * rng.choice([0.05, 0.5, 2.0]))
    extent = 8 * s
    quads = QuadSet(np.array(corners).T, np.array(us).T, np.array(vs).T, np.zeros(len(corners), np.int32),
                    dtype, extent)
    v0 = rng.uniform(-2.5, 2.5, (3, n_triangles)) * s
    v1 = v0 + rng.normal(size=(3, n_triangles)) * s
    v2 = v0 + rng.normal(size=(3, n_triangles)) * s
    triangles = TriangleSet(v0, v1, v2, np.zeros(n_triangles, np.int32), dtype, extent)
    spheres = SphereSet(rng.uniform(-2, 2, (3, n_spheres)) * s, rng.uniform(0.1, 0.6, n_spheres) * s,
                        np.zeros(n_spheres, np.int32), dtype)
    return Primitives([spheres, quads, triangles], dtype, exact_pad(dtype, extent))


def hard_rays(rng, prims, n, scale):
    """Random rays, axis-aligned rays, rays from surfaces, rays aimed at
    corners and edges of quads and triangles, and rays lying in a quad's plane
    along its edges (grazing): every place a conservative filter could go wrong."""
    quads = prims.kinds[[type(k) for k in prims.kinds].index(QuadSet)]
    m = len(quads)
    origin = rng.uniform(-2.9, 2.9, (3, n)) * scale
    direction = normalize(rng.normal(size=(3, n)))
    k = n // 8
    direction[:, :6] = np.eye(3)[:, [0, 1, 2, 0, 1, 2]] * np.array([1, 1, 1, -1, -1, -1])  # axis-aligned
    # nearly axis-aligned: components whose reciprocals overflow float32 (or even float64)
    tiny = np.array([1e-39, -1e-42, 1e-300, -1e-320, 3e-38, 0.0])
    direction[:, 6:12] = normalize(np.eye(3)[:, [0, 1, 2, 0, 1, 2]] + tiny[None, :] * np.array([[0], [1], [-1]]))
    pick = rng.integers(0, m, n)
    a, b = rng.uniform(0, 1, n), rng.uniform(0, 1, n)
    # on an edge or at a corner: a or b (or both) exactly 0 or 1
    edge = rng.integers(0, 4, n)
    a = np.where(edge == 0, 0.0, np.where(edge == 1, 1.0, a))
    b = np.where(edge == 2, 0.0, np.where(edge == 3, 1.0, b))
    b = np.where(rng.uniform(size=n) < 0.2, np.round(b), b)
    target = quads.corner[:, pick] + a * quads.u[:, pick] + b * quads.v[:, pick]
    rows = slice(12, 6 + 3 * k)
    direction[:, rows] = normalize(target[:, rows] - origin[:, rows])
    # from points on quads (bounce rays), some leaving along the surface
    rows = slice(6 + 3 * k, 6 + 5 * k)
    origin[:, rows] = quads.corner[:, pick[rows]] + rng.uniform(0, 1, k * 2) * quads.u[:, pick[rows]] \
        + rng.uniform(0, 1, k * 2) * quads.v[:, pick[rows]]
    # grazing: in the plane of a quad, along (or parallel to) one of its edges
    rows = slice(6 + 5 * k, 6 + 7 * k)
    p = pick[rows]
    start = quads.corner[:, p] - 0.5 * quads.u[:, p] + np.round(rng.uniform(0, 1, 2 * k)) * quads.v[:, p]
    origin[:, rows] = start
    direction[:, rows] = normalize(quads.u[:, p])
    tri = prims.kinds[-1]
    if isinstance(tri, TriangleSet) and len(tri):
        rows = slice(6 + 7 * k, n)
        t_pick = rng.integers(0, len(tri), n - (6 + 7 * k))
        point = tri.v0[:, t_pick] + rng.uniform(0, 1, t_pick.size) * tri.e1[:, t_pick]  # on an edge
        direction[:, rows] = normalize(point - origin[:, rows])
    return origin, direction, target


def assert_same(prims, origin, direction, t_max, time=None):
    exact = exact_only(prims)
    want = exact.intersect(origin, direction, t_max, time)
    got = prims.intersect(origin, direction, t_max, time)
    np.testing.assert_array_equal(got.primitive_idx, want.primitive_idx)
    np.testing.assert_array_equal(got.t, want.t)
    np.testing.assert_array_equal(prims.occluded(origin, direction, t_max, time),
                                  exact.occluded(origin, direction, t_max, time))
    return want


@settings(deadline=None, max_examples=60)
@given(st.integers(0, 2**32 - 1), st.sampled_from([1e-3, 1.0, 555.0 / 6, 1e5]),
       st.tuples(st.integers(0, 4), st.integers(0, 12), st.integers(0, 12), st.integers(0, 3)),
       st.lists(st.sampled_from(sorted(TRANSFORMS)), min_size=1, max_size=4),
       st.sampled_from(["inf", "scalar", "per ray", "segments"]), st.booleans(),
       st.sampled_from([np.float64, np.float64, np.float32]))
def test_filtered_brute_force_equals_the_exact_test_of_every_pair(seed, scale, counts, transforms, limit, blocks,
                                                                  dtype):
    """Same primitive, same t, same any-hit answer as the exact test of every
    pair: for boxes under every kind of transform, walls, loose quads,
    triangles and spheres; for rays at edges and corners, from surfaces, along
    surfaces and along the axes; with no limit, one limit, a limit per ray,
    and shadow-ray segments ending on quads (the emitter's own plane); in
    float64 and in float32 (a scene's ``precision: float32``)."""
    rng = np.random.default_rng(seed)
    prims = scene(rng, scale, *counts, transforms, dtype)
    n = 600
    origin, direction, target = hard_rays(rng, prims, n, scale)
    if limit == "inf":
        t_max = np.inf
    elif limit == "scalar":
        t_max = 2.0 * scale
    elif limit == "per ray":
        t_max = rng.uniform(0, 6, n) * scale
    else:  # shadow rays towards points on quads, stopping just short of them or exactly at them
        origin[:, 6:] = rng.uniform(-2.9, 2.9, (3, n - 6)) * scale
        to = target - origin
        distance = np.sqrt((to * to).sum(axis=0))
        direction = to / distance
        t_max = distance * np.where(rng.uniform(size=n) < 0.5, 1.0 - 1e-4, 1.0)
    names = ("FILTER_PRIMITIVES", "FILTER_MIN_RAYS", "FILTER_BLOCK_ELEMENTS")
    saved = [getattr(primitives_module, name) for name in names]
    if blocks:  # 5 primitives and 40 rays per block: ties across blocks go to the earlier block
        for name, value in zip(names, (5, 40, 200)):
            setattr(primitives_module, name, value)
    origin, direction = origin.astype(dtype), direction.astype(dtype)
    t_max = t_max if np.ndim(t_max) == 0 else t_max.astype(dtype)
    try:
        assert_same(prims, origin, direction, t_max)
    finally:
        for name, value in zip(names, saved):
            setattr(primitives_module, name, value)


def test_duplicate_quads_tie_to_the_lower_index():
    corner, u, v = np.array([[0.0], [0.0], [1.0]]), np.array([[1.0], [0], [0]]), np.array([[0.0], [1], [0]])
    quads = QuadSet(np.repeat(corner, 3, 1), np.repeat(u, 3, 1), np.repeat(v, 3, 1), np.zeros(3, np.int32),
                    np.float64, 4.0)
    prims = Primitives([quads], np.float64, exact_pad(np.float64, 4.0))
    origin = np.array([[0.5, 0.0, 1.0], [0.5, 0.0, 1.0], [0.0, 0.0, 0.0]])
    hits = assert_same(prims, origin, normalize(np.array([[0.0, 0.0, 0.0], [0.0, 0.0, 0.0], [1.0, 1.0, 1.0]])),
                       np.inf)
    np.testing.assert_array_equal(hits.primitive_idx, [0, 0, 0])


def test_rays_from_beyond_the_extent_fall_back_to_every_pair():
    """The filter's float32 bound holds for origins within the extent; a ray
    from farther away is tested exactly against every primitive."""
    rng = np.random.default_rng(5)
    prims = scene(rng, 1.0, 2, 4, 4, 1, ["rotate"])
    origin = np.tile(np.array([[1e7], [0.3], [0.2]]), 50)
    direction = normalize(np.array([[-1.0], [0.0], [0.0]]) + rng.normal(size=(3, 50)) * 1e-7)
    assert not prims._filtered(origin)
    hits = assert_same(prims, origin, direction, np.inf)
    assert (hits.primitive_idx >= 0).all()


def test_the_filter_keeps_few_pairs_in_a_room():
    """What the filter is for (not a timing): in a room of walls and two
    boxes, a ray is tested exactly against a few of the 18 quads, not all."""
    rng = np.random.default_rng(7)
    prims = scene(rng, 1.0, 2, 0, 0, 0, ["rotate_y"])
    origin, direction, _ = hard_rays(rng, prims, 1000, 1.0)
    quads = prims.kinds[0]
    ray, _ = prims.filters[0].pairs(0, len(quads), primitives_module.SlabFilter.rays(origin, direction, np.inf))
    assert ray.size < 4 * origin.shape[1] < len(quads) * origin.shape[1]


@pytest.mark.parametrize("name", sorted(TRANSFORMS))
def test_boxes_under_each_transform(name):
    rng = np.random.default_rng(sum(map(ord, name)))
    for scale in (1e-2, 1.0, 300.0):
        prims = scene(rng, scale, 3, 0, 0, 0, [name])
        origin, direction, _ = hard_rays(rng, prims, 2000, scale)
        assert_same(prims, origin, direction, np.inf)


def textbook_quad_t(corner, normal, offset, alpha_axis, beta_axis, box_lo, box_hi, origin, direction):
    """The quad test as RTOW writes it (what ``QuadSet.exact_t`` computed
    before it ran its sums in place)."""
    denom = normal[0] * direction[0] + normal[1] * direction[1] + normal[2] * direction[2]
    t = offset - (normal[0] * origin[0] + normal[1] * origin[1] + normal[2] * origin[2])
    with np.errstate(divide="ignore", invalid="ignore", over="ignore"):
        t /= denom
        p = (origin[0] + t * direction[0], origin[1] + t * direction[1], origin[2] + t * direction[2])
        q = (p[0] - corner[0], p[1] - corner[1], p[2] - corner[2])
        a = q[0] * alpha_axis[0] + q[1] * alpha_axis[1] + q[2] * alpha_axis[2]
        b = q[0] * beta_axis[0] + q[1] * beta_axis[1] + q[2] * beta_axis[2]
        ok = (t > T_MIN) & (a >= 0) & (a <= 1) & (b >= 0) & (b <= 1) & in_box(p, box_lo, box_hi)
    return np.where(ok, t, np.inf)


@settings(deadline=None, max_examples=30)
@given(st.integers(0, 2**32 - 1), st.sampled_from([1e-3, 1.0, 1e4]), st.sampled_from([np.float64, np.float32]))
def test_the_quad_test_is_the_textbook_arithmetic_bit_for_bit(seed, scale, dtype):
    """In place or not, the quad test computes the same numbers, broadcast
    over a block and pair by pair (the BVH's and the filter's way)."""
    rng = np.random.default_rng(seed)
    prims = scene(rng, scale, 3, 8, 0, 0, sorted(TRANSFORMS), dtype)
    quads = prims.kinds[[type(k) for k in prims.kinds].index(QuadSet)]
    origin, direction, _ = hard_rays(rng, prims, 300, scale)
    origin, direction = origin.astype(dtype), direction.astype(dtype)
    block = quads.t_block(0, len(quads), origin, direction)
    want = textbook_quad_t(*quads.block(0, len(quads)), origin[:, None, :], direction[:, None, :])
    np.testing.assert_array_equal(block, want)
    assert np.isfinite(want).any()
    idx = rng.integers(0, len(quads), origin.shape[1])
    np.testing.assert_array_equal(quads.t_pairs(idx, origin, direction),
                                  textbook_quad_t(*quads.gather(idx), origin, direction))


@settings(deadline=None, max_examples=40)
@given(st.integers(0, 2**32 - 1), st.sampled_from([np.float64, np.float32]), st.booleans())
def test_sphere_any_hit_answers_as_the_nearest_root_below_t_max(seed, dtype, moving):
    """The spheres' shadow-ray test (both roots compared, no nearest chosen)
    answers exactly ``nearest root < t_max`` for rays from inside, from the
    surface (leaving and entering), grazing, and with ``t_max`` at a root,
    for huge, tiny and ordinary spheres; moving spheres take the generic test."""
    rng = np.random.default_rng(seed)
    m, n = 7, 3000
    center = rng.uniform(-3, 3, (3, m))
    center[:, 0] = (-1001.0, 0.0, 0.0)  # a wall of radius 1000
    radius = np.concatenate(([1000.0, 1e-3], rng.uniform(0.05, 2.0, m - 2)))
    spheres = SphereSet(center, radius, np.zeros(m, np.int32), dtype,
                        velocity=rng.uniform(-0.5, 0.5, (3, m)) if moving else None)
    time = rng.uniform(0, 1, n).astype(dtype) if moving else None
    origin = rng.uniform(-4, 4, (3, n))
    direction = normalize(rng.normal(size=(3, n)))
    pick = rng.integers(0, m, n)
    on = rng.random(n) < 0.5  # from a sphere's surface, or just inside it
    outward = normalize(rng.normal(size=(3, n)))
    origin[:, on] = (center[:, pick] + radius[pick] * rng.choice([1.0, 1 - 1e-7, 1 - 0.5], n) * outward)[:, on]
    grazing = rng.random(n) < 0.2  # along the tangent plane
    tangent = normalize(np.cross(outward, rng.normal(size=(3, n)), axis=0))
    direction[:, on & grazing] = tangent[:, on & grazing]
    origin, direction = origin.astype(dtype), direction.astype(dtype)
    t = np.fmin.reduce(spheres.t_block(0, m, origin, direction, time), axis=0)
    t_max = rng.choice([np.inf, 1.0, 1e-3, 50.0], n).astype(dtype)
    at_root = np.isfinite(t) & (rng.random(n) < 0.3)
    t_max[at_root] = t[at_root]  # a root exactly at t_max is not below it
    past = at_root & (rng.random(n) < 0.5)
    t_max[past] = np.nextafter(t, np.inf)[past]  # and one just past it is
    want = (spheres.t_block(0, m, origin, direction, time) < t_max).any(axis=0)
    np.testing.assert_array_equal(spheres.any_hit_block(0, m, origin, direction, t_max, time), want)
    assert want.any() and not want.all()


@settings(deadline=None, max_examples=60)
@given(st.integers(0, 2**32 - 1), st.sampled_from([np.float64, np.float32]), st.integers(1, 300),
       st.booleans(), st.sampled_from([1, 7, 64, 1 << 18]))
def test_brute_force_picks_the_lowest_nearest_sphere(seed, dtype, n, limited, block_elements):
    """Brute force's least-rank pick of each ray's nearest sphere is
    ``argmin`` over every sphere's exact ``t``: the same hits, ``t`` and
    lowest index on a tie (duplicated spheres meet a ray at the same ``t``),
    whether the spheres come in one block or several (a tie across blocks
    goes to the earlier), in blocks of more than 128 (the wider ranks) or
    fewer."""
    rng = np.random.default_rng(seed)
    m = int(rng.choice([rng.integers(1, 10), rng.integers(100, 200)]))
    center, radius = rng.uniform(-3, 3, (3, m)), rng.uniform(0.2, 2.0, m)
    twin = rng.integers(0, m, m)  # every sphere again, some twice: ties
    center, radius = np.concatenate((center, center[:, twin]), axis=1), np.concatenate((radius, radius[twin]))
    spheres = SphereSet(center, radius, np.zeros(radius.size, np.int32), dtype)
    prims = Primitives([spheres], dtype)
    origin = rng.uniform(-5, 5, (3, n)).astype(dtype)
    direction = normalize(rng.normal(size=(3, n))).astype(dtype)
    t_max = rng.uniform(0.5, 8.0, n).astype(dtype) if limited else np.inf
    saved, primitives_module.BLOCK_ELEMENTS = primitives_module.BLOCK_ELEMENTS, block_elements
    try:
        hits = prims.intersect(origin, direction, t_max)
    finally:
        primitives_module.BLOCK_ELEMENTS = saved
    t = spheres.t_block(0, len(spheres), origin, direction)
    t = np.where(np.isnan(t), np.inf, t)  # a miss may be NaN
    nearest = t.argmin(axis=0)  # the first (lowest) index at the minimum
    t_nearest = t.min(axis=0)
    hit = t_nearest < t_max
    np.testing.assert_array_equal(hits.primitive_idx, np.where(hit, nearest, -1))
    np.testing.assert_array_equal(hits.t, np.where(hit, t_nearest, np.inf).astype(dtype))
    assert hits.primitive_idx.dtype == np.int32


@pytest.mark.parametrize("scalar", [False, True])
def test_a_nan_limit_admits_no_hit_across_blocks(scalar):
    """Nothing lies in (T_MIN, NaN): brute force's nearest-hit query agrees
    with its any-hit query and the BVH there, also when the spheres span
    several blocks (the first block's hit once became the bound of the next,
    whose nearer sphere was then accepted)."""
    from wavefront.bvh import BVH

    n, m = 4097, 100  # blocks of fewer spheres than m at this many rays
    centres = np.zeros((3, m))
    centres[2] = -10.0 - (m - np.arange(m))  # a later index is nearer
    spheres = SphereSet(centres, np.full(m, 0.25), np.zeros(m, np.int32))
    prims = Primitives([spheres], np.float64)
    assert len(list(prims._blocks(n))) > 1  # the case at stake
    origin, direction = np.zeros((3, n)), np.zeros((3, n))
    direction[2] = -1.0
    t_max = np.float64(np.nan) if scalar else np.where(np.arange(n) % 2 == 0, np.nan, 50.0)
    hits = prims.intersect(origin, direction, t_max)
    nan_rows = np.isnan(np.broadcast_to(t_max, (n,)))
    assert (hits.primitive_idx[nan_rows] == -1).all()
    assert not prims.occluded(origin, direction, t_max)[nan_rows].any()
    # finite limits still find the nearest sphere (index m - 1, at 10.75)
    if not scalar:
        assert (hits.primitive_idx[~nan_rows] == m - 1).all()
        assert np.allclose(hits.t[~nan_rows], 10.75)
    tree = BVH(prims)
    assert (tree.intersect(origin, direction, t_max).primitive_idx == hits.primitive_idx).all()


def test_sphere_sets_and_their_subsets_are_read_only():
    """A set's shared axes, anchors and cached key plans are derived from its
    centres and radii once: writing a centre in place after a query kept the
    old hits (session 12's review), in a subset (the BVH's outsized set) too."""
    from wavefront.shapes.sphere import SphereSet
    center = np.array([[0.0, 1.0, 2.0], [1.0, 1.0, 1.0], [0.0, 0.0, 0.0]])
    spheres = SphereSet(center, np.array([0.5, 0.5, 2000.0]), np.zeros(3, dtype=np.int32), np.float32)
    for s in (spheres, spheres.subset(np.array([1, 2]))):
        for field in (s.center, s.radius, s.radius_squared):
            with pytest.raises(ValueError):
                field[..., 0] = 5.0

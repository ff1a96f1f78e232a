"""Float32 for scenes of small spheres inside huge ones (geometry.FLOAT32_MAX_REACH).

The policy both ways (cornell_spheres' walls of radius 1000 and the cover
scene's ground, through the BVH, run anchored in float32; far cameras, tiny
spheres, far small spheres, astronomic reaches and moving spheres keep
float64), the anchored roots' error
(no ray leaving a huge wall finds it again, where Haines' float32 roots do),
and the image: a per-pixel z-test of cornell_spheres in float32 against
float64, with a wrong power of the origin that the same test must reject.
"""

import dataclasses
from pathlib import Path

import numpy as np
import pytest

import wavefront.shapes.sphere as sphere_module
from wavefront import Dielectric, Metal, Sphere, load_scene
from wavefront.geometry import (FLOAT32_EXTENT, T_MIN, anchored_roots, first_root, key_root, nearest_root,
                                nearest_root_key, roots_key, sphere_root_keys, sphere_roots)
from wavefront.bvh import BVH
from wavefront.scene import precision_of
from wavefront.shapes import Primitives, SphereSet
from wavefront.vecmath import normalize

from .test_light_sampling import estimate, rejected, with_settings

SCENES = Path(__file__).resolve().parent.parent / "scenes"


def cornell_spheres():
    return load_scene(SCENES / "cornell_spheres.yaml")


def test_huge_walls_around_a_small_room_run_anchored_in_float32():
    scene = cornell_spheres()
    assert precision_of(scene) == np.float32
    spheres = scene.compile().shapes.kinds[0]
    assert spheres.anchored and spheres.dtype == np.float32
    # the anchors are antipodal points of each sphere, the first nearest the origin
    near, far = spheres.near_point.astype(np.float64), spheres.far_point.astype(np.float64)
    np.testing.assert_allclose(near[:, 0], (-1.0, 0.0, 0.0))
    np.testing.assert_allclose(0.5 * (near + far), spheres.center.astype(np.float64), atol=1e-4)


@pytest.mark.parametrize("change", ["far camera", "tiny sphere", "far small sphere", "astronomic wall",
                                    "moving sphere", "no huge sphere", "whitted", "ground of 1e5",
                                    "huge lamp", "huge mirror", "huge fuzzy metal", "huge glass"])
def test_hostile_scenes_keep_float64(change):
    """Everything but the huge spheres must pass the float32 rule on its own."""
    scene = cornell_spheres()
    white = "white"
    if change == "far camera":
        scene = scene.replace(camera=dataclasses.replace(scene.camera, look_from=(0.0, 0.0, 400.0)))
    elif change == "tiny sphere":
        scene = scene.replace(spheres=[*scene.spheres, Sphere((0.0, 0.0, 0.0), 1e-4, white)])
    elif change == "far small sphere":
        scene = scene.replace(spheres=[*scene.spheres, Sphere((300.0, 0.0, 0.0), 1.0, white)])
    elif change == "astronomic wall":
        scene = scene.replace(spheres=[*scene.spheres, Sphere((0.0, -2e6 - 1.0, 0.0), 2e6, white)])
    elif change == "moving sphere":
        scene = scene.replace(spheres=[*scene.spheres, Sphere((0.0, 0.0, 0.0), 0.1, white, center1=(0.1, 0, 0))])
    elif change == "whitted":  # pixel centres: the horizon of a huge ground must not flip with rounding
        scene = scene.replace(render=dataclasses.replace(scene.render, integrator="whitted"))
    elif change == "ground of 1e5":  # its horizon's hits land ~5e-3 off the surface in float32
        scene = scene.replace(spheres=[Sphere((0.0, -1e5 - 1.0, 0.0), 1e5, white), *scene.spheres[5:]])
    elif change == "huge lamp":  # the ceiling lights the room: its shadow rays' margin is below float32's error
        scene = scene.replace(spheres=[*scene.spheres[:3], dataclasses.replace(scene.spheres[3], material="lamp"),
                                       *scene.spheres[4:]])
    elif change.startswith("huge") and change != "huge lamp":
        # a specular ground sends grazing rays on at the angles where the anchored
        # roots' self-hits grow (u |o - q| / cos): a metal ground's horizon came out darker
        material = {"huge mirror": Metal(albedo=(0.9, 0.9, 0.9), fuzz=0.0),
                    "huge fuzzy metal": Metal(albedo=(0.9, 0.9, 0.9), fuzz=0.05),
                    "huge glass": Dielectric(refraction_index=1.5)}[change]
        scene = scene.replace(materials={**scene.materials, "floor": material},
                              spheres=[*scene.spheres[:2], dataclasses.replace(scene.spheres[2], material="floor"),
                                       *scene.spheres[3:]])
    elif change == "no huge sphere":  # the walls at 300: everything fails the rule, nothing is huge
        scene = scene.replace(spheres=[Sphere((300.0, 0.0, 0.0), 2.0, white), *scene.spheres[5:]])
    assert precision_of(scene) == np.float64


def test_the_cover_with_a_metal_ground_keeps_float64():
    """The BVH-sized case of the specular rule: the cover scene with a metal
    ground came out 4-8 % darker along its horizon in float32 (per-block z down
    to -15.6), its lambertian ground passes."""
    cover = load_scene(SCENES / "final_scene.yaml")
    assert precision_of(cover) == np.float32
    metal = cover.replace(materials={**cover.materials, "ground": Metal(albedo=(0.5, 0.5, 0.5), fuzz=0.02)})
    assert precision_of(metal) == np.float64


def test_the_policy_leaves_scenes_of_ordinary_spheres_as_they_were():
    assert precision_of(load_scene(SCENES / "three_spheres.yaml")) == np.float32
    assert not load_scene(SCENES / "three_spheres.yaml").compile().shapes.kinds[0].anchored  # ground radius 100


def shifted(scene, offset):
    """``scene`` with every sphere and the camera moved by ``offset``."""
    spheres = [dataclasses.replace(s, center=tuple(np.add(s.center, offset))) for s in scene.spheres]
    camera = dataclasses.replace(scene.camera, look_from=tuple(np.add(scene.camera.look_from, offset)),
                                 look_at=tuple(np.add(scene.camera.look_at, offset)))
    return scene.replace(spheres=spheres, camera=camera)


def test_bvh_sized_scenes_run_anchored_in_float32_too():
    """The cover scene (486 spheres: the BVH) runs anchored in float32, its
    ground and three balls tested by brute force outside the tree (see the
    module docstring of wavefront.bvh for why the BVH's hits stay brute
    force's); cornell_spheres with 60 more balls alike.  Moving spheres (the
    bouncing cover), and the cover scene moved far from the origin (its small
    spheres then fail the float32 rule), keep float64."""
    from wavefront.bvh import BVH

    cover = load_scene(SCENES / "final_scene.yaml")
    assert precision_of(cover) == np.float32
    shapes = cover.compile().shapes
    assert isinstance(shapes, BVH) and shapes.primitives.kinds[0].anchored
    radius = shapes.primitives.kinds[0].radius
    np.testing.assert_array_equal(np.sort(radius[shapes.outsized]), [1.0, 1.0, 1.0, 1000.0])
    rng = np.random.default_rng(1)
    scene = cornell_spheres()
    extra = [Sphere(tuple(rng.uniform(-0.8, 0.8, 3)), 0.02, "white") for _ in range(60)]
    assert precision_of(scene.replace(spheres=[*scene.spheres, *extra])) == np.float32
    assert precision_of(load_scene(SCENES / "bouncing_spheres.yaml")) == np.float64
    for offset in ([300.0, 0.0, 0.0], [1e3, 0.0, 700.0], [1e4, 0.0, 7e3]):
        assert precision_of(shifted(cover, offset)) == np.float64


def wall_departures(rng, n):
    """Float32 points on the left wall of cornell_spheres (radius 1000) within
    the room, and directions leaving it into the room, half of them within
    3 degrees of grazing (where a self-hit past T_MIN shows first)."""
    center, radius = np.array([-1001.0, 0.0, 0.0]), 1000.0
    y, z = rng.uniform(-1, 1, n), rng.uniform(-1, 1, n)
    point = np.stack((center[0] + np.sqrt(radius**2 - y * y - z * z), y, z))
    normal = normalize(point - center[:, None])
    tangent = normalize(np.cross(normal, rng.normal(size=(3, n)), axis=0))
    cos = np.where(rng.random(n) < 0.5, rng.uniform(0, 0.05, n), rng.uniform(0, 1, n))
    direction = normalize(cos * normal + np.sqrt(1 - cos * cos) * tangent)
    return point.astype(np.float32), direction.astype(np.float32), center, radius


def test_rays_leaving_a_huge_wall_never_find_it_again_in_float32():
    """A ray leaving the outside of a sphere cannot meet it again.  Haines'
    roots in float32 err by ~u |o - c| (6e-5 at the walls' 1000 units): some
    grazing departures find their own wall a little past T_MIN (the negative
    control); the anchored roots err by ~u |o - q| / cos and find none."""
    rng = np.random.default_rng(5)
    origin, direction, center, radius = wall_departures(rng, 40000)
    spheres = SphereSet(center[:, None], [radius], [0], np.float32)
    assert spheres.anchored
    t = spheres.t_pairs(np.zeros(origin.shape[1], dtype=np.int64), origin, direction)
    assert not (t < np.inf).any()
    c, r2 = center.astype(np.float32)[:, None], np.float32(radius * radius)
    haines = nearest_root(*sphere_roots(c, r2, origin, direction))
    self_hits = haines < np.inf
    assert self_hits.sum() >= 20 and haines[self_hits].max() < 1.0  # all of them within a unit of the origin



def ball_departures(rng, n):
    """A float32 cover-like set (anchored: a ground of radius 1000 under a
    grid of balls of radius 0.2, 2 units apart, their tops 5 units above it),
    and float32 rays leaving points on the balls within 1e-9..1e-6 of tangent
    (or exactly along it), half of them tilted inwards: each ray's two true
    roots are 0 and ~0.4 cos, below T_MIN.  Returns the set, the rays and
    the index of the ball each ray leaves."""
    grid = np.arange(-4, 5) * 2.0
    x, z = np.meshgrid(grid, grid)
    center = np.vstack(([0.0, -1000.0, 0.0], np.stack((x.ravel(), np.full(x.size, 4.8), z.ravel()), axis=1))).T
    radius = np.concatenate(([1000.0], np.full(x.size, 0.2)))
    spheres = SphereSet(center, radius, np.zeros(radius.size, np.int32), np.float32)
    ball = rng.integers(1, radius.size, n)
    c = spheres.center.astype(np.float64)[:, ball]
    origin = (c + 0.2 * normalize(rng.normal(size=(3, n)))).astype(np.float32)
    normal = normalize(origin.astype(np.float64) - c)
    along = normalize(np.cross(normal, rng.normal(size=(3, n)), axis=0))
    tilt = rng.choice([0.0, 1e-9, 1e-8, 1e-7, 1e-6], n) * rng.choice([-1.0, 1.0], n)
    return spheres, origin, normalize(along + tilt * normal).astype(np.float32), ball


def test_rays_leaving_a_small_ball_near_tangent_never_find_it_again_in_float32():
    """The anchored small root is the power of the origin over the big root:
    within ~1e-9 of tangent the big root is ~1e-10 and the power rounding
    noise, so the quotient landed anywhere (self-hits up to hundreds of
    units from a ball of radius 0.2: the negative control, that arithmetic
    uncapped).  Capped at |big| it stays below T_MIN: no ray finds its own
    ball again, in brute force or the BVH, nearest hit or any hit (within
    0.5, where nothing else can be met)."""
    rng = np.random.default_rng(12)
    spheres, origin, direction, ball = ball_departures(rng, 20000)
    assert spheres.anchored
    prims = Primitives([spheres], np.float32)
    for intersector in (prims, BVH(prims, 2000.0)):
        hits = intersector.intersect(origin, direction)
        assert not (hits.primitive_idx == ball).any()
        for t_max in (np.float32(0.5), np.full(ball.size, 0.5, dtype=np.float32)):  # compared per root, and keyed
            assert not intersector.occluded(origin, direction, t_max).any()
    # the negative control: the same quotient, uncapped
    fields = [np.take(f, ball, axis=-1) for f in (spheres.center, spheres.radius_squared, spheres.near_point,
                                                  spheres.far_point)]
    h, sqrt_disc = sphere_roots(fields[0], fields[1], origin, direction)
    big = h + np.copysign(sqrt_disc, h)
    power = ((origin - fields[2]) * (origin - fields[3])).sum(axis=0)
    with np.errstate(divide="ignore", invalid="ignore"):
        small = power / big
    self_hits = (small > T_MIN) & (small < np.inf)
    assert self_hits.sum() >= 100 and small[self_hits].max() > 10.0

def test_anchored_float32_hits_lie_on_the_float64_spheres():
    """From points in the room (and far out, beyond FLOAT32_EXTENT), the
    anchored float32 test hits where float64 does, and its hit points lie on
    the spheres to a few float32 epsilons of the distance from the origin (along a grazing
    ray the hit may slide further: the root is ill-conditioned there in any
    precision, but the point stays on the surface)."""
    scene = cornell_spheres()
    s32 = scene.compile().shapes.kinds[0]
    s64 = with_settings(scene, precision="float64").compile().shapes.kinds[0]
    rng = np.random.default_rng(9)
    n = 20000
    origin = rng.uniform(-0.95, 0.95, (3, n))
    origin[:, :2000] *= rng.uniform(1, 900, 2000)  # some far out, beyond FLOAT32_EXTENT
    direction = normalize(rng.normal(size=(3, n))).astype(np.float32)
    origin = origin.astype(np.float32)
    m = len(s32)
    t32 = s32.t_block(0, m, origin, direction).astype(np.float64)
    # the same rays in float64, their directions renormalised (the roots assume |d| = 1)
    o64, d64 = origin.astype(np.float64), normalize(direction.astype(np.float64))
    t64 = s64.t_block(0, m, o64, d64)
    # hit or miss differs only where float32 rounding decides: a handful of pairs
    assert (np.isfinite(t32) != np.isfinite(t64)).sum() <= n * m * 1e-4
    both = np.isfinite(t32) & np.isfinite(t64)
    sphere, ray = np.nonzero(both)
    point = o64[:, ray] + t32[sphere, ray] * d64[:, ray]
    off = np.abs(np.linalg.norm(point - s64.center[:, sphere], axis=0) - np.sqrt(s64.radius_squared[sphere]))
    scale = np.abs(o64[:, ray]).max(axis=0) + t32[sphere, ray]
    assert (off / scale).max() <= 4e-6 and np.median(off / scale) <= 1e-7  # ~64 and ~2 float32 epsilons
    assert (np.abs(origin).max(axis=0) > FLOAT32_EXTENT).any() and ray.size > n


@pytest.mark.parametrize("far_out", [False, True])
def test_anchored_keys_give_the_anchored_roots_bit_for_bit(far_out):
    """Brute force keys an anchored set's roots (key_block): each ray's
    nearest root and the spheres at it are t_block's, bit for bit, for rays
    in the room (T_MIN) and with some far out (a t_min of their own)."""
    spheres = cornell_spheres().compile().shapes.kinds[0]
    assert spheres.anchored
    rng = np.random.default_rng(11)
    n, m = 6000, len(spheres)
    origin = rng.uniform(-0.95, 0.95, (3, n))
    if far_out:
        origin[:, :600] *= rng.uniform(1, 900, 600)  # beyond FLOAT32_EXTENT
    origin = origin.astype(np.float32)
    direction = normalize(rng.normal(size=(3, n))).astype(np.float32)
    keys = spheres.key_block(0, m, origin, direction)
    t = spheres.t_block(0, m, origin, direction)
    nearest = np.fmin.reduce(t, axis=0)
    hit = nearest < np.inf
    got = key_root(np.minimum.reduce(keys, axis=0))
    np.testing.assert_array_equal(got[hit].view(np.uint32), nearest[hit].view(np.uint32))
    assert np.all(got[~hit] == np.inf) and hit.mean() > 0.5
    np.testing.assert_array_equal((keys == keys.min(axis=0))[:, hit], (t == nearest)[:, hit])
    assert (np.abs(origin).max(axis=0) > FLOAT32_EXTENT).any() == far_out


def test_only_spheres_reaching_past_float32_extent_are_anchored():
    """In an anchored set the spheres within FLOAT32_EXTENT keep Haines' keyed
    roots (as in a set without huge spheres), on rays in the set's type, in
    blocks of both kinds, pair by pair and in subsets alike."""
    spheres = cornell_spheres().compile().shapes.kinds[0]
    reach = np.linalg.norm(spheres.center.astype(np.float64), axis=0) + spheres.radius.astype(np.float64)
    np.testing.assert_array_equal(spheres.anchor, reach > FLOAT32_EXTENT)
    assert spheres.anchor.any() and not spheres.anchor.all()
    rng = np.random.default_rng(13)
    n, m = 3000, len(spheres)
    origin = rng.uniform(-0.95, 0.95, (3, n)).astype(np.float32)
    direction = normalize(rng.normal(size=(3, n)))  # float64: taken in the set's type
    own = direction.astype(np.float32)
    t = spheres.t_block(0, m, origin, direction)
    small, huge = np.flatnonzero(~spheres.anchor), np.flatnonzero(spheres.anchor)
    plain = key_root(sphere_root_keys(spheres.center[:, small, None], spheres.radius_squared[small, None],
                                      origin[:, None, :], own[:, None, :]))
    np.testing.assert_array_equal(t[small], plain)
    fields = [np.take(getattr(spheres, f), huge, axis=-1)[..., None] for f in SphereSet.ANCHORED_FIELDS]
    np.testing.assert_array_equal(t[huge], first_root(*anchored_roots(*fields, origin[:, None, :], own[:, None, :])))
    assert np.isfinite(t[small]).any() and np.isfinite(t[huge]).any()
    pick = rng.integers(0, m, n)
    np.testing.assert_array_equal(spheres.t_pairs(pick, origin, direction), t[pick, np.arange(n)])
    part = spheres.subset(small)
    assert not part.anchored
    np.testing.assert_array_equal(part.t_block(0, small.size, origin, own), plain)


@pytest.mark.parametrize("far_out", [False, True])
@pytest.mark.parametrize("ground_row", [0, 1, 3])
def test_mixed_blocks_key_each_kind_in_its_rows(ground_row, far_out):
    """A block of anchored and plain spheres (the cover's outsized ones: a
    ground of radius 1000 and three balls at one height) keys each kind in
    its rows, the plain ones with the coordinates they share among
    themselves (y and z; the ground shares only z) as rows: the keys of each
    kind's full block, bit for bit, whether each kind's rows are a run
    (written in place) or not, in blocks and sub-blocks.  The ground's
    antipodes have coordinates +0.0, which its roots take as the rays' own
    (never writing into the rays), with rays within FLOAT32_EXTENT and some
    beyond it."""
    center = np.array([[-4.0, 0.0, 4.0], [1.0, 1.0, 1.0], [0.0, 0.0, 0.0]])
    center = np.insert(center, ground_row, [0.0, -1000.0, 0.0], axis=1)
    radius = np.insert(np.array([1.0, 1.0, 1.0]), ground_row, 1000.0)
    spheres = SphereSet(center, radius, np.zeros(4, np.int32), np.float32)
    assert np.flatnonzero(spheres.anchor).tolist() == [ground_row] and spheres.shared_axes == (2,)
    rng = np.random.default_rng(17)
    n = 5000
    origin = (rng.uniform(-6, 6, (3, n)) + [[0], [3], [0]]).astype(np.float32)
    origin[:, :40] = spheres.center[:, [ground_row - 1 if ground_row else 1]]  # rays from a centre: exact zeros
    if far_out:
        origin[:, 40:400] *= np.float32(300.0)
    direction = normalize(rng.normal(size=(3, n))).astype(np.float32)
    rays = origin.copy(), direction.copy()
    assert spheres._anchor_zeros(0, 4, np.array([ground_row])) == ((0, 1, 2), (0, 2))
    small, huge = np.flatnonzero(~spheres.anchor), np.flatnonzero(spheres.anchor)
    o, d = origin[:, None, :], direction[:, None, :]
    expected = np.empty((4, n), np.uint32)
    expected[small] = sphere_root_keys(spheres.center[:, small, None], spheres.radius_squared[small, None], o, d)
    fields = [np.take(getattr(spheres, f), huge, axis=-1)[..., None] for f in SphereSet.ANCHORED_FIELDS]
    a, b, t_min = anchored_roots(*fields, o, d)
    assert (np.ndim(t_min) > 0) == far_out
    expected[huge] = roots_key(first_root(a, b, t_min)) if far_out else roots_key(a, b)
    assert spheres._key_plan(0, 4)[0][1].shape == (1, 1)  # the balls' y: one row
    for _ in range(2):  # the plans are made once per block, then reused
        np.testing.assert_array_equal(spheres.key_block(0, 4, origin, direction), expected)
        np.testing.assert_array_equal(spheres.key_block(1, 4, origin, direction), expected[1:])
        np.testing.assert_array_equal(origin, rays[0])
        np.testing.assert_array_equal(direction, rays[1])
    hit = key_root(expected.min(axis=0)) < np.inf
    assert 0.3 < hit.mean() < 0.95 and (key_root(expected[small].min(axis=0)) < np.inf).mean() > 0.02


def test_first_root_is_nearest_root_on_haines_roots():
    """The anchored test's root choice is nearest_root's arithmetic on any pair of roots."""
    rng = np.random.default_rng(2)
    h, s = rng.uniform(-3, 3, 1000), np.abs(rng.normal(size=1000))
    s[::7] = np.nan
    np.testing.assert_array_equal(np.nan_to_num(first_root(h + s, h - s, T_MIN), nan=np.inf),
                                  np.nan_to_num(nearest_root(h, s), nan=np.inf))


@pytest.mark.parametrize("dtype", [np.float32, np.float64])
def test_root_keys_are_nearest_root_bit_for_bit(dtype):
    """Keyed roots give nearest_root's root wherever it is a hit (inf where it
    is none), and order as the roots, across T_MIN, zero, negatives and NaN."""
    rng = np.random.default_rng(3)
    t_min = dtype(T_MIN)
    around = np.concatenate([np.nextafter(t_min, dtype(np.inf)) * np.arange(-3, 4, dtype=dtype),
                             [t_min, np.nextafter(t_min, dtype(0)), np.nextafter(t_min, dtype(1)), 0.0, -0.0]])
    h = np.concatenate([rng.uniform(-3, 3, 2000), around, around, rng.uniform(-1e-2, 1e-2, 500)]).astype(dtype)
    s = np.abs(np.concatenate([rng.normal(size=2000), around * 0, around, rng.uniform(0, 1e-2, 500)])).astype(dtype)
    s[::7] = np.nan
    s[1::11] = np.inf  # a root at -inf and one at inf
    with np.errstate(invalid="ignore"):
        expected = nearest_root(h.copy(), s)
        keys = nearest_root_key(h, s)
    hit = expected < np.inf
    got = key_root(keys)
    assert got.dtype == dtype
    np.testing.assert_array_equal(got[hit].view(keys.dtype), expected[hit].view(keys.dtype))
    assert np.all(got[~hit] == np.inf)
    # the least key of any two is the nearer hit
    order = np.argsort(keys, kind="stable")
    assert np.all(np.diff(got[order][hit[order]]) >= 0)
    assert hit.sum() > 1000 and (~hit).sum() > 500


@pytest.mark.parametrize("dtype", [np.float32, np.float64])
def test_chunked_block_keys_are_the_whole_blocks(dtype, monkeypatch):
    """key_block's keys, fused (sphere_root_keys) and in chunks of rays
    (KEY_BLOCK_BYTES), are nearest_root_key's over the whole block, bit for bit."""
    rng = np.random.default_rng(5)
    m, n = 7, 5000
    spheres = SphereSet(rng.uniform(-3, 3, (3, m)), rng.uniform(0.2, 2, m), np.zeros(m, np.int32), dtype)
    origin = rng.uniform(-4, 4, (3, n)).astype(dtype)
    direction = normalize(rng.normal(size=(3, n))).astype(dtype)
    whole = nearest_root_key(*sphere_roots(*spheres.block(0, m), origin[:, None, :], direction[:, None, :]))
    monkeypatch.setattr(sphere_module, "KEY_MIN_RAYS", 64)
    for budget in (1 << 30, 999 * m * np.dtype(dtype).itemsize, 64 * m * np.dtype(dtype).itemsize):
        monkeypatch.setattr(sphere_module, "KEY_BLOCK_BYTES", budget)
        keys = spheres.key_block(0, m, origin, direction)
        assert keys.dtype == whole.dtype and keys.shape == (m, n)
        np.testing.assert_array_equal(keys, whole)
        np.testing.assert_array_equal(spheres.key_block(2, 5, origin, direction), whole[2:5])
    assert 0.3 < (key_root(whole.min(axis=0)) < np.inf).mean() < 0.9  # rays that hit and rays that miss


@pytest.mark.parametrize("dtype", [np.float32, np.float64])
@pytest.mark.parametrize("shared", [(0,), (1,), (2,), (0, 2), (1, 2), (0, 1, 2)])
def test_shared_coordinates_key_as_full_blocks(dtype, shared):
    """A coordinate every sphere shares is keyed as one row (key_block), with
    the keys of the full block bit for bit; a subset finds its own."""
    rng = np.random.default_rng(7)
    m, n = 6, 3000
    center = rng.uniform(-3, 3, (3, m))
    center[list(shared)] = center[list(shared), :1]
    spheres = SphereSet(center, rng.uniform(0.3, 2, m), np.zeros(m, np.int32), dtype)
    assert spheres.shared_axes == tuple(a for a in shared if not (a == 1 and 0 in shared))
    origin = rng.uniform(-4, 4, (3, n)).astype(dtype)
    origin[:, :50] = spheres.center[:, :1]  # rays from a centre: differences of exactly 0
    direction = normalize(rng.normal(size=(3, n))).astype(dtype)
    whole = nearest_root_key(*sphere_roots(*spheres.block(0, m), origin[:, None, :], direction[:, None, :]))
    np.testing.assert_array_equal(spheres.key_block(0, m, origin, direction), whole)
    np.testing.assert_array_equal(spheres.key_block(1, 4, origin, direction), whole[1:4])
    assert 0.1 < (key_root(whole.min(axis=0)) < np.inf).mean() < 0.95  # rays that hit and rays that miss
    part = spheres.subset(np.array([0, 5]))
    part.center = part.center + np.array([[0.0, 1.0]])  # apart on every axis: nothing shared any more (a new array: sets are read-only)
    assert part.subset(np.arange(2)).shared_axes == ()


@pytest.mark.parametrize("types", [(np.float32, np.float64, np.float32), (np.float32, np.float32, np.float64),
                                   (np.float64, np.float32, np.float64)])
def test_any_hit_of_mixed_types_is_the_nearest_roots(types):
    """Rays and limits of other types than the set's: the any-hit test
    (keyed where the limit has the roots' type) answers as t_block does."""
    origin_type, direction_type, limit_type = types
    rng = np.random.default_rng(9)
    m, n = 5, 4000
    center = rng.uniform(-3, 3, (3, m))
    center[2] = 0.5  # a shared coordinate too
    spheres = SphereSet(center, rng.uniform(0.3, 2, m), np.zeros(m, np.int32), np.float32)
    origin = rng.uniform(-4, 4, (3, n)).astype(origin_type)
    direction = normalize(rng.normal(size=(3, n))).astype(direction_type)
    t_max = rng.uniform(0, 8, n).astype(limit_type)
    expected = (spheres.t_block(0, m, origin, direction) < t_max).any(axis=0)
    np.testing.assert_array_equal(spheres.any_hit_block(0, m, origin, direction, t_max), expected)
    assert 0.1 < expected.mean() < 0.9


@pytest.mark.parametrize("dtype", [np.float32, np.float64])
@pytest.mark.parametrize("shared", [(0,), (1,), (2,), (1, 2)])
def test_shared_coordinates_with_no_rays(dtype, shared):
    """A call with no rays on a set sharing a coordinate answers with empty
    arrays, as other sets do: a row and a block of 0 rays have the same size,
    and telling them apart by size had broadcast a (1, 0) row into a (2, 0)
    block (a fog render whose shadow rays were all blocked asked its boundaries
    about 0 rays and crashed; session 11's review)."""
    center = np.array([[0.0, 1.0, 2.0], [0.5, -0.5, 0.25], [-1.0, -2.0, -3.0]])
    center[list(shared)] = center[list(shared), :1]
    spheres = SphereSet(center, np.full(3, 0.5), np.zeros(3, np.int32), dtype)
    assert spheres.shared_axes
    origin = np.zeros((3, 0), dtype)
    assert spheres.key_block(0, 3, origin, origin).shape == (3, 0)
    assert spheres.t_block(0, 3, origin, origin).shape == (3, 0)
    assert spheres.any_hit_block(0, 3, origin, origin, np.zeros(0, dtype)).shape == (0,)
    hits = Primitives([spheres]).intersect(origin, origin)
    assert hits.t.shape == hits.primitive_idx.shape == (0,)
    assert Primitives([spheres]).occluded(origin, origin, np.zeros(0, dtype)).shape == (0,)


def test_shared_coordinates_compare_bits():
    """0.0 and -0.0 are one value but not one row: c - o differs in the sign of a zero."""
    spheres = SphereSet(np.array([[0.0, -0.0], [1, 2], [1, 1]]), np.ones(2), np.zeros(2, np.int32))
    assert spheres.shared_axes == (2,)


def test_root_keys_negative_control():
    """A key made with T_MIN's own bits, not the next float's, accepts a root at T_MIN: the test above sees it."""
    t_min = np.float32(T_MIN)
    h, s = np.array([t_min], dtype=np.float32), np.zeros(1, dtype=np.float32)
    assert nearest_root(h.copy(), s)[0] == np.inf
    wrong = (h - s).view(np.uint32) - t_min.view(np.uint32)  # T_MIN itself keyed as the first hit
    assert wrong[0] < np.float32(np.inf).view(np.uint32) - t_min.view(np.uint32)
    assert key_root(nearest_root_key(h, s))[0] == np.inf


def _wrong_power(center, radius_squared, near_point, far_point, origin, direction, zeros=((), ())):
    """A deliberately wrong anchored test: the power of the origin taken
    from the near point and the centre (not two antipodes; the antipodes'
    zero coordinates are not the centre's, so ``zeros`` is not passed on)."""
    return anchored_roots(center, radius_squared, near_point, center, origin, direction)


def assert_float32_is_float64_and_a_wrong_power_is_rejected(monkeypatch, scene, samples_per_pixel):
    """``scene``'s anchored float32 image against its float64 image (per-block
    z-test over 12 seeds each), and the same test rejects :func:`_wrong_power`."""
    f64 = estimate(with_settings(scene, precision="float64"), 12, 300, samples_per_pixel=samples_per_pixel)
    f32 = estimate(scene, 12, 500, samples_per_pixel=samples_per_pixel)
    bad, z = rejected(f32, f64)
    assert not bad, f"float32 differs from float64 (max |z| {z:.1f})"
    monkeypatch.setattr(sphere_module, "anchored_roots", _wrong_power)
    wrong = estimate(scene, 12, 700, samples_per_pixel=samples_per_pixel)
    assert rejected(wrong, f64)[0], "the z-test did not reject a wrong power of the origin"


def test_float32_image_is_the_float64_image_and_a_wrong_power_is_rejected(monkeypatch):
    assert_float32_is_float64_and_a_wrong_power_is_rejected(
        monkeypatch, cornell_spheres().with_overrides(width=24, height=24), 32)


def test_float32_huge_spheres_image_does_not_depend_on_workers_or_chunk_size():
    """Paths far out (per-ray t_min) and in the room (scalar T_MIN) share
    batches differently with every chunk size: the image must not notice."""
    from wavefront import render_scene

    from .test_render import assert_same_on_two_workers

    scene = cornell_spheres().with_overrides(width=24, height=16, samples_per_pixel=8)
    image = render_scene(scene, workers=1, chunk_size=4096).image
    np.testing.assert_array_equal(render_scene(scene, workers=1, chunk_size=300).image, image)
    assert_same_on_two_workers(scene, image, chunk_size=700)


def test_cover_scene_float32_image_is_the_float64_image_and_a_wrong_power_is_rejected(monkeypatch):
    """The cover scene through the BVH, anchored float32 against float64: the
    per-block z-test of the Cornell room above, on the ground's horizon, the
    carpet and the glass balls; the same wrong power of the origin must fail it."""
    assert_float32_is_float64_and_a_wrong_power_is_rejected(
        monkeypatch, load_scene(SCENES / "final_scene.yaml").with_overrides(width=48, height=28), 16)


def test_anchored_sets_take_rays_of_another_type():
    """Whitted's shadow rays in a forced float32 scene come with float64
    directions: an anchored set tests them as rays of its own type (it moved a
    sign bit between arrays of two types by viewing their bits, and crashed;
    session 11's review), and an empty block of spheres keys nothing."""
    rng = np.random.default_rng(11)
    center = np.array([[0.0, 0.3, -0.4], [-1000.0, 0.25, 0.3], [0.0, 0.1, -0.2]])
    spheres = SphereSet(center, np.array([1000.0, 0.2, 0.25]), np.zeros(3, np.int32), np.float32)
    assert spheres.anchored
    origin = rng.uniform(-1, 1, (3, 500)).astype(np.float32)
    origin[1] = np.abs(origin[1]) + 0.5
    direction = normalize(rng.normal(size=(3, 500)))  # float64
    limit = np.full(500, 5.0)
    own = direction.astype(np.float32)
    np.testing.assert_array_equal(spheres.any_hit_block(0, 3, origin, direction, limit),
                                  spheres.any_hit_block(0, 3, origin, own, limit.astype(np.float32)))
    np.testing.assert_array_equal(spheres.key_block(0, 3, origin, direction), spheres.key_block(0, 3, origin, own))
    assert 0.1 < spheres.any_hit_block(0, 3, origin, own, limit.astype(np.float32)).mean() < 0.9
    assert spheres.key_block(1, 1, origin, own).shape == (0, 500)


def test_whitted_in_forced_float32_with_huge_spheres_renders():
    scene = load_scene(SCENES / "whitted.yaml").with_overrides(width=24, samples_per_pixel=1)
    scene = scene.replace(render=dataclasses.replace(scene.render, precision="float32"))
    from wavefront import render_scene

    image = render_scene(scene, workers=1).image
    assert np.isfinite(image).all() and image.mean() > 0.01

"""Participating media: homogeneous fog inside invisible boundaries (wavefront.media, path.py's media stages).

Exact scenes first: a medium of density 0 changes nothing; an absorbing slab
in front of a uniform background lets ``exp(-density * length)`` through; a
white medium under a uniform background is a furnace (every sample exactly
the background); a camera inside absorbing fog sees ``exp(-density *
distance to the boundary)``, checked against an independent estimate.  Then
light sampling at medium vertices: images with next-event estimation equal
the pure path tracer's within noise (z-test), and shadow rays that ignore
transmittance are rejected by the same test.  Determinism, the mask
arithmetic, point-in-boundary tests, and bad input through the CLI.
"""

import dataclasses
import functools
import math

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

import wavefront.path
import wavefront.sampling
import wavefront.units
from wavefront import (Box, Camera, Dielectric, Emissive, Lambertian, Medium, Metal, Quad, RenderSettings, Scene,
                       SceneError, Solid, Sphere, load_scene, render, render_scene)
from wavefront.film import scene_fingerprint
from wavefront.media import contains, cross, current_medium, winding_number
from wavefront.shapes import Mesh
from wavefront.transform import Transform

from .test_cli import run
from .test_furnace import SCENES
from .test_light_sampling import book, estimate, rejected, with_settings
from .test_render import assert_same_on_two_workers

trimesh = pytest.importorskip("trimesh")


def background_scene(media, *, camera=None, background=1.0, size=16, spp=16, **render_settings):
    """Only media under a uniform background (no shapes at all)."""
    settings = dict(samples_per_pixel=spp, max_depth=10_000, russian_roulette=False) | render_settings
    return Scene(media=media, materials={}, background=Solid((background,) * 3), width=size, height=size,
                 camera=camera or Camera(look_from=(0, 0, 4), look_at=(0, 0, 0), vfov=40),
                 render=RenderSettings(**settings))


def z_score(image, expected):
    """How many standard errors the image's mean lies from ``expected``, for
    samples in [0, 1] (a mean of Bernoulli samples has variance at most p(1-p)/n)."""
    n = image.shape[0] * image.shape[1] * SPP_OF[id(image)]
    p = float(np.clip(expected, 1e-9, 1 - 1e-9))
    return (float(image[..., 0].mean(dtype=np.float64)) - expected) / math.sqrt(p * (1 - p) / n)


SPP_OF = {}


def rendered(scene, **kwargs):
    image = render(scene, workers=1, **kwargs)
    SPP_OF[id(image)] = scene.render.samples_per_pixel
    return image


# -- the mask and the boundaries --------------------------------------------------

@settings(max_examples=200, deadline=None)
@given(st.lists(st.integers(0, 2**64 - 1), min_size=1, max_size=20))
def test_the_current_medium_is_the_highest_set_bit(masks):
    got = current_medium(np.array(masks, dtype=np.uint64))
    np.testing.assert_array_equal(got, [m.bit_length() - 1 for m in masks])


def test_crossing_sets_and_clears_only_its_own_bit():
    mask = np.array([0b1010, 0b1010, 0, 0b1], dtype=np.uint64)
    out = cross(mask, np.array([0, 3, 63, 0]), np.array([True, False, True, False]))
    np.testing.assert_array_equal(out, np.array([0b1011, 0b0010, 1 << 63, 0], dtype=np.uint64))


def box_mesh_file(tmp_path, name="box.ply", lo=(-1, -1, -1), hi=(1, 1, 1), open_=False, inward=False):
    mesh = trimesh.creation.box(bounds=[lo, hi])
    faces = mesh.faces[1:] if open_ else mesh.faces
    faces = faces[:, ::-1] if inward else faces
    path = tmp_path / name
    trimesh.Trimesh(mesh.vertices, faces, process=False).export(path)
    return path


def test_point_in_boundary_for_each_kind(tmp_path):
    sphere = Medium(Sphere((1, 2, 3), 2, 0), 0.1)
    assert contains(sphere, (1, 2, 4.9)) and not contains(sphere, (1, 2, 5.1))
    # a box turned 45 degrees about y: its corners reach sqrt(2) along the axes, its faces' middles
    # lie at 1 along the diagonals, so the turned box holds (1.35, 0, 0) and not (0.9, 0, 0.9)
    turned = Medium(Box((-1, -1, -1), (1, 1, 1), 0, [{"rotate": {"axis": [0, 1, 0], "angle": 45}},
                                                     {"translate": [0, 5, 0]}]), 0.1)
    assert contains(turned, (1.35, 5, 0)) and contains(turned, (0, 5.9, -1.35))
    assert not contains(turned, (0.9, 5, 0.9)) and not contains(turned, (0, 0, 0))
    for inward in (False, True):  # an inward-wound mesh is turned outwards
        mesh = Mesh.read(box_mesh_file(tmp_path, f"b{inward}.ply", inward=inward), 0,
                         transform=Transform.translate((5, 0, 0)))
        medium = Medium(mesh, 0.1)
        assert contains(medium, (5.5, 0.5, -0.5)) and not contains(medium, (3.9, 0, 0))
        assert winding_number(wavefront.media.mesh_triangles(medium.boundary), np.array([5.0, 0, 0])) == \
            pytest.approx(1.0)


@settings(max_examples=100, deadline=None)
@given(point=st.lists(st.floats(-3, 3), min_size=3, max_size=3),
       axis=st.lists(st.floats(-1, 1), min_size=3, max_size=3).filter(lambda a: sum(x * x for x in a) > 0.01),
       angle=st.floats(-180, 180))
def test_a_box_and_the_same_box_as_a_mesh_agree_on_what_is_inside(point, axis, angle):
    """Two independent point-in-boundary tests: the box's (in its object
    space) and the winding number of its twelve triangles."""
    steps = [{"rotate": {"axis": axis, "angle": angle}}, {"translate": [0.5, -0.2, 0.1]}]
    box = Box((-1, -0.5, -2), (1.5, 1, 1), 0, steps)
    triangles = trimesh.creation.box(bounds=[(-1, -0.5, -2), (1.5, 1, 1)])
    mesh = Mesh(np.asarray(triangles.vertices), np.asarray(triangles.faces), 0, transform=box.transform)
    p = np.array(point)
    w = winding_number(wavefront.media.mesh_triangles(mesh), p)
    # a point on a face (hypothesis found (0, 0, -1.9) with no rotation) has
    # a winding number of 0 or 1 by rounding, not 0.5: judged in object space
    q = np.linalg.solve(box.transform.array, np.append(p, 1.0))[:3]
    on_face = np.any(np.isclose(q, box.min, rtol=0, atol=1e-9) | np.isclose(q, box.max, rtol=0, atol=1e-9))
    if abs(w - 0.5) > 1e-6 and not on_face:  # not on the surface
        assert contains(Medium(box, 1.0), p) == (w > 0.5)
        assert contains(Medium(mesh, 1.0), p) == (w > 0.5)
        assert min(abs(w), abs(w - 1)) < 1e-9  # 0 or 1: closed and outward


def test_an_open_mesh_is_refused(tmp_path):
    mesh = Mesh.read(box_mesh_file(tmp_path, open_=True), 0)
    with pytest.raises(SceneError, match="boundary.mesh.file.*not closed"):
        Medium(mesh, 0.1)


# -- exact scenes -------------------------------------------------------------------

def lit_scene():
    """A floor, a ball and a quad lamp: surfaces, emission and light sampling."""
    materials = {"floor": Lambertian((0.6, 0.6, 0.6)), "ball": Lambertian((0.7, 0.3, 0.2)),
                 "lamp": Emissive((6, 6, 6))}
    return Scene(spheres=[Sphere((0, 0.5, 0), 0.5, "ball")],
                 quads=[Quad((-2, 0, 2), (4, 0, 0), (0, 0, -4), "floor"),
                        Quad((-0.75, 2, -0.75), (1.5, 0, 0), (0, 0, 1.5), "lamp")],
                 materials=materials, camera=Camera(look_from=(0, 1.5, 3.5), look_at=(0, 0.5, 0), vfov=50),
                 background=Solid((0.1, 0.1, 0.12)), width=16, height=12,
                 render=RenderSettings(samples_per_pixel=16, max_depth=8))


def test_a_medium_of_density_zero_is_invisible():
    """Boundaries are crossed, but nothing scatters and every transmittance is
    exactly 1; each hit is still found from the path's vertex, so the image is
    the one without the media, bit for bit (with the camera in one of them)."""
    plain = lit_scene()
    foggy = plain.replace(media=[Medium(Sphere((0.3, 0.6, 0.2), 0.9, 0), 0.0, (0.5, 0.5, 0.5)),
                                 Medium(Box((-3, -1, -3), (3, 3, 4), 0), 0.0)])  # holds the camera
    a, b = render(plain, workers=1), render(foggy, workers=1)
    table = foggy.compile().media
    assert table.medium_of_bit.tolist() == [1, 0]  # the box encloses more: bit 0
    assert table.camera_mask == 1
    np.testing.assert_array_equal(a, b)
    # and a fog of some density is not invisible (the test can fail)
    thick = plain.replace(media=[dataclasses.replace(foggy.media[0], density=2.0)])
    assert np.abs(render(thick, workers=1) - a).max() > 0.1


SLAB_DENSITY, SLAB_LENGTH = 0.5, 2.0


def slab_scene(spp=64):
    """An absorbing slab (albedo 0) 2 units thick filling a 2-degree view of a
    uniform white background: every ray crosses it almost perpendicularly
    (within 1.5e-4 of the straight length)."""
    slab = Medium(Box((-100, -100, -1 - SLAB_LENGTH), (100, 100, -1), 0), SLAB_DENSITY, (0, 0, 0))
    return background_scene([slab], camera=Camera(look_from=(0, 0, 0), look_at=(0, 0, -1), vfov=2), size=32,
                            spp=spp)


def test_transmittance_through_an_absorbing_slab_is_beer_lambert():
    image = rendered(slab_scene())
    expected = math.exp(-SLAB_DENSITY * SLAB_LENGTH)
    assert abs(z_score(image, expected)) < 4.5
    # negative control: 5 % more optical depth is far outside the noise
    assert abs(z_score(image, math.exp(-1.05 * SLAB_DENSITY * SLAB_LENGTH))) > 6


def test_a_slab_with_light_sampling_on_and_roulette_is_still_beer_lambert():
    scene = slab_scene()
    scene = with_settings(scene, light_sampling=True, russian_roulette={"depth": 1})
    assert abs(z_score(rendered(scene), math.exp(-SLAB_DENSITY * SLAB_LENGTH))) < 4.5


@pytest.mark.parametrize("look_from", [(0, 0, 4), (0.2, -0.1, 0.3)], ids=["outside", "inside"])
def test_white_fog_under_a_uniform_background_is_a_furnace(look_from):
    """Albedo 1 loses nothing: with roulette off every sample is exactly the
    background, whether the camera is outside the fog or inside it."""
    fog = [Medium(Sphere((0, 0, 0), 1.0, 0), 2.0), Medium(Box((-0.5, -0.5, -0.5), (0.8, 0.5, 0.5), 0), 3.0)]
    scene = background_scene(fog, camera=Camera(look_from=look_from, look_at=(0, 0, -1), vfov=60))
    image = render(scene, workers=1)
    np.testing.assert_array_equal(image, 1.0)
    # negative control: an albedo of 0.9 does lose light
    grey = scene.replace(media=[dataclasses.replace(m, albedo=(0.9, 0.9, 0.9)) for m in fog])
    dim = render(grey, workers=1)
    assert dim.mean() < 0.99 and dim.min() < 0.8


def test_white_fog_furnace_with_roulette_is_unbiased():
    fog = [Medium(Sphere((0, 0, 0), 1.0, 0), 4.0)]
    scene = background_scene(fog, spp=32, russian_roulette={"depth": 1}, max_depth=10_000)
    image = render(scene, workers=1)
    # roulette reweights by 1 / 0.95: samples are 0 or 0.95^-k; the mean stays 1
    n = image.size // 3 * 32
    assert abs(image.mean(dtype=np.float64) - 1.0) < 5 * image.std() / math.sqrt(n) + 1e-3


def test_a_camera_inside_absorbing_fog_sees_exp_minus_density_radius():
    """Centred in a sphere of fog, every camera ray travels exactly the radius."""
    density, radius = 0.4, 2.5
    fog = Medium(Sphere((1, 2, 3), radius, 0), density, (0, 0, 0))
    scene = background_scene([fog], camera=Camera(look_from=(1, 2, 3), look_at=(1, 2, 2), vfov=90), spp=64)
    image = rendered(scene)
    assert abs(z_score(image, math.exp(-density * radius))) < 4.5
    # negative control: a camera not known to be in the fog would see the background
    assert abs(z_score(image, 1.0 - 1e-6)) > 50


def test_a_camera_inside_a_mesh_of_fog_matches_an_independent_estimate(tmp_path):
    """Off-centre in a (rotated) mesh box of absorbing fog: the image's mean is
    the mean of exp(-density * exit distance) over camera rays, which numpy
    computes here with the slab method on the box (an independent estimate)."""
    density = 0.7
    lo, hi = np.array([-1.0, -0.5, -2.0]), np.array([1.5, 1.0, 1.0])
    turn = Transform.rotate((1, 1, 0), 30)
    mesh = Mesh.read(box_mesh_file(tmp_path, lo=lo, hi=hi), 0, transform=turn)
    camera = Camera(look_from=tuple(turn.points(np.array([[0.3], [0.2], [0.4]]))[:, 0]),
                    look_at=(0.5, -2, -3), vfov=70)
    scene = background_scene([Medium(mesh, density, (0, 0, 0))], camera=camera, spp=64, size=20)
    image = rendered(scene)

    rng = np.random.default_rng(7)
    frame = camera.frame(scene.width, scene.height)
    n = 400_000
    origin, direction = frame.generate_rays(rng.integers(0, scene.width * scene.height, n), rng.random((4, n)))
    inverse = np.linalg.inv(turn.array)  # rays into the box's object space
    o = inverse[:3, :3] @ origin + inverse[:3, 3:]
    d = inverse[:3, :3] @ direction  # a rotation: still unit length
    with np.errstate(divide="ignore"):
        exit_t = np.maximum((lo[:, None] - o) / d, (hi[:, None] - o) / d).min(axis=0)
    expected = np.exp(-density * exit_t).mean()
    assert abs(z_score(image, expected)) < 4.5
    assert abs(z_score(image, expected * 1.06)) > 5  # the test can tell 6 %


@pytest.mark.parametrize("inner_last", [True, False])
def test_overlapping_media_the_innermost_wins(inner_last):
    """Absorbing fog of density 0.2 in a ball of radius 2 and of density 1 in
    a ball of radius 0.5 at its centre, seen through both centres: in either
    order the inner ball is a denser core, and the ray leaves it back into the
    outer fog (RTOW's final scene lists its blue ball before the mist)."""
    outer, inner = Medium(Sphere((0, 0, 0), 2.0, 0), 0.2, (0, 0, 0)), Medium(Sphere((0, 0, 0), 0.5, 0), 1.0, (0, 0, 0))
    scene = background_scene([outer, inner] if inner_last else [inner, outer], spp=64,
                             camera=Camera(look_from=(0, 0, 10), look_at=(0, 0, 0), vfov=0.5))
    image = rendered(scene)
    assert abs(z_score(image, math.exp(-(0.2 * 3.0 + 1.0 * 1.0)))) < 4.5
    assert abs(z_score(image, math.exp(-0.2 * 4.0))) > 10  # the outer fog alone
    assert abs(z_score(image, math.exp(-(0.2 * 4.0 + 1.0 * 1.0)))) > 10  # densities added


def test_partly_overlapping_media_the_smaller_wins_the_overlap():
    """Two absorbing slabs along the view, the thinner (smaller volume)
    overlapping the thicker's far half: that half has the thinner's density."""
    thick = Medium(Box((-100, -100, -5), (100, 100, -1), 0), 0.1, (0, 0, 0))  # z in [-5, -1], volume 160 000
    thin = Medium(Box((-50, -50, -8), (50, 50, -3), 0), 0.4, (0, 0, 0))  # z in [-8, -3], volume 50 000
    for media in ([thick, thin], [thin, thick]):
        scene = background_scene(media, camera=Camera(look_from=(0, 0, 0), look_at=(0, 0, -1), vfov=2), spp=64)
        image = rendered(scene)
        assert abs(z_score(image, math.exp(-(0.1 * 2 + 0.4 * 5)))) < 4.5
        assert abs(z_score(image, math.exp(-(0.1 * 4 + 0.4 * 3)))) > 10  # had the thicker won


def test_fog_resting_on_a_floor_is_not_left_through_the_floor():
    """A box of fog whose bottom face lies in the floor's plane (Cornell
    smoke): rays entering through the top reach the floor still inside the
    fog, whatever the rounding of distances measured from their restart on
    the top face (before COINCIDENT, about half of them left through the floor)."""
    turn = [{"rotate": {"axis": [0, 1, 0], "angle": 15}}, {"translate": [265, 0, 295]}]
    scene = Scene(quads=[Quad((0, 0, 555), (555, 0, 0), (0, 0, -555), "floor")], materials={"floor": Lambertian()},
                  media=[Medium(Box((0, 0, 0), (165, 330, 165), 0, turn), 1e-9)])
    compiled = scene.compile()
    rng = np.random.default_rng(3)
    n = 20_000
    target = np.array([[347.0], [0.0], [377.0]]) + rng.uniform(-40, 40, (3, n)) * [[1], [0], [1]]
    origin = target + rng.uniform(-60, 60, (3, n)) * [[1], [0], [1]] + [[0], [600], [0]]
    direction = (target - origin) / np.linalg.norm(target - origin, axis=0)
    sampler = wavefront.path.render_sampler(compiled, np.uint64(1))
    live = wavefront.path.camera_paths(compiled, scene.camera.frame(4, 4), sampler,
                                       wavefront.units.Job([wavefront.units.Unit(0, 0, 0, 4, 4, 0, 1)], 4, 1), 0, 1)
    live = live.take(np.zeros(n, dtype=np.int64))
    live.origin, live.direction, live.media_mask = origin, direction, np.zeros(n, dtype=np.uint64)
    hits = compiled.shapes.intersect(origin, direction)
    surface, hits, in_medium, _ = wavefront.path.travel_media(compiled, sampler, live, hits)
    assert len(in_medium) == 0 and len(surface) == n and (hits.primitive_idx == 0).all()
    inside = wavefront.media.contains(scene.media[0], (347, 1, 377))
    assert inside and (surface.media_mask == 1).all()


def test_fog_inside_a_glass_ball_is_entered_through_the_glass():
    """RTOW's final scene fills a glass ball with fog using the same sphere for
    both: the visible ball becomes the boundary, and refraction enters it.
    Through the centre of a ball of index 1 (no bending, no reflection head-on)
    the ray crosses the diameter: exp(-2 density radius)."""
    density, radius = 0.3, 1.0
    scene = background_scene([Medium(Sphere((0, 0, 0), radius, 0), density, (0, 0, 0))],
                             camera=Camera(look_from=(0, 0, 10), look_at=(0, 0, 0), vfov=2), spp=64)
    glass = scene.replace(spheres=[Sphere((0, 0, 0), radius, "glass")], materials={"glass": Dielectric(1.0)})
    compiled = glass.compile()
    assert len(compiled.shapes) == 1 and compiled.media.interface_of.tolist() == [0]
    image = rendered(glass)
    assert abs(z_score(image, math.exp(-2 * density * radius))) < 4.5


@pytest.mark.parametrize("precision", ["float32", "float64"])
def test_a_visible_shape_bounds_its_medium_at_either_precision(precision):
    """The match of a boundary with a visible shape is made at the render's
    precision: in a forced float32 render of a ball whose numbers float32
    cannot hold exactly, the visible ball (held in float32) is still the
    fog's boundary, and so is a rotated box's every face."""
    center, radius = (0.1, 0.2, 0.3), 0.7
    turn = Transform.rotate((1, 1, 0), 33).then(Transform.translate((0.1, 0, 0)))
    lo, hi = (-0.3, -0.2, -0.1), (0.3, 0.2, 0.1)
    scene = background_scene([Medium(Sphere(center, radius, 0), 0.3, (0, 0, 0)),
                              Medium(Box(lo, hi, 0, transform=turn), 0.3, (0, 0, 0))], precision=precision)
    glass = scene.replace(spheres=[Sphere(center, radius, "glass")], quads=Box(lo, hi, "glass", transform=turn).quads(),
                          materials={"glass": Dielectric(1.0)})
    compiled = glass.compile()
    assert compiled.dtype == np.dtype(precision)
    assert (compiled.media.interface_of >= 0).all() and compiled.media.boundaries is None


def fog_in_glass_scene(radius=0.5):
    """The lit floor with its ball turned to glass full of dense fog (RTOW's final scene's blue ball)."""
    scene = lit_scene()
    return scene.replace(materials=scene.materials | {"ball": Dielectric(1.5)},
                         media=[Medium(Sphere((0, 0.5, 0), radius, 0), 2.0, (0.2, 0.4, 0.9))])


@settings(max_examples=60, deadline=None)
@given(st.integers(0, 2**32 - 1))
def test_shadow_rays_dropped_in_sealed_fog_are_all_blocked(seed):
    """``sealed_in`` drops only shadow rays the any-hit query finds blocked
    (origins inside, on and just outside the glass; targets inside and out),
    and it does drop most of those from deep inside."""
    compiled = fog_in_glass_scene().compile()
    assert compiled.media.sealed is not None
    rng = np.random.default_rng(seed)
    n = 2000
    center = np.array([[0.0], [0.5], [0.0]])
    origin = center + random_in_ball(rng, n, 0.52)
    target = center + random_in_ball(rng, n, 3.0)
    offset = target - origin
    distance = np.linalg.norm(offset, axis=0)
    direction = (offset / distance).astype(compiled.dtype)
    t_max = (distance * (1.0 - wavefront.path.SHADOW_EPSILON)).astype(compiled.dtype)
    origin = origin.astype(compiled.dtype)
    medium = np.zeros(n, dtype=np.int64)
    dropped = wavefront.path.sealed_in(compiled.media.sealed, medium, origin, direction, t_max)
    blocked = compiled.shapes.occluded(origin, direction, t_max)
    assert blocked[dropped].all()
    deep_and_leaving = (np.linalg.norm(origin - center, axis=0) < 0.45) & (np.linalg.norm(target - center, axis=0) > 0.55)
    assert dropped[deep_and_leaving].all()
    # a path in no medium (-1) is never culled
    assert not wavefront.path.sealed_in(compiled.media.sealed, medium - 1, origin, direction, t_max).any()


def random_in_ball(rng, n, radius):
    v = rng.normal(size=(3, n))
    return v / np.linalg.norm(v, axis=0) * radius * rng.random(n) ** (1 / 3)


def test_dropping_sealed_shadow_rays_changes_no_pixel(monkeypatch):
    scene = fog_in_glass_scene()
    culled = render_scene(scene, workers=1)
    monkeypatch.setattr(wavefront.path, "sealed_in", lambda sealed, medium, *rest: np.zeros(medium.shape, dtype=bool))
    traced = render_scene(scene, workers=1)
    assert culled.stats.shadow_rays < traced.stats.shadow_rays
    np.testing.assert_array_equal(culled.image, traced.image)


def balls_in_mist_scene():
    """125 balls (a BVH) and a glass ball of dense fog, under a lamp, all in
    a mist the camera is inside: capped hit queries in both media."""
    grid = np.linspace(-1.2, 1.2, 5)
    balls = [Sphere((float(x), float(y) + 1.5, float(z)), 0.2, "white") for x in grid for y in grid for z in grid]
    scene = fog_in_glass_scene()
    return scene.replace(spheres=scene.spheres + balls, materials=scene.materials | {"white": Lambertian((0.7, 0.7, 0.7))},
                         media=scene.media + [Medium(Sphere((0, 1, 0), 8.0, 0), 0.4, (0.9, 0.9, 0.9))],
                         render=dataclasses.replace(scene.render, samples_per_pixel=8))


@pytest.mark.parametrize("name", ["balls_in_mist", "lamp_in_fog", "cornell_smoke"])
def test_capped_hit_queries_in_media_change_no_pixel(name, monkeypatch):
    """intersect_in_media stops a medium path's hit query just past its first
    free flight: the image must be the one of full queries, bit for bit."""
    scene = {"balls_in_mist": balls_in_mist_scene, "lamp_in_fog": lambda: lamp_in_fog_scene(),
             "cornell_smoke": lambda: load_scene(SCENES / "cornell_smoke.yaml").with_overrides(
                 width=12, height=12, samples_per_pixel=4)}[name]()
    capped = render(scene, workers=1)
    monkeypatch.setattr(wavefront.path, "intersect_in_media", lambda cs, sampler, live: (
        cs.shapes.intersect(live.origin, live.direction, time=live.time), None))
    np.testing.assert_array_equal(render(scene, workers=1), capped)


# -- light sampling at medium vertices --------------------------------------------------

def foggy_lit_scene():
    scene = lit_scene()
    return scene.replace(media=[Medium(Sphere((0.2, 0.7, 0.3), 0.7, 0), 1.5, (0.9, 0.8, 0.7)),
                                Medium(Box((-2, 0, -2), (2, 0.4, 2), 0), 0.3, (1, 1, 1))],
                         render=dataclasses.replace(scene.render, max_depth=6))


def lamp_in_fog_scene():
    """The camera and a sphere lamp inside one big ball of fog, a mirror ball
    and a glass ball in it too: sphere-light samples from medium vertices,
    delta vertices in fog, the camera's medium."""
    materials = {"lamp": Emissive((8, 7, 6)), "floor": Lambertian((0.5, 0.5, 0.5)), "mirror": Metal((0.9, 0.9, 0.9)),
                 "glass": Dielectric(1.5)}
    return Scene(spheres=[Sphere((0.6, 1.2, -0.5), 0.45, "lamp"), Sphere((-0.7, 0.5, 0), 0.5, "mirror"),
                          Sphere((0.2, 0.35, 0.6), 0.35, "glass")],
                 quads=[Quad((-3, 0, 3), (6, 0, 0), (0, 0, -6), "floor")], materials=materials,
                 media=[Medium(Sphere((0, 0, 0), 4.0, 0), 0.35, (0.8, 0.85, 0.9))],
                 camera=Camera(look_from=(0, 1.2, 3), look_at=(0, 0.6, 0), vfov=60), background=Solid((0, 0, 0)),
                 width=16, height=12, render=RenderSettings(samples_per_pixel=16, max_depth=6))


SPLITS, BOOK_SPP, NEE_SPP = 12, 128, 32
FOGGY = {"fog_on_a_lit_floor": foggy_lit_scene, "lamp_in_fog": lamp_in_fog_scene}


@functools.lru_cache(maxsize=None)
def book_estimate(name):
    return estimate(book(FOGGY[name]()), SPLITS, seed=100, samples_per_pixel=BOOK_SPP)


@pytest.fixture(scope="module")
def book_foggy():
    return book_estimate("fog_on_a_lit_floor")


@pytest.mark.parametrize("name", sorted(FOGGY))
def test_light_sampling_in_fog_keeps_the_expectation(name):
    assert FOGGY[name]().compile().media.camera_mask == (1 if name == "lamp_in_fog" else 0)
    bad, worst = rejected(estimate(FOGGY[name](), SPLITS, seed=500, samples_per_pixel=NEE_SPP), book_estimate(name))
    assert not bad, f"largest |z| = {worst:.2f}"


@pytest.mark.parametrize("name", sorted(FOGGY))
def test_negative_control_shadow_rays_without_transmittance_are_rejected(name, monkeypatch):
    monkeypatch.setattr(wavefront.path, "transmittance", lambda density, length: np.ones_like(length))
    bad, worst = rejected(estimate(FOGGY[name](), SPLITS, seed=500, samples_per_pixel=NEE_SPP), book_estimate(name))
    assert bad, f"largest |z| = {worst:.2f}"


def test_negative_control_medium_vertices_without_mis_are_rejected(book_foggy, monkeypatch):
    """Full weight for both strategies counts light scattered by the fog twice."""
    monkeypatch.setattr(wavefront.path, "mis_weight", lambda pdf_a, pdf_b: np.where(pdf_a > 0, 1.0, 0.0))
    bad, worst = rejected(estimate(foggy_lit_scene(), SPLITS, seed=500, samples_per_pixel=NEE_SPP), book_foggy)
    assert bad, f"largest |z| = {worst:.2f}"


# -- determinism, scenes, fingerprints ---------------------------------------------------

@pytest.fixture(scope="module")
def smoke():
    return load_scene(SCENES / "cornell_smoke.yaml").with_overrides(width=20, height=20, samples_per_pixel=3)


@pytest.fixture(scope="module")
def smoke_image(smoke):
    return render(smoke, workers=1)


@pytest.mark.parametrize("chunk_size", [97, 1000])
def test_media_image_does_not_depend_on_chunk_size(smoke, smoke_image, chunk_size):
    np.testing.assert_array_equal(render(smoke, workers=1, chunk_size=chunk_size), smoke_image)


def test_media_image_does_not_depend_on_worker_count(smoke, smoke_image):
    assert_same_on_two_workers(smoke, smoke_image, chunk_size=300)


def test_cornell_smoke_is_book_2s_scene(smoke, smoke_image):
    assert [m.density for m in smoke.media] == [0.01, 0.01]
    assert [m.albedo for m in smoke.media] == [(0.0, 0.0, 0.0), (1.0, 1.0, 1.0)]
    compiled = smoke.compile()
    assert len(compiled.media.boundaries) == 12 and compiled.media.camera_mask == 0
    assert len(compiled.shapes) == 6 and (compiled.media.interface_of < 0).all()  # the walls and the lamp
    assert np.isfinite(smoke_image).all() and smoke_image.mean() > 0.05


def test_culling_by_the_boundaries_box_changes_no_sample(smoke):
    """Rays that miss the box around every boundary skip the boundaries'
    intersector; with an infinite box every ray asks it, and every sample is
    the same, bit for bit."""
    scene = smoke.replace(media=smoke.media + [Medium(Sphere((400, 400, 300), 60, 0), 0.02, (0.5, 0.7, 0.9))])
    job = wavefront.units.Job([wavefront.units.Unit(0, 0, 0, 20, 20, 0, 3)], 20, 3)
    key = wavefront.sampling.scene_key(1)
    compiled = scene.compile()
    culled = wavefront.path.trace_paths(compiled, job, key, 4096)
    compiled.media.bounds = (np.full((3, 1), -np.inf), np.full((3, 1), np.inf))
    np.testing.assert_array_equal(wavefront.path.trace_paths(compiled, job, key, 4096), culled)


def test_the_checkpoint_fingerprint_covers_media(smoke):
    thicker = smoke.replace(media=[dataclasses.replace(smoke.media[0], density=0.02), smoke.media[1]])
    assert scene_fingerprint(thicker) != scene_fingerprint(smoke)
    recoloured = smoke.replace(media=[smoke.media[0], dataclasses.replace(smoke.media[1], albedo=(1, 1, 0.9))])
    assert scene_fingerprint(recoloured) != scene_fingerprint(smoke)


# -- bad input ------------------------------------------------------------------------

MEDIUM = "  - {boundary: {sphere: {center: [0, 0, -2], radius: 1}}, density: 0.5}\n"
HEAD = "materials: {m: {type: lambertian}}\nspheres: [{center: [0, -101, 0], radius: 100, material: m}]\n"


@pytest.mark.parametrize("media,needle", [
    ("  - {boundary: {sphere: {center: [0, 0, -2], radius: 1}}, density: -0.1}\n", "media[0].density: must be >= 0"),
    ("  - {boundary: {sphere: {center: [0, 0, -2], radius: 1}}, density: .nan}\n", "media[0].density: must be finite"),
    ("  - {boundary: {sphere: {center: [0, 0, -2], radius: 1}}, density: 1, albedo: [1, 2, 1]}\n",
     "media[0].albedo[1]: must be <= 1.0"),
    ("  - {boundary: {sphere: {center: [0, 0, -2], radius: 1}}, density: 1, colour: [1, 1, 1]}\n",
     "media[0].colour: unknown key"),
    ("  - {boundary: {sphere: {center: [0, 0, -2], radius: 1, material: m}}, density: 1}\n",
     "media[0].boundary.sphere.material: unknown key"),
    ("  - {boundary: {cone: {center: [0, 0, -2]}}, density: 1}\n", "media[0].boundary.cone: unknown key"),
    ("  - {boundary: {sphere: {center: [0, 0, -2], radius: 1}, box: {min: [0, 0, 0], max: [1, 1, 1]}},"
     " density: 1}\n", "media[0].boundary: expected exactly one of"),
    ("  - {boundary: {sphere: {center: [0, 0, -2], radius: -1}}, density: 1}\n",
     "media[0].boundary.sphere.radius: must be > 0"),
    ("  - {boundary: {box: {min: [0, 0, 0], max: [1, 1, .nan]}}, density: 1}\n",
     "media[0].boundary.box.max[2]: must be finite"),
    ("  - {density: 1}\n", "media[0].boundary: required key is missing"),
    ("  - {boundary: {mesh: {file: nowhere.ply}}, density: 1}\n", "media[0].boundary.mesh.file"),
    ("  - {boundary: {mesh: {file: open.ply}}, density: 1}\n", "media[0].boundary.mesh.file"),
    (MEDIUM + "render: {integrator: whitted}\n", "media need the path integrator"),
    ("  - {boundary: {sphere: {center: [0, 0, -2], radius: 1}}, density: 1, albedo: {type: image, file: e.png}}\n",
     "media[0].albedo: an image texture needs a surface's uv"),
    ("  - {boundary: {sphere: {center: [0, 0, -2], radius: 1}}, density: 1,"
     " albedo: {type: checker, even: [1, 1, 1], odd: [0, 3, 0]}}\n", "media[0].albedo.odd[1]: must be <= 1.0"),
    ("  - {boundary: {sphere: {center: [0, 0, -2], radius: 1}}, density: 1, albedo: {type: noise, scale: 0}}\n",
     "media[0].albedo.scale: must be > 0"),
])
def test_bad_media_exit_2_with_one_line_and_no_output(tmp_path, media, needle):
    box_mesh_file(tmp_path, "open.ply", open_=True)
    text = HEAD + "media:\n" + media
    scene = tmp_path / "bad.yaml"
    scene.write_text(text)
    out = tmp_path / "out.png"
    out.write_bytes(b"precious")
    r = run("render", scene, "-o", out, "--width", 8, "--height", 8, "--spp", 1)
    assert r.returncode == 2, r.stderr
    assert "Traceback" not in r.stderr and len(r.stderr.strip().splitlines()) == 1
    assert "bad.yaml" in r.stderr and needle in r.stderr, r.stderr
    if "mesh" in needle:
        assert ("nowhere.ply" in r.stderr and "cannot read" in r.stderr) or ("open.ply" in r.stderr
                                                                             and "not closed" in r.stderr)
    assert out.read_bytes() == b"precious"


def test_media_in_python_are_checked_like_the_file():
    with pytest.raises(SceneError, match="density"):
        Medium(Sphere((0, 0, 0), 1, 0), -1)
    with pytest.raises(SceneError, match="boundary"):
        Medium("a sphere", 1)
    with pytest.raises(SceneError, match="at most 64"):
        background_scene([Medium(Sphere((0, 0, 0), 1, 0), 0.1)] * 65)
    with pytest.raises(SceneError, match="media need the path integrator"):
        background_scene([Medium(Sphere((0, 0, 0), 1, 0), 0.1)], integrator="whitted", max_depth=3,
                         russian_roulette=None)


def test_a_textured_albedo_is_read_where_the_path_scatters():
    """A solid checker is evaluated at the scattering point: fog lying wholly
    in one of its cells renders bit for bit as fog of that cell's colour, and
    swapping the checker's colours gives the other colour's image."""
    from wavefront import Checker

    def fog(albedo):
        return [Medium(Box((1.2, 1.2, 1.2), (2.8, 2.8, 2.8), 0), 1.5, albedo)]

    camera = Camera(look_from=(2, 2, 7), look_at=(2, 2, 2), vfov=30)
    scene = background_scene(fog((0.3, 0.5, 0.7)), camera=camera, spp=8)
    plain = render(scene, workers=1)
    other = render(scene.replace(media=fog((0.9, 0.2, 0.4))), workers=1)
    # the cell [0, 10)^3 has index sum 0: even
    checker = Checker(scale=10.0, even=(0.3, 0.5, 0.7), odd=(0.9, 0.2, 0.4))
    np.testing.assert_array_equal(render(scene.replace(media=fog(checker)), workers=1), plain)
    swapped = Checker(scale=10.0, even=(0.9, 0.2, 0.4), odd=(0.3, 0.5, 0.7))
    np.testing.assert_array_equal(render(scene.replace(media=fog(swapped)), workers=1), other)
    assert np.abs(plain - other).max() > 0.05  # the two colours do give different images


def test_a_moving_sphere_never_bounds_a_medium():
    """A boundary identical to a sphere's start is not that sphere's surface
    when the sphere moves: the fog stays put."""
    scene = lit_scene()
    sphere = Sphere((0.3, 0.6, 0.2), 0.5, "ball")
    moving = dataclasses.replace(sphere, center1=(0.3, 1.6, 0.2))
    media = [Medium(Sphere((0.3, 0.6, 0.2), 0.5, 0), 1.0)]
    still = scene.replace(spheres=[*scene.spheres, sphere], media=media).compile().media
    assert (still.interface_of >= 0).any() and still.boundaries is None
    table = scene.replace(spheres=[*scene.spheres, moving], media=media).compile().media
    assert (table.interface_of < 0).all() and table.boundaries is not None


def test_the_compile_estimate_counts_medium_boundaries(tmp_path):
    """A mesh boundary is compiled into its own triangle set and BVH: a budget
    that would hold the visible scene alone must still refuse it, before
    compiling (a 1.3M-face boundary once peaked at 2.1 GiB under --memory 2G)."""
    from wavefront.memory import MemoryBudgetError, current_rss
    from wavefront.render import BOUNDARY_COMPILE_BYTES_PER_PRIMITIVE, compile_bytes, compile_within

    ball = trimesh.creation.icosphere(subdivisions=4)  # 5,120 faces
    ball.export(tmp_path / "ball.ply")
    boundary = Mesh.read(str(tmp_path / "ball.ply"), 0)
    scene = lit_scene().replace(media=[Medium(boundary, 1.0), Medium(Box((-3, -1, -3), (3, 3, 4), 0), 0.1),
                                       Medium(Sphere((0, 0.5, 0), 0.7, 0), 0.2)])
    need, what = compile_bytes(scene)
    visible = compile_bytes(lit_scene())[0]
    assert need - visible == BOUNDARY_COMPILE_BYTES_PER_PRIMITIVE * (5120 + 6 + 1)
    assert "5,127 medium-boundary primitives" in what
    with pytest.raises(MemoryBudgetError, match="medium-boundary"):
        compile_within(scene, current_rss() + visible + (need - visible) // 2)

"""Scene objects built in Python obey the scene file's rules (issue #10, items 10 and 11).

Each refusal is a SceneError naming the object (``<Sphere>``, ``<Scene>``) and
the field (``radius``, ``spheres[1].material``); the same values in a file are
refused with the file's name and YAML path by the same code.
"""

import math
import unicodedata
import warnings

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from wavefront import (Camera, Dielectric, Emissive, Lambertian, Metal, Phong, PointLight, RenderSettings, Scene,
                       SceneError, Sky, Solid, Sphere, render)
from wavefront.scenefile import scene_from_dict


def scene(**changes):
    base = dict(spheres=[Sphere((0, 0, -1), 0.5, "ball"), Sphere((0, -100.5, -1), 100, "ball")],
                materials={"ball": Lambertian((0.5, 0.5, 0.5))}, width=8, height=6,
                render=RenderSettings(samples_per_pixel=2))
    base.update(changes)
    return Scene(**base)


def refused(make, source, path, problem):
    with pytest.raises(SceneError) as e:
        make()
    prefix = f"{source}: {path}: " if path else f"{source}: "
    assert str(e.value).startswith(prefix), str(e.value)
    assert problem in str(e.value), str(e.value)
    return e.value


OBJECT_CASES = [
    (lambda: Sphere((0, 0, 0), -1.0, "m"), "<Sphere>", "radius", "> 0"),
    (lambda: Sphere((0, 0, 0), 0, "m"), "<Sphere>", "radius", "> 0"),
    (lambda: Sphere((0, 0, 0), math.nan, "m"), "<Sphere>", "radius", "finite"),
    (lambda: Sphere((0, math.inf, 0), 1, "m"), "<Sphere>", "center[1]", "finite"),
    (lambda: Sphere((0, 0), 1, "m"), "<Sphere>", "center", "3 numbers"),
    (lambda: Sphere((0, "x", 0), 1, "m"), "<Sphere>", "center[1]", "expected a number"),
    (lambda: Sphere((0, 0, 0), True, "m"), "<Sphere>", "radius", "expected a number"),
    (lambda: Sphere((0, 0, 0), "1", "m"), "<Sphere>", "radius", "expected a number"),
    (lambda: Sphere((0, 0, 0), 1, None), "<Sphere>", "material", "expected a string"),
    (lambda: Lambertian((1, -1, 1)), "<Lambertian>", "albedo[1]", ">= 0"),
    (lambda: Lambertian((1, 1)), "<Lambertian>", "albedo", "3 numbers"),
    (lambda: Metal(fuzz=-0.1), "<Metal>", "fuzz", ">= 0"),
    (lambda: Dielectric(0), "<Dielectric>", "refraction_index", ">= 1e-06"),
    (lambda: Dielectric(math.inf), "<Dielectric>", "refraction_index", "finite"),
    (lambda: Emissive((1, 1, math.nan)), "<Emissive>", "color[2]", "finite"),
    (lambda: Phong(reflectivity=(0, 1.5, 0)), "<Phong>", "reflectivity[1]", "<= 1"),
    (lambda: Phong(shininess=-1), "<Phong>", "shininess", ">= 0"),
    (lambda: Sky(top=(1, 1, -1)), "<Sky>", "top[2]", ">= 0"),
    (lambda: Solid("red"), "<Solid>", "color", "3 numbers"),
    (lambda: PointLight((0, 0)), "<PointLight>", "position", "3 numbers"),
    (lambda: PointLight((0, 0, 0), (1, -1, 1)), "<PointLight>", "color[1]", ">= 0"),
    (lambda: Camera(look_from=(1, 2, 3), look_at=(1, 2, 3)), "<Camera>", "look_at", "must differ"),
    (lambda: Camera(vup=(0, 0, 2)), "<Camera>", "vup", "parallel"),
    (lambda: Camera(vup=(0, 0, 0)), "<Camera>", "vup", "zero"),
    (lambda: Camera(vfov=180), "<Camera>", "vfov", "< 180"),
    (lambda: Camera(focus_dist=0), "<Camera>", "focus_dist", "> 0"),
    (lambda: Camera(look_from=(0, 0)), "<Camera>", "look_from", "3 numbers"),
    (lambda: RenderSettings(samples_per_pixel=0), "<RenderSettings>", "samples_per_pixel", ">= 1"),
    (lambda: RenderSettings(samples_per_pixel=1 << 25), "<RenderSettings>", "samples_per_pixel", "<= 16777216"),
    (lambda: RenderSettings(max_depth=10_001), "<RenderSettings>", "max_depth", "<= 10000"),
    (lambda: RenderSettings(max_depth=0), "<RenderSettings>", "max_depth", ">= 1"),
    (lambda: RenderSettings(seed=-1), "<RenderSettings>", "seed", ">= 0"),
    (lambda: RenderSettings(seed=2**63), "<RenderSettings>", "seed", "<="),
    (lambda: RenderSettings(samples_per_pixel=2.5), "<RenderSettings>", "samples_per_pixel", "integer"),
    (lambda: RenderSettings(integrator="bidir"), "<RenderSettings>", "integrator", "unknown value"),
    (lambda: scene(width=0), "<Scene>", "width", ">= 1"),
    (lambda: scene(height=-3), "<Scene>", "height", ">= 1"),
    (lambda: scene(width=1 << 15, height=1 << 14), "<Scene>", "", "pixels"),
    (lambda: scene(spheres=[Sphere((0, 0, -1), 0.5, "ball"), Sphere((0, 0, -1), 0.5, "nowhere")]),
     "<Scene>", "spheres[1].material", "unknown material 'nowhere'"),
    (lambda: scene(spheres=[Sphere((0, 0, -1), 0.5, "ball"), (0, 0, 1)]), "<Scene>", "spheres[1]", "a Sphere"),
    (lambda: scene(materials={"ball": (0.5, 0.5, 0.5)}), "<Scene>", "materials.ball", "a material"),
    (lambda: scene(camera={"look_from": (0, 0, 0)}), "<Scene>", "camera", "a Camera"),
    (lambda: scene(ambient=(1, 1)), "<Scene>", "ambient", "3 numbers"),
    (lambda: scene(lights=[(0, 0, 0)]), "<Scene>", "lights[0]", "a PointLight"),
]


@pytest.mark.parametrize("make,source,path,problem", OBJECT_CASES,
                         ids=[f"{c[1]}.{c[2]}:{c[3]}" for c in OBJECT_CASES])
def test_objects_refuse_what_files_refuse(make, source, path, problem):
    refused(make, source, path, problem)


def test_the_objects_normalise_their_values():
    s = Sphere(np.array([0, 1, 2]), np.float32(0.5), "m")
    assert s.center == (0.0, 1.0, 2.0) and type(s.center[0]) is float and type(s.radius) is float
    assert RenderSettings(samples_per_pixel=np.int64(4), seed=4.0).samples_per_pixel == 4
    assert Scene(spheres=(s,), materials={"m": Lambertian()}).spheres == [s]


def test_overrides_and_replace_are_validated():
    base = scene()
    refused(lambda: base.with_overrides(samples_per_pixel=0), "<Scene>", "render.samples_per_pixel", ">= 1")
    refused(lambda: base.with_overrides(max_depth=10_001), "<Scene>", "render.max_depth", "<= 10000")
    refused(lambda: base.with_overrides(width=0), "<Scene>", "width", ">= 1")
    refused(lambda: base.with_overrides(width=1 << 20, height=1 << 20), "<Scene>", "", "pixels")
    # one side given, the other kept in proportion: the message names the side given, not the derived one
    refused(lambda: base.with_overrides(height=200_000_000), "<Scene>", "height", "266666667x200000000")
    refused(lambda: base.with_overrides(width=30_000_000), "<Scene>", "width", "30000000x22500000")
    refused(lambda: base.with_overrides(height=1 << 20), "<Scene>", "height", "pixels")
    refused(lambda: base.with_overrides(width=10**400), "<Scene>", "width", "<= 268435456")  # not OverflowError
    refused(lambda: base.replace(spheres=[Sphere((0, 0, 0), 1, "x")]), "<Scene>", "spheres[0].material", "unknown")
    assert base.with_overrides(width=16).height == 12


def test_a_missing_material_is_a_scene_error_not_a_key_error():
    """It was a bare KeyError from compile()."""
    refused(lambda: render(scene(spheres=[Sphere((0, 0, -1), 0.5, "missing")])),
            "<Scene>", "spheres[0].material", "unknown material")


def test_material_names_are_unicode_nfc_in_objects_and_files():
    nfd, nfc = unicodedata.normalize("NFD", "é"), unicodedata.normalize("NFC", "é")
    assert nfd != nfc
    s = scene(spheres=[Sphere((0, 0, -1), 0.5, nfd)], materials={nfc: Lambertian()})
    assert s.spheres[0].material == nfc
    s = scene(spheres=[Sphere((0, 0, -1), 0.5, nfc)], materials={nfd: Lambertian()})
    assert list(s.materials) == [nfc]
    refused(lambda: scene(spheres=[], materials={nfd: Lambertian(), nfc: Metal()}),
            "<Scene>", f"materials.{nfc}", "another Unicode form")
    doc = {"materials": {nfd: {"type": "lambertian"}}, "spheres": [{"center": [0, 0, -1], "radius": 1, "material": nfc}]}
    assert scene_from_dict(doc).spheres[0].material == nfc


@pytest.mark.parametrize("radius", [5e-324, 1e-200, 1e-160, 1e200, 1.7e308])
def test_radii_float64_cannot_square_or_invert_are_refused_cleanly(radius):
    """5e-324 printed a bare NumPy overflow warning (1/r is inf, r*r is 0)."""
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        e = refused(lambda: Sphere((0, 0, -1), radius, "m"), "<Sphere>", "radius", "float64")
        assert "too small" in str(e) if radius < 1 else "too large" in str(e)


def test_tiny_radius_within_the_limit_renders_without_warnings():
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        image = render(scene(spheres=[Sphere((0, 0, -1), 1e-150, "ball"), Sphere((0, -100.5, -1), 100, "ball")]),
                       workers=1)
    assert np.isfinite(image).all()


def test_a_far_camera_one_unit_from_its_target_renders():
    """look_from [1e12, 0, 0], look_at [1e12, 0, -1] differ by one unit; float64
    positions there are 1.2e-4 apart, far finer than a pixel, so it renders."""
    cam = Camera(look_from=(1e12, 0, 0), look_at=(1e12, 0, -1))
    s = scene(camera=cam, spheres=[Sphere((1e12, 0, -3), 1, "ball")])
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        image = render(s, workers=1)
    assert np.isfinite(image).all() and image.max() > 0


def test_an_unresolvable_view_says_what_precision_is_missing():
    e = refused(lambda: scene(camera=Camera(look_from=(1e15, 0, 0), look_at=(1e15, 0, -1))),
                "<Scene>", "camera.look_at", "cannot be resolved in float64")
    assert "0.125 apart" in str(e) and "equal" not in str(e)


def test_metal_fuzz_above_one_warns_with_the_field():
    with pytest.warns(Warning, match=r"<Metal>: fuzz: 2.5 clamped to 1"):
        assert Metal(fuzz=2.5).fuzz == 1.0


def test_limits_live_with_the_objects_and_stay_importable_from_scenefile():
    from wavefront import scene as scene_module
    from wavefront import scenefile
    for name in ("MAX_PIXELS", "MAX_SAMPLES_PER_PIXEL", "MAX_DEPTH", "MAX_SEED"):
        assert getattr(scenefile, name) == getattr(scene_module, name)
    assert scenefile.SceneError is SceneError


EDGES = st.one_of(
    st.sampled_from([0, 1, -1, 0.5, -0.0, 1e-150, 9.9e-151, 1e150, 1.0000001e150, 5e-324, 1e308, 10**400, -10**400,
                     math.nan, math.inf, -math.inf, True, None, "1", np.float32(2.0), np.int64(3)]),
    st.floats(), st.integers(),
)
# mostly plain values, so that whole lists often take the bulk path and an edge is the one odd value
COORDINATE = st.one_of(*[st.floats(-100, 100)] * 3, st.integers(-100, 100), EDGES)
RADIUS = st.one_of(*[st.floats(1e-3, 100)] * 3, st.integers(1, 100), EDGES)
MATERIAL = st.one_of(*[st.just("m")] * 4, st.sampled_from(["e\u0301", 3, None, ["m"]]))


@given(st.lists(st.tuples(st.one_of(*[st.tuples(COORDINATE, COORDINATE, COORDINATE)] * 4,
                                    st.lists(COORDINATE, max_size=4)), RADIUS, MATERIAL),
                min_size=1, max_size=6))
@settings(max_examples=300, deadline=None)
def test_bulk_construction_is_construction_one_by_one(rows):
    """Sphere.many's NumPy check may only ever agree with the constructor."""
    centers, radii, materials = (list(column) for column in zip(*rows))
    try:
        expected = [Sphere(c, r, m) for c, r, m in rows]
    except SceneError:
        expected = None
    try:
        got = Sphere.many(centers, radii, materials)
    except SceneError as e:
        assert expected is None
        i = int(e.path[1:e.path.index("]")])
        with pytest.raises(SceneError) as single:
            Sphere(*rows[i])
        assert e.path == f"[{i}]{'.' if single.value.path[0] != '[' else ''}{single.value.path}"
        assert e.problem == single.value.problem
        for row in rows[:i]:
            Sphere(*row)
    else:
        assert got == expected
        assert [type(x) for s in got for x in (*s.center, s.radius)] == [float] * (4 * len(got))


# --- shapes beyond spheres (issue #11) obey the same rules as their YAML -------

from wavefront import Box, Mesh, Quad, Transform, Triangle  # noqa: E402

SHAPE_CASES = [
    (lambda: Quad((0, 0, 0), (1, 0, 0), (2, 0, 0), "m"), "<Quad>", "", "parallel"),
    (lambda: Quad((0, 0, math.nan), (1, 0, 0), (0, 1, 0), "m"), "<Quad>", "corner[2]", "finite"),
    (lambda: Quad((0, 0, 0), (1, 0, 0), (0, 1, 0), 3.5), "<Quad>", "material", "expected a string"),
    (lambda: Triangle(((0, 0, 0), (1, 1, 1), (2, 2, 2)), "m"), "<Triangle>", "vertices", "zero-area"),
    (lambda: Triangle(((0, 0, 0), (1, 0, 0)), "m"), "<Triangle>", "vertices", "3 points"),
    (lambda: Box((0, 0, 0), (1, 0, 1), "m"), "<Box>", "max", "must exceed min"),
    (lambda: Sphere((0, 0, 0), 1, "m", [{"scale": [1, 2, 1]}]), "<Sphere>", "transform[0].scale", "uniformly"),
    (lambda: Sphere((0, 0, 0), 1, "m", Transform.scale((1, 2, 1))), "<Sphere>", "transform", "uniformly"),
    (lambda: Quad((0, 0, 0), (1, 0, 0), (0, 1, 0), "m", [{"rotate": {"axis": [0, 0, 0], "angle": 3}}]),
     "<Quad>", "transform[0].rotate.axis", "zero"),
    (lambda: Quad((0, 0, 0), (1, 0, 0), (0, 1, 0), "m", [{"shear": 1}]), "<Quad>", "transform[0].shear",
     "unknown key"),
    (lambda: Quad((0, 0, 0), (1, 0, 0), (0, 1, 0), "m", [{"scale": 0}]), "<Quad>", "transform[0].scale", "zero"),
    (lambda: Mesh(np.zeros((3, 3)), np.array([[0, 1, 3]]), "m"), "<Mesh>", "faces", "out of range"),
    (lambda: Mesh(np.full((3, 3), np.nan), np.array([[0, 1, 2]]), "m"), "<Mesh>", "vertices", "NaN"),
    (lambda: Mesh(np.zeros((3, 2)), np.array([[0, 1, 2]]), "m"), "<Mesh>", "vertices", "shape"),
    (lambda: Mesh(np.eye(3), np.array([[0.5, 1, 2]]), "m"), "<Mesh>", "faces", "array of numbers"),
    (lambda: Mesh(np.eye(3), np.array([[0, 1, 2]]), "m", smooth="yes"), "<Mesh>", "smooth", "true or false"),
    (lambda: scene(spheres=[], quads=[Quad((0, 0, 0), (1, 0, 0), (0, 1, 0), "nope")]), "<Scene>",
     "quads[0].material", "unknown material"),
    (lambda: scene(spheres=[]), "<Scene>", "shapes", "no shapes"),
]


@pytest.mark.parametrize("make, source, path, problem", SHAPE_CASES)
def test_shape_objects_are_refused_with_the_field_named(make, source, path, problem):
    refused(make, source, path, problem)


def test_shape_objects_accept_what_files_accept():
    quad = Quad([0, 0, 0], [1, 0, 0], [0, 1, 0], "ball", [{"rotate": {"axis": [0, 1, 0], "angle": 15}},
                                                          {"translate": [1, 2, 3]}])
    assert quad.corner == (0.0, 0.0, 0.0) and isinstance(quad.transform, Transform)
    box = Box((0, 0, 0), (1, 2, 3), "ball")
    s = scene(quads=box.quads(), triangles=[Triangle(((0, 0, -2), (1, 0, -2), (0, 1, -2)), "ball")],
              meshes=[Mesh(np.eye(3) - 2, np.array([[0, 1, 2]]), "ball")])
    assert len(s.quads) == 6 and np.isfinite(render(s, workers=1)).all()


@pytest.mark.parametrize("dtype", [np.float32, np.float64])
def test_background_radiance_at_rows_is_radiance_of_those_rows(dtype):
    """The escaped rows' colour from the y row alone (Sky.radiance_at) is
    radiance of the gathered directions, bit for bit, on a (3, N) view too."""
    from wavefront.background import Sky, Solid
    rng = np.random.default_rng(3)
    wide = rng.normal(size=(3, 500)).astype(dtype)
    wide /= np.sqrt((wide * wide).sum(axis=0))
    direction = wide[:, :400]  # PathBatch.fill's views
    rows = rng.permutation(400)[:123]
    for background in (Sky(), Sky((0.2, 0.1, 0.05), (1.0, 0.3, 0.9)), Solid((0.3, 0.2, 0.1))):
        got = background.radiance_at(direction, rows)
        want = background.radiance(direction[:, rows])
        assert got.dtype == want.dtype == dtype and got.shape == want.shape == (3, 123)
        np.testing.assert_array_equal(np.ascontiguousarray(got).view(np.uint8), np.ascontiguousarray(want).view(np.uint8))

"""Scene files: the documented format loads; every malformed value is named by its YAML path."""

import copy

import pytest

from wavefront import Dielectric, Emissive, Lambertian, Metal, SceneError, Sky, Solid, load_scene
from wavefront.scenefile import read_yaml, scene_from_dict

from .test_furnace import SCENES

VALID = {
    "image": {"width": 40, "height": 30},
    "camera": {"look_from": [-2, 2, 1], "look_at": [0, 0, -1], "vup": [0, 1, 0], "vfov": 20,
               "defocus_angle": 10, "focus_dist": 3.4},
    "render": {"samples_per_pixel": 4, "max_depth": 10, "seed": 1},
    "background": {"type": "sky", "bottom": [1, 1, 1], "top": [0.5, 0.7, 1.0]},
    "materials": {"ground": {"type": "lambertian", "albedo": [0.8, 0.8, 0.0]},
                  "glass": {"type": "dielectric", "refraction_index": 1.5},
                  "gold": {"type": "metal", "albedo": [0.8, 0.6, 0.2], "fuzz": 0.0},
                  "lamp": {"type": "emissive", "color": [4, 4, 4]}},
    "spheres": [{"center": [0, -100.5, -1], "radius": 100, "material": "ground"},
                {"center": [-1, 0, -1], "radius": 0.5, "material": "glass"},
                {"center": [1, 0, -1], "radius": 0.5, "material": "gold"},
                {"center": [0, 0, -1], "radius": 0.5, "material": "lamp"}],
}


def test_issue_example_loads_exactly():
    scene = load_scene(SCENES / "three_spheres.yaml")
    assert (scene.width, scene.height) == (400, 225)
    assert scene.render.samples_per_pixel == 100 and scene.render.depth == 50 and scene.render.seed == 1
    assert scene.materials["bubble"] == Dielectric(0.6666666666666666)
    assert scene.materials["gold"] == Metal((0.8, 0.6, 0.2), 0.0)
    assert scene.materials["lamp"] == Emissive((4.0, 4.0, 4.0))
    assert scene.background == Sky((1, 1, 1), (0.5, 0.7, 1.0))
    assert len(scene.spheres) == 5 and scene.spheres[3].radius == 0.4
    assert scene.camera.defocus_angle == 10 and scene.camera.focus_dist == 3.4


def test_everything_but_a_shape_has_a_default():
    ball = {"materials": {"m": {"type": "lambertian"}}, "spheres": [{"center": [0, 0, -1], "radius": 1, "material": "m"}]}
    scene = scene_from_dict(ball)
    assert (scene.width, scene.height, scene.render.samples_per_pixel, scene.render.depth) == (400, 225, 100, 50)
    assert isinstance(scene.background, Sky)
    assert scene_from_dict({**ball, "background": {"type": "solid"}}).background == Solid((0, 0, 0))
    assert scene.materials["m"] == Lambertian()


def broken(path, value):
    """VALID with the value at a dotted/indexed path replaced (or deleted)."""
    doc = copy.deepcopy(VALID)
    keys = path.replace("[", ".").replace("]", "").split(".")
    node = doc
    for k in keys[:-1]:
        node = node[int(k)] if isinstance(node, list) else node[k]
    last = int(keys[-1]) if isinstance(node, list) else keys[-1]
    if value is DELETE:
        del node[last]
    else:
        node[last] = value
    return doc


DELETE = object()

CASES = [
    ("spheres[3].material", "nowhere", "spheres[3].material", "unknown material"),
    ("spheres[1].radius", 0, "spheres[1].radius", "> 0"),
    ("spheres[1].radius", -1, "spheres[1].radius", "> 0"),
    ("spheres[0].center", [0, 1], "spheres[0].center", "3 numbers"),
    ("spheres[0].center", [0, "x", 1], "spheres[0].center[1]", "number"),
    ("spheres[0].center", [0, float("nan"), 1], "spheres[0].center[1]", "finite"),
    ("spheres[2].radius", float("inf"), "spheres[2].radius", "finite"),
    ("spheres[2].material", DELETE, "spheres[2].material", "missing"),
    ("spheres[2].colour", "red", "spheres[2].colour", "unknown key"),
    ("image.width", 0, "image.width", ">= 1"),
    ("image.height", 2.5, "image.height", "integer"),
    ("image.depth", 3, "image.depth", "unknown key"),
    ("materials.gold.fuzz", -0.1, "materials.gold.fuzz", ">= 0"),
    ("materials.glass.refraction_index", 0, "materials.glass.refraction_index", "> 0"),
    ("materials.glass.type", "plastic", "materials.glass.type", "unknown value"),
    ("materials.ground.albedo", [1, 1, -1], "materials.ground.albedo[2]", ">= 0"),
    ("materials.ground.roughness", 1, "materials.ground.roughness", "unknown key"),
    ("camera.look_at", [-2, 2, 1], "camera.look_at", "differ"),
    ("camera.vup", [2, -2, -2], "camera.vup", "parallel"),
    ("camera.vfov", 180, "camera.vfov", "< 180"),
    ("render.samples_per_pixel", 0, "render.samples_per_pixel", ">= 1"),
    ("render.integrator", "bidir", "render.integrator", "unknown value"),
    ("render.seed", -1, "render.seed", ">= 0"),
    ("background.type", "hdri", "background.type", "unknown value"),
    ("background.color", [1, 1, 1], "background.color", "unknown key"),
    ("spheres", {"a": 1}, "spheres", "expected a list"),
]


@pytest.mark.parametrize("path,value,where,problem", CASES, ids=[c[2] for c in CASES])
def test_malformed_value_is_named_by_yaml_path(path, value, where, problem):
    with pytest.raises(SceneError) as e:
        scene_from_dict(broken(path, value), source="bad.yaml")
    message = str(e.value)
    assert message.startswith(f"bad.yaml: {where}: "), message
    assert problem in message


@pytest.mark.parametrize("doc", [{"image": {"width": 4}}, {"spheres": [], "quads": None}])
def test_a_scene_needs_at_least_one_shape(doc):
    with pytest.raises(SceneError, match=r"x.yaml: the scene has no shapes"):
        scene_from_dict(doc, source="x.yaml")


@pytest.mark.parametrize("text,problem", [
    (b"image: {width: 4\n", "invalid YAML"),
    (b"", "empty"),
    (b"spheres: []\nspheres: []\n", "duplicate key"),
    (b"\xff\xfe spheres", "UTF-8"),
    (b"a: &a [1,1,1,1,1,1,1,1,1]\nb: &b [*a,*a,*a,*a,*a,*a,*a,*a,*a]\nc: &c [*b,*b,*b,*b,*b,*b,*b,*b,*b]\n"
     b"d: &d [*c,*c,*c,*c,*c,*c,*c,*c,*c]\ne: &e [*d,*d,*d,*d,*d,*d,*d,*d,*d]\nf: &f [*e,*e,*e,*e,*e,*e,*e,*e,*e]\n"
     b"g: &g [*f,*f,*f,*f,*f,*f,*f,*f,*f]\nh: [*g,*g,*g,*g,*g,*g,*g,*g,*g]\n", "alias bomb"),
    (b"!!python/object/apply:os.system ['true']", "invalid YAML"),
])
def test_hostile_yaml_is_refused_cleanly(text, problem):
    with pytest.raises(SceneError) as e:
        read_yaml(text, "evil.yaml")
    assert str(e.value).startswith("evil.yaml") and problem in str(e.value)


def test_duplicate_key_names_its_path():
    with pytest.raises(SceneError, match=r"d.yaml: spheres\[0\].radius: duplicate key"):
        read_yaml(b"spheres:\n  - {center: [0,0,0], radius: 1, radius: 2, material: m}\n", "d.yaml")


def test_missing_file(tmp_path):
    with pytest.raises(SceneError, match="cannot read"):
        load_scene(tmp_path / "absent.yaml")

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
    ("image.width", 1 << 29, "image.width", "<= 268435456"),
    ("image", {"height": 1 << 27}, "image.height", "400x134217728"),  # only the height is set: name it
    ("image", {"width": 1 << 27}, "image.width", "134217728x225"),
    ("image", {"width": 1 << 15, "height": 1 << 14}, "image", "32768x16384"),  # both set: the mapping
    ("materials.gold.fuzz", -0.1, "materials.gold.fuzz", ">= 0"),
    ("materials.glass.refraction_index", 0, "materials.glass.refraction_index", ">= 1e-06"),
    ("materials.glass.type", "plastic", "materials.glass.type", "unknown value"),
    ("materials.ground.albedo", [1, 1, -1], "materials.ground.albedo[2]", ">= 0"),
    ("materials.ground.roughness", 1, "materials.ground.roughness", "unknown key"),
    ("camera.look_at", [-2, 2, 1], "camera.look_at", "differ"),
    ("camera.vup", [2, -2, -2], "camera.vup", "parallel"),
    ("camera.vfov", 180, "camera.vfov", "< 180"),
    ("render.samples_per_pixel", 0, "render.samples_per_pixel", ">= 1"),
    ("render.integrator", "bidir", "render.integrator", "unknown value"),
    ("render.seed", -1, "render.seed", ">= 0"),
    ("render.sampler", "halton", "render.sampler", "unknown value"),
    ("render.sampler", 3, "render.sampler", "expected a string"),
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
    (b"!!python/object/apply:os.system ['true']", "unsupported tag"),
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


# --- issue #10, item 8: numbers are read by YAML 1.2's core schema ---------------------------------------

def sphere_file(radius_text: str) -> bytes:
    return (b"materials: {m: {type: lambertian}}\n"
            b"spheres:\n  - {center: [0, 0, -1], radius: " + radius_text.encode() + b", material: m}\n")


@pytest.mark.parametrize("text,value", [
    ("1e6", 1e6), ("1.0e6", 1e6), ("1e-3", 1e-3), (".5", 0.5), ("+1", 1.0), ("-.5e+3", -500.0),
    ("1E+2", 100.0), ("2.", 2.0), ("0x1F", 31.0), ("0o17", 15.0), ("0", 0.0), ("7", 7.0), ("1.5", 1.5),
])
def test_yaml_1_2_numbers_are_numbers(text, value):
    """1e6 was text under YAML 1.1's float pattern ("expected a number")."""
    doc = read_yaml(("[" + text + "]").encode(), "n.yaml")
    assert doc == [value] and type(doc[0]) in (int, float)
    if value > 0:
        assert scene_from_dict(read_yaml(sphere_file(text), "n.yaml")).spheres[0].radius == value


@pytest.mark.parametrize("text,problem", [
    ("1:30", "base-60 number 90"),
    ("010", "octal 8, YAML 1.2 as 10"),
    ("-010", "octal -8"),
    ("09", "YAML 1.2 reads it as 9"),
    ("1_000", "YAML 1.1 reads it as 1000"),
    ("0b11", "binary 3"),
])
def test_yaml_1_1_numbers_that_1_2_reads_differently_are_refused(text, problem):
    """1:30 was silently 90 and 010 silently 8."""
    with pytest.raises(SceneError) as e:
        scene_from_dict(read_yaml(sphere_file(text), "n.yaml"), source="n.yaml")
    assert str(e.value).startswith("n.yaml: spheres[0].radius: expected a number, got "), str(e.value)
    assert problem in str(e.value), str(e.value)


def test_yaml_1_1_lookalikes_are_text_where_text_is_expected():
    assert read_yaml(b"name: 1:30\nspheres: []\n", "n.yaml")["name"] == "1:30"
    assert scene_from_dict(read_yaml(b"name: 010\nmaterials: {m: {type: lambertian}}\nspheres: [{center: [0, 0, -1], radius: 0.5, material: m}]\n", "n.yaml")).name == "010"


@pytest.mark.parametrize("text,expected", [
    ("yes", "string 'yes'"), ("on", "string 'on'"), ("true", "boolean True"), ("~", "nothing"),
    (".nan", "finite"), (".inf", "finite"), ("-.Inf", "finite"),
])
def test_yaml_1_2_booleans_nulls_and_specials(text, expected):
    with pytest.raises(SceneError) as e:
        scene_from_dict(read_yaml(sphere_file(text), "n.yaml"), source="n.yaml")
    assert str(e.value).startswith("n.yaml: spheres[0].radius: ") and expected in str(e.value), str(e.value)


def test_explicit_core_tags_are_read_and_checked():
    assert read_yaml(b"[!!float 1, !!str 1, !!int 0x10, ! 5]", "t.yaml") == [1.0, "1", 16, "5"]
    with pytest.raises(SceneError, match=r"t.yaml: \[0\]: 'abc' is not a valid int"):
        read_yaml(b"[!!int abc]", "t.yaml")


# --- item 9: libyaml, under the same checks; aliases counted apart from size ------------------------------

def test_libyaml_is_used_when_present():
    import yaml

    from wavefront import scenefile
    if yaml.__with_libyaml__:
        assert issubclass(scenefile._Parser, yaml.cyaml.CParser)


def test_python_parser_reads_the_same_values(monkeypatch):
    from wavefront import scenefile
    text = (SCENES / "three_spheres.yaml").read_bytes() + b"extra: [1e6, 010, 1:30, .5, &a [1, 2], *a, yes]\n"
    fast = read_yaml(text, "s.yaml")
    monkeypatch.setattr(scenefile, "_Parser", scenefile._PythonParser)
    assert read_yaml(text, "s.yaml") == fast
    with pytest.raises(SceneError, match="duplicate key"):
        read_yaml(b"a: 1\na: 2\n", "d.yaml")


def test_a_large_document_without_aliases_is_not_an_alias_bomb():
    """200,000 spheres (~2.4 M values) were refused as "alias bomb?" though the file had no aliases."""
    values = read_yaml(b"[" + b"0.5, " * 2_500_000 + b"]", "big.yaml")
    assert len(values) == 2_500_000


def test_aliases_are_counted_by_what_they_expand_to():
    ok = read_yaml(b"s: &s {center: [0, 0, -1], radius: 1, material: m}\nt: [" + b"*s, " * 1000 + b"]\n", "a.yaml")
    assert len(ok["t"]) == 1000 and ok["t"][0] is ok["s"]
    with pytest.raises(SceneError, match=r"a.yaml: t\[\d+\]: aliases expand the document by more than"):
        read_yaml(b"s: &s [" + b"0, " * 1000 + b"]\nt: [" + b"*s, " * 2100 + b"]\n", "a.yaml")
    with pytest.raises(SceneError, match="refers to a value that contains it"):
        read_yaml(b"a: &a [*a]\n", "r.yaml")
    with pytest.raises(SceneError, match="no anchor"):
        read_yaml(b"a: *b\n", "r.yaml")


def test_nesting_error_names_its_path():
    with pytest.raises(SceneError, match=r"n.yaml: a\[0\]\[0\]\[0\].*: nested more than 64 levels"):
        read_yaml(b"a: " + b"[" * 100 + b"]" * 100, "n.yaml")


def test_files_past_the_old_16_mib_limit_load(tmp_path):
    scene = tmp_path / "big.yaml"
    scene.write_bytes(b"#" * (20 << 20) + b"\nmaterials: {m: {type: lambertian}}\nspheres: [{center: [0, 0, -1], radius: 0.5, material: m}]\n")
    assert len(load_scene(scene).spheres) == 1


def test_bulk_spheres_are_checked_like_single_ones():
    """The bulk path (Sphere.many) names the first bad sphere by its index, as the one-by-one path does."""
    doc = {"materials": {"m": {"type": "lambertian"}},
           "spheres": [{"center": [i, 0, -1], "radius": 1, "material": "m"} for i in range(1000)]}
    assert len(scene_from_dict(doc).spheres) == 1000
    for key, value, where, problem in [("radius", -1, "spheres[700].radius", "> 0"),
                                       ("radius", 5e-324, "spheres[700].radius", "too small"),
                                       ("radius", True, "spheres[700].radius", "expected a number"),
                                       ("center", [0, "x", 0], "spheres[700].center[1]", "expected a number"),
                                       ("center", [0, 0], "spheres[700].center", "3 numbers"),
                                       ("material", "nowhere", "spheres[700].material", "unknown material")]:
        bad = copy.deepcopy(doc)
        bad["spheres"][700][key] = value
        bad["spheres"][900]["radius"] = -2  # a later problem is not the one reported
        with pytest.raises(SceneError) as e:
            scene_from_dict(bad, source="b.yaml")
        assert str(e.value).startswith(f"b.yaml: {where}: ") and problem in str(e.value), str(e.value)


# --- item 11: messages ---------------------------------------------------------------------------------

def test_a_too_large_file_is_reported_in_mib(tmp_path):
    scene = tmp_path / "huge.yaml"
    with open(scene, "wb") as f:
        f.truncate(200 << 20)  # sparse: takes no disk
    with pytest.raises(SceneError) as e:
        load_scene(scene)
    assert "200.0 MiB" in str(e.value) and "limit is 128 MiB" in str(e.value) and "bytes" not in str(e.value)


def test_material_names_in_two_unicode_forms_match_in_files():
    text = "materials: {\"e\u0301\": {type: lambertian}}\nspheres: [{center: [0, 0, -1], radius: 1, material: \u00e9}]\n"
    assert load_scene_text(text).spheres[0].material == "\u00e9"


def load_scene_text(text):
    return scene_from_dict(read_yaml(text.encode(), "u.yaml"), source="u.yaml")


def test_a_radius_float64_cannot_invert_is_a_clean_error():
    with pytest.raises(SceneError, match=r"r.yaml: spheres\[0\].radius: 5e-324 is too small"):
        scene_from_dict(read_yaml(sphere_file("5e-324"), "r.yaml"), source="r.yaml")


def test_far_camera_close_target_is_judged_by_precision_not_called_equal():
    far = broken("camera", {"look_from": [1e12, 0, 0], "look_at": [1e12, 0, -1]})
    assert scene_from_dict(far).camera.look_at == (1e12, 0.0, -1.0)
    farther = broken("camera", {"look_from": [1e15, 0, 0], "look_at": [1e15, 0, -1]})
    with pytest.raises(SceneError) as e:
        scene_from_dict(farther, source="c.yaml")
    assert str(e.value).startswith("c.yaml: camera.look_at: the view cannot be resolved in float64")
    assert "equal" not in str(e.value) and "0.125 apart" in str(e.value)


def test_the_number_of_values_is_bounded_apart_from_aliases(monkeypatch):
    """Bytes alone do not bound memory: "[[], [], ...]" costs ~20 times its size in Python objects."""
    from wavefront import scenefile
    monkeypatch.setattr(scenefile, "MAX_VALUES", 1000)
    assert len(read_yaml(b"[" + b"[], " * 400 + b"]", "v.yaml")) == 400
    with pytest.raises(SceneError) as e:
        read_yaml(b"[" + b"[], " * 1200 + b"]", "v.yaml")
    assert "more than 1000 values" in str(e.value) and "alias" not in str(e.value)


@pytest.mark.parametrize("text", [b"spheres: [{radius: " + b"9" * 5000 + b"}]\n",
                                  b"spheres: [{radius: !!int " + b"9" * 5000 + b"}]\n"])
def test_an_integer_past_the_digit_limit_is_named_without_python_advice(text):
    """Python's message ended "use sys.set_int_max_str_digits() to increase the limit"."""
    with pytest.raises(SceneError) as e:
        read_yaml(text, "big.yaml")
    message = str(e.value)
    assert message.startswith("big.yaml: spheres[0].radius: cannot read '9999") and "sys." not in message, message
    assert "an integer of 5,000 digits (at most 4,300 can be read)" in message, message


_HUGE = "0x" + "f" * 5000  # 6,021 decimal digits: str() of it raises ValueError (the 4,300-digit limit)


@pytest.mark.parametrize("old,new", [
    ("samples_per_pixel: 100", "samples_per_pixel: " + _HUGE), ("seed: 1", "seed: " + _HUGE),
    ("width: 400", "width: " + _HUGE), ("max_depth: 50", "max_depth: " + _HUGE), ("vfov: 20", "vfov: " + _HUGE),
    ("radius: 0.5,", "radius: " + _HUGE + ","), ("albedo: [0.1,", "albedo: [" + _HUGE + ","),
    ("seed: 1", "seed: 0o" + "7" * 7000)])
def test_a_huge_integer_is_quoted_by_its_length(tmp_path, old, new):
    """A message quoting it called str() on it: a traceback (exit 1)."""
    with open("scenes/three_spheres.yaml") as f:
        text = f.read()
    assert old in text
    scene = tmp_path / "scene.yaml"
    scene.write_text(text.replace(old, new, 1))
    with pytest.raises(SceneError) as e:
        load_scene(str(scene))
    assert "integer of 6021 digits" in str(e.value) or "integer of 6322 digits" in str(e.value), str(e.value)


def test_quote_counts_digits_exactly():
    from wavefront.validation import quote

    for k in (36, 40, 41, 42, 4300, 4301):
        for value, digits in ((10 ** k - 1, k), (10 ** k, k + 1), (-(10 ** k), k + 1)):
            expected = repr(value) if digits <= 40 else f"{'a negative' if value < 0 else 'an'} integer of {digits} digits"
            assert quote(value) == expected

"""Hostile scene files: loading succeeds or fails with a SceneError naming the
YAML path; the CLI exits 0 or 2, never prints a traceback, never leaves an
output file behind on failure."""

import copy
import math

import pytest
import yaml
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from wavefront import SceneError
from wavefront.scenefile import read_yaml, scene_from_dict

from .test_cli import run
from .test_scenefile import VALID

# fuzzed documents often carry fuzz > 1, which is clamped with a warning
pytestmark = pytest.mark.filterwarnings("ignore::wavefront.scenefile.SceneWarning")


def paths(node, prefix=""):
    """Every (path, parent, key) in a document, YAML-path spelled."""
    if isinstance(node, dict):
        for k, v in node.items():
            p = f"{prefix}.{k}" if prefix else k
            yield p, node, k
            yield from paths(v, p)
    elif isinstance(node, list):
        for i, v in enumerate(node):
            p = f"{prefix}[{i}]"
            yield p, node, i
            yield from paths(v, p)


ALL_PATHS = [p for p, _, _ in paths(VALID)]

BAD_VALUES = st.one_of(
    st.sampled_from([None, True, "text", "", [], {}, [1, 2], [1, 2, 3, 4], math.nan, math.inf, -math.inf,
                     1e308, -1e308, 10**400, -1, 0, 0.0, -0.0, 1e-320, [math.nan] * 3, ["a", "b", "c"],
                     {"unknown": 1}, [[1, 2, 3]]]),
    st.integers(), st.floats(), st.text(max_size=5),
    st.lists(st.floats(allow_nan=True), min_size=0, max_size=4),
)


@st.composite
def mutated_documents(draw):
    doc = copy.deepcopy(VALID)
    target = draw(st.sampled_from(ALL_PATHS))
    parent, key = next((parent, key) for p, parent, key in paths(doc) if p == target)
    action = draw(st.sampled_from(["replace", "replace", "delete", "add_key"]))
    if action == "delete":
        del parent[key]
    elif action == "add_key" and isinstance(parent[key], dict):
        parent[key][draw(st.sampled_from(["colour", "radius2", "Type", "x"]))] = 1  # error lies under target
    else:
        parent[key] = draw(BAD_VALUES)
    return target, doc


def related(error_path: str, mutated: str) -> bool:
    if error_path.startswith(mutated) or mutated.startswith(error_path):
        return True
    # breaking a material can leave a sphere referring to a name that no longer resolves
    if mutated.startswith("materials") and error_path.startswith("spheres"):
        return True
    # look_from, look_at and vup constrain each other; the error names the one checked last
    return mutated.startswith("camera.") and error_path in ("camera.look_at", "camera.vup")


@given(mutated_documents())
@settings(max_examples=400)
def test_loader_accepts_or_names_the_broken_path(case):
    mutated, doc = case
    try:
        scene_from_dict(doc, source="fuzz.yaml")
    except SceneError as e:
        assert str(e).startswith("fuzz.yaml"), str(e)
        assert related(e.path, mutated), (e.path, mutated, str(e))


@given(mutated_documents())
@settings(max_examples=150)
def test_yaml_round_trip_is_handled_the_same(case):
    _, doc = case
    text = yaml.safe_dump(doc).encode()
    try:
        scene_from_dict(read_yaml(text, "fuzz.yaml"), source="fuzz.yaml")
    except SceneError as e:
        assert str(e).startswith("fuzz.yaml")


@given(st.binary(max_size=300))
@settings(max_examples=300)
def test_arbitrary_bytes_never_escape_as_other_errors(data):
    try:
        scene_from_dict(read_yaml(data, "junk.yaml"), source="junk.yaml")
    except SceneError:
        pass


@given(st.text(alphabet="[]{}:,-&*!| \n'\"ab01.", max_size=200))
@settings(max_examples=300)
def test_yaml_punctuation_soup_never_escapes(text):
    try:
        scene_from_dict(read_yaml(text.encode(), "soup.yaml"), source="soup.yaml")
    except SceneError:
        pass


def test_deep_nesting_is_refused():
    for text in ("[" * 5000 + "]" * 5000, "a:\n" + "".join(" " * i + "b:\n" for i in range(1, 200))):
        try:
            read_yaml(text.encode(), "deep.yaml")
        except SceneError as e:
            assert "deep" in str(e)
        else:
            raise AssertionError("deep nesting accepted")


@given(mutated_documents())
@settings(max_examples=12, suppress_health_check=[HealthCheck.function_scoped_fixture])
def test_cli_exits_cleanly_on_fuzzed_scenes(tmp_path_factory, case):
    _, doc = case
    folder = tmp_path_factory.mktemp("fuzz")
    scene = folder / "scene.yaml"
    scene.write_text(yaml.safe_dump(doc))
    out = folder / "out.npy"
    r = run("render", scene, "-o", out, "--width", 8, "--height", 6, "--spp", 1, "--max-depth", 4,
            "--workers", 1)
    assert r.returncode in (0, 2), r.stderr
    assert "Traceback" not in r.stderr
    assert out.exists() == (r.returncode == 0)
    assert not list(folder.glob(".wavefront-*"))

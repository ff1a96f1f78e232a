"""Reading scene files: YAML in, a validated :class:`~wavefront.scene.Scene` out.

Every problem is reported as one :class:`SceneError` naming the file, the YAML
path of the offending value (``spheres[3].material``) and what is wrong.  The
YAML is read with a safe loader, duplicate keys are errors rather than silently
overwritten, and the document's size, nesting and alias expansion are bounded
so a hostile file cannot exhaust memory.
"""

from __future__ import annotations

import math
import os
import warnings
from typing import Any

import numpy as np
import yaml

from .background import Sky, Solid
from .camera import Camera
from .geometry import Sphere
from .materials import Dielectric, Emissive, Lambertian, Metal, Phong
from .scene import INTEGRATORS, PRECISIONS, PointLight, RenderSettings, Scene
from .shapes import Mesh, MeshError, Quad, Triangle, box_quads
from .shapes import mesh as mesh_files
from .shapes.sphere import world_sphere
from .transform import Transform

MAX_FILE_BYTES = 16 * 1024 * 1024  # a scene of a million spheres is ~60 MB; refuse more than a sane hand/script file
MAX_NODES = 2_000_000  # YAML nodes after alias expansion ("billion laughs" guard)
MAX_NESTING = 64  # no valid scene nests deeper than ~4
MAX_PIXELS = 1 << 28  # 268 M pixels: the float32 film alone would need 3 GiB
MAX_SAMPLES_PER_PIXEL = 1 << 24
MAX_DEPTH = 10_000
MAX_SEED = 2**63 - 1
# World-space coordinates and sizes of shapes: the ray tests square them, and
# float64 squares overflow beyond ~1e154.
MAX_COORDINATE = 1e150


class SceneError(ValueError):
    """A scene file or value is malformed.

    ``str(error)`` is the whole user-facing message:
    ``file: yaml.path: problem``.
    """

    def __init__(self, source: str, path: str, problem: str):
        self.source, self.path, self.problem = source, path, problem
        where = f"{source}: {path}" if path else source
        super().__init__(f"{where}: {problem}")


class SceneWarning(UserWarning):
    """Something in a scene was accepted but changed or ignored."""


# ---------------------------------------------------------------------------
# YAML reading

class _Loader(yaml.SafeLoader):
    """Safe loader; mappings are checked for duplicate keys in ``_check_tree``."""


def _check_tree(node: yaml.Node, source: str) -> None:
    """Reject duplicate keys, deep nesting and alias bombs before constructing.

    Expanded size is counted with memoisation on shared (aliased) nodes, so a
    bomb is measured in linear time without ever being expanded.
    """
    sizes: dict[int, int] = {}

    def walk(n: yaml.Node, path: str, depth: int) -> int:
        if depth > MAX_NESTING:
            raise SceneError(source, path, f"nested more than {MAX_NESTING} levels deep")
        key = id(n)
        if key in sizes:
            return sizes[key]
        sizes[key] = 1  # guards against recursive aliases
        total = 1
        if isinstance(n, yaml.MappingNode):
            seen = set()
            for k, v in n.value:
                name = k.value if isinstance(k, yaml.ScalarNode) else "?"
                if isinstance(k, yaml.ScalarNode):
                    if k.value in seen:
                        raise SceneError(source, _join(path, name), "duplicate key")
                    seen.add(k.value)
                total += walk(k, path, depth + 1) + walk(v, _join(path, name), depth + 1)
                if total > MAX_NODES:
                    break
        elif isinstance(n, yaml.SequenceNode):
            for i, v in enumerate(n.value):
                total += walk(v, f"{path}[{i}]", depth + 1)
                if total > MAX_NODES:
                    break
        if total > MAX_NODES:
            raise SceneError(source, path, f"document expands to more than {MAX_NODES} values (alias bomb?)")
        sizes[key] = total
        return total

    walk(node, "", 0)


def _join(path: str, key: str) -> str:
    return f"{path}.{key}" if path else str(key)


def read_yaml(data: bytes, source: str) -> Any:
    """Parse YAML bytes safely, raising :class:`SceneError` on any problem."""
    if len(data) > MAX_FILE_BYTES:
        raise SceneError(source, "", f"file is {len(data)} bytes; the limit is {MAX_FILE_BYTES}")
    try:
        text = data.decode("utf-8")
    except UnicodeDecodeError as e:
        raise SceneError(source, "", f"not UTF-8 text (byte {e.start}: {data[e.start:e.start + 1]!r})") from None
    loader = None
    try:
        loader = _Loader(text)  # the reader already rejects some characters here
        node = loader.get_single_node()
        if node is None:
            raise SceneError(source, "", "the file is empty")
        _check_tree(node, source)
        return loader.construct_document(node)
    except yaml.YAMLError as e:
        mark = getattr(e, "problem_mark", None)
        where = f" (line {mark.line + 1}, column {mark.column + 1})" if mark else ""
        problem = getattr(e, "problem", None) or str(e).splitlines()[0]
        raise SceneError(source, "", f"invalid YAML{where}: {problem}") from None
    except RecursionError:
        raise SceneError(source, "", "YAML nested too deeply") from None
    finally:
        if loader is not None:
            loader.dispose()


def load_scene(path: str | os.PathLike) -> Scene:
    """Read and validate a YAML scene file.

    Raises
    ------
    SceneError
        Naming the file, the YAML path and the problem.
    """
    source = os.fspath(path)
    try:
        with open(source, "rb") as f:
            data = f.read(MAX_FILE_BYTES + 1)
    except OSError as e:
        raise SceneError(source, "", f"cannot read: {e.strerror or e}") from None
    doc = read_yaml(data, source)
    name = os.path.splitext(os.path.basename(source))[0]
    return scene_from_dict(doc, source=source, default_name=name)


# ---------------------------------------------------------------------------
# Validation helpers: each takes the value and its YAML path.

class _Reader:
    def __init__(self, source: str):
        self.source = source

    def fail(self, path: str, problem: str):
        raise SceneError(self.source, path, problem)

    def mapping(self, value, path: str, allowed: set[str], required: set[str] = frozenset()) -> dict:
        if value is None:
            value = {}
        if not isinstance(value, dict):
            self.fail(path, f"expected a mapping, got {_describe(value)}")
        for key in value:
            if not isinstance(key, str):
                self.fail(path, f"keys must be strings, got {_describe(key)}")
            if key not in allowed:
                self.fail(_join(path, key), f"unknown key (expected one of: {', '.join(sorted(allowed))})")
        for key in sorted(required):
            if key not in value:
                self.fail(_join(path, key), "required key is missing")
        return value

    def number(self, value, path: str, *, low=None, low_open=False, high=None, high_open=False) -> float:
        if isinstance(value, bool) or not isinstance(value, (int, float)):
            self.fail(path, f"expected a number, got {_describe(value)}")
        x = float(value) if not isinstance(value, int) or abs(value) < 2**1023 else math.inf
        if not math.isfinite(x):
            self.fail(path, f"must be finite, got {value!r}")
        if low is not None and (x <= low if low_open else x < low):
            self.fail(path, f"must be {'>' if low_open else '>='} {low}, got {value!r}")
        if high is not None and (x >= high if high_open else x > high):
            self.fail(path, f"must be {'<' if high_open else '<='} {high}, got {value!r}")
        return x

    def integer(self, value, path: str, *, low=None, high=None) -> int:
        if isinstance(value, bool) or not isinstance(value, int):
            if isinstance(value, float) and math.isfinite(value) and value.is_integer():
                value = int(value)
            else:
                self.fail(path, f"expected an integer, got {_describe(value)}")
        if low is not None and value < low:
            self.fail(path, f"must be >= {low}, got {value}")
        if high is not None and value > high:
            self.fail(path, f"must be <= {high}, got {value}")
        return value

    def vec3(self, value, path: str, *, low=None, high=None) -> tuple[float, float, float]:
        if not isinstance(value, (list, tuple)) or len(value) != 3:
            self.fail(path, f"expected a list of 3 numbers, got {_describe(value)}")
        return tuple(self.number(v, f"{path}[{i}]", low=low, high=high) for i, v in enumerate(value))

    def color(self, value, path: str, *, high=None) -> tuple[float, float, float]:
        return self.vec3(value, path, low=0.0, high=high)

    def string(self, value, path: str, choices=None) -> str:
        if not isinstance(value, str):
            self.fail(path, f"expected a string, got {_describe(value)}")
        if choices is not None and value not in choices:
            self.fail(path, f"unknown value {value!r} (expected one of: {', '.join(choices)})")
        return value


def _describe(value) -> str:
    if value is None:
        return "nothing (null)"
    kind = {bool: "boolean", int: "integer", float: "number", str: "string",
            list: "list", dict: "mapping"}.get(type(value), type(value).__name__)
    if isinstance(value, (list, dict)):
        return f"a {kind} of {len(value)} item{'s' if len(value) != 1 else ''}"
    text = repr(value)
    return f"{kind} {text[:40] + '...' if len(text) > 40 else text}"


# ---------------------------------------------------------------------------
# The schema

_MATERIAL_KEYS = {
    "lambertian": {"albedo"},
    "metal": {"albedo", "fuzz"},
    "dielectric": {"refraction_index"},
    "emissive": {"color"},
    "phong": {"ambient", "diffuse", "specular", "shininess", "reflectivity"},
}


def _material(r: _Reader, value, path: str):
    spec = r.mapping(value, path, {"type"} | set().union(*_MATERIAL_KEYS.values()), {"type"})
    kind = r.string(spec["type"], _join(path, "type"), tuple(_MATERIAL_KEYS))
    r.mapping(spec, path, {"type"} | _MATERIAL_KEYS[kind])
    p = lambda key: _join(path, key)  # noqa: E731
    if kind == "lambertian":
        return Lambertian(**({"albedo": r.color(spec["albedo"], p("albedo"))} if "albedo" in spec else {}))
    if kind == "metal":
        kw = {}
        if "albedo" in spec:
            kw["albedo"] = r.color(spec["albedo"], p("albedo"))
        if "fuzz" in spec:
            fuzz = r.number(spec["fuzz"], p("fuzz"), low=0.0)
            if fuzz > 1.0:
                warnings.warn(f"{r.source}: {p('fuzz')}: {fuzz} clamped to 1", SceneWarning, stacklevel=2)
            kw["fuzz"] = min(fuzz, 1.0)
        return Metal(**kw)
    if kind == "dielectric":
        kw = {}
        if "refraction_index" in spec:
            kw["refraction_index"] = r.number(spec["refraction_index"], p("refraction_index"), low=0.0, low_open=True)
        return Dielectric(**kw)
    if kind == "emissive":
        return Emissive(**({"color": r.color(spec["color"], p("color"))} if "color" in spec else {}))
    kw = {}
    for key in ("ambient", "diffuse", "specular"):
        if key in spec:
            kw[key] = r.color(spec[key], p(key))
    if "reflectivity" in spec:
        kw["reflectivity"] = r.color(spec["reflectivity"], p("reflectivity"), high=1.0)
    if "shininess" in spec:
        kw["shininess"] = r.number(spec["shininess"], p("shininess"), low=0.0)
    return Phong(**kw)


def scene_from_dict(doc: Any, *, source: str = "<scene>", default_name: str = "scene") -> Scene:
    """Validate a parsed scene document and build the :class:`Scene`."""
    r = _Reader(source)
    top = r.mapping(doc, "", {"name", "image", "camera", "render", "background", "materials",
                              "spheres", "lights", "ambient", "quads", "boxes", "triangles", "meshes"})

    name = r.string(top["name"], "name") if "name" in top else default_name

    image = r.mapping(top.get("image"), "image", {"width", "height"})
    width = r.integer(image.get("width", 400), "image.width", low=1)
    height = r.integer(image.get("height", 225), "image.height", low=1)
    if width * height > MAX_PIXELS:
        r.fail("image", f"{width}x{height} is more than {MAX_PIXELS} pixels")

    rs = r.mapping(top.get("render"), "render", {"samples_per_pixel", "max_depth", "seed", "integrator", "precision"})
    integrator = r.string(rs.get("integrator", "path"), "render.integrator", INTEGRATORS)
    settings = RenderSettings(
        samples_per_pixel=r.integer(rs.get("samples_per_pixel", 100), "render.samples_per_pixel",
                                    low=1, high=MAX_SAMPLES_PER_PIXEL),
        max_depth=r.integer(rs["max_depth"], "render.max_depth", low=1, high=MAX_DEPTH) if "max_depth" in rs else None,
        seed=r.integer(rs.get("seed", 0), "render.seed", low=0, high=MAX_SEED),
        integrator=integrator,
        precision=r.string(rs.get("precision", "auto"), "render.precision", PRECISIONS),
    )

    camera = _camera(r, top.get("camera"))
    background = _background(r, top.get("background"))

    mats = top.get("materials") or {}
    if not isinstance(mats, dict):
        r.fail("materials", f"expected a mapping of names to materials, got {_describe(mats)}")
    materials = {}
    for key, spec in mats.items():
        if not isinstance(key, str):
            r.fail("materials", f"material names must be strings, got {_describe(key)}")
        materials[key] = _material(r, spec, f"materials.{key}")

    spheres = _spheres(r, top.get("spheres"), materials)
    quads = _quads(r, top.get("quads"), materials) + _boxes(r, top.get("boxes"), materials)
    triangles = _triangles(r, top.get("triangles"), materials)
    meshes = _meshes(r, top.get("meshes"), materials)
    if not (spheres or quads or triangles or meshes):
        r.fail("", "the scene has no shapes (give at least one of: spheres, quads, boxes, triangles, meshes)")

    lights_doc = top.get("lights") or []
    if not isinstance(lights_doc, list):
        r.fail("lights", f"expected a list, got {_describe(lights_doc)}")
    lights = []
    for i, spec in enumerate(lights_doc):
        path = f"lights[{i}]"
        spec = r.mapping(spec, path, {"type", "position", "color"}, {"position"})
        r.string(spec.get("type", "point"), f"{path}.type", ("point",))
        lights.append(PointLight(
            position=r.vec3(spec["position"], f"{path}.position"),
            color=r.color(spec["color"], f"{path}.color") if "color" in spec else (1.0, 1.0, 1.0),
        ))
    ambient = r.color(top["ambient"], "ambient") if "ambient" in top else (0.0, 0.0, 0.0)

    if integrator == "path" and (lights or "ambient" in top):
        warnings.warn(f"{source}: lights/ambient are ignored by the path integrator "
                      "(it is lit by emissive shapes and the background)", SceneWarning, stacklevel=2)

    return Scene(spheres=spheres, materials=materials, camera=camera, width=width, height=height,
                 render=settings, background=background, lights=tuple(lights), ambient=ambient, name=name,
                 quads=quads, triangles=triangles, meshes=meshes)


def _camera(r: _Reader, value) -> Camera:
    spec = r.mapping(value, "camera", {"look_from", "look_at", "vup", "vfov", "defocus_angle", "focus_dist"})
    d = Camera()
    look_from = r.vec3(spec["look_from"], "camera.look_from") if "look_from" in spec else d.look_from
    look_at = r.vec3(spec["look_at"], "camera.look_at") if "look_at" in spec else d.look_at
    vup = r.vec3(spec["vup"], "camera.vup") if "vup" in spec else d.vup
    forward = [b - a for a, b in zip(look_from, look_at)]
    if math.hypot(*forward) <= 1e-12 * max(1.0, math.hypot(*look_from)):
        r.fail("camera.look_at", "must differ from camera.look_from")
    cross = (vup[1] * forward[2] - vup[2] * forward[1],
             vup[2] * forward[0] - vup[0] * forward[2],
             vup[0] * forward[1] - vup[1] * forward[0])
    if math.hypot(*cross) <= 1e-9 * math.hypot(*vup) * math.hypot(*forward):
        r.fail("camera.vup", "must not be zero or parallel to the view direction (look_at - look_from)")
    return Camera(
        look_from=look_from,
        look_at=look_at,
        vup=vup,
        vfov=r.number(spec.get("vfov", d.vfov), "camera.vfov",
                      low=0.0, low_open=True, high=180.0, high_open=True),
        defocus_angle=r.number(spec.get("defocus_angle", 0.0), "camera.defocus_angle",
                               low=0.0, high=180.0, high_open=True),
        focus_dist=(r.number(spec["focus_dist"], "camera.focus_dist", low=0.0, low_open=True)
                    if "focus_dist" in spec else None),
    )


def _background(r: _Reader, value):
    spec = r.mapping(value, "background", {"type", "bottom", "top", "color"})
    kind = r.string(spec.get("type", "sky"), "background.type", ("sky", "solid"))
    if kind == "sky":
        r.mapping(spec, "background", {"type", "bottom", "top"})
        d = Sky()
        return Sky(
            bottom=r.color(spec["bottom"], "background.bottom") if "bottom" in spec else d.bottom,
            top=r.color(spec["top"], "background.top") if "top" in spec else d.top,
        )
    r.mapping(spec, "background", {"type", "color"})
    return Solid(color=r.color(spec["color"], "background.color") if "color" in spec else (0.0, 0.0, 0.0))


# ---------------------------------------------------------------------------
# Shapes and their transforms

def _shape_list(r: _Reader, value, key: str) -> list:
    if value is None:
        return []
    if not isinstance(value, list):
        r.fail(key, f"expected a list, got {_describe(value)}")
    return value


def _shape_material(r: _Reader, spec: dict, path: str, materials: dict) -> str:
    material = r.string(spec["material"], f"{path}.material")
    if material not in materials:
        known = ", ".join(sorted(materials)) or "none"
        r.fail(f"{path}.material", f"unknown material {material!r} (defined: {known})")
    return material


def _transform(r: _Reader, value, path: str, *, similarity_only: bool = False) -> Transform | None:
    """A ``transform`` list, first step applied first: ``{translate: [x, y, z]}``,
    ``{rotate: {axis: [x, y, z], angle: degrees}}``, ``{scale: s}`` or
    ``{scale: [sx, sy, sz]}``.  ``similarity_only`` (spheres) refuses
    non-uniform scales, the only step that could make a sphere an ellipsoid."""
    if value is None:
        return None
    if not isinstance(value, list):
        r.fail(path, f"expected a list of steps (translate, rotate, scale), got {_describe(value)}")
    total = Transform()
    for i, step in enumerate(value):
        here = f"{path}[{i}]"
        step = r.mapping(step, here, {"translate", "rotate", "scale"})
        if len(step) != 1:
            r.fail(here, "each step has exactly one of: translate, rotate, scale")
        (kind, arg), = step.items()
        where = f"{here}.{kind}"
        if kind == "translate":
            total = total.then(Transform.translate(r.vec3(arg, where)))
        elif kind == "rotate":
            spec = r.mapping(arg, where, {"axis", "angle"}, {"axis", "angle"})
            axis = r.vec3(spec["axis"], f"{where}.axis")
            if math.hypot(*axis) == 0.0 or not math.isfinite(math.hypot(*axis)):
                r.fail(f"{where}.axis", "must not be zero")
            total = total.then(Transform.rotate(axis, r.number(spec["angle"], f"{where}.angle")))
        else:
            factor = r.vec3(arg, where) if isinstance(arg, (list, tuple)) else (r.number(arg, where),) * 3
            if 0.0 in factor:
                r.fail(where, "must not be zero (it would flatten the shape)")
            if similarity_only and not (factor[0] == factor[1] == factor[2]):
                r.fail(where, "a sphere can only be scaled uniformly (translate, rotate and uniform scale only)")
            total = total.then(Transform.scale(factor))
    if not all(math.isfinite(x) for row in total.matrix for x in row):
        r.fail(path, "the transform overflows")
    return total


def _spheres(r: _Reader, value, materials: dict) -> list[Sphere]:
    spheres = []
    for i, spec in enumerate(_shape_list(r, value, "spheres")):
        path = f"spheres[{i}]"
        spec = r.mapping(spec, path, {"center", "radius", "material", "transform"}, {"center", "radius", "material"})
        material = _shape_material(r, spec, path, materials)
        sphere = Sphere(
            center=r.vec3(spec["center"], f"{path}.center"),
            radius=r.number(spec["radius"], f"{path}.radius", low=0.0, low_open=True),
            material=material,
            transform=_transform(r, spec.get("transform"), f"{path}.transform", similarity_only=True),
        )
        try:
            center, radius = world_sphere(sphere)
        except ValueError as e:
            r.fail(f"{path}.transform", str(e))
        if not (np.abs(center).max() <= MAX_COORDINATE and 0.0 < radius <= MAX_COORDINATE):
            r.fail(path, f"in world space the sphere's centre {center.tolist()} or radius {radius} is beyond "
                         f"{MAX_COORDINATE:g} (or zero)")
        spheres.append(sphere)
    return spheres


def _cross(a, b):
    return (a[1] * b[2] - a[2] * b[1], a[2] * b[0] - a[0] * b[2], a[0] * b[1] - a[1] * b[0])


def _quads(r: _Reader, value, materials: dict) -> list[Quad]:
    quads = []
    for i, spec in enumerate(_shape_list(r, value, "quads")):
        path = f"quads[{i}]"
        spec = r.mapping(spec, path, {"corner", "u", "v", "material", "transform"}, {"corner", "u", "v", "material"})
        material = _shape_material(r, spec, path, materials)
        corner, u, v = (r.vec3(spec[k], f"{path}.{k}") for k in ("corner", "u", "v"))
        area = math.hypot(*_cross(u, v))
        if not area > 1e-12 * math.hypot(*u) * math.hypot(*v) or not math.isfinite(area):
            r.fail(path, "degenerate quad: u and v are parallel (or zero)")
        quad = Quad(corner, u, v, material, _transform(r, spec.get("transform"), f"{path}.transform"))
        _check_world(r, path, np.stack(quad.world()), "quad")
        quads.append(quad)
    return quads


def _boxes(r: _Reader, value, materials: dict) -> list[Quad]:
    quads = []
    for i, spec in enumerate(_shape_list(r, value, "boxes")):
        path = f"boxes[{i}]"
        spec = r.mapping(spec, path, {"min", "max", "material", "transform"}, {"min", "max", "material"})
        material = _shape_material(r, spec, path, materials)
        lo, hi = r.vec3(spec["min"], f"{path}.min"), r.vec3(spec["max"], f"{path}.max")
        if not all(a < b for a, b in zip(lo, hi)):
            r.fail(f"{path}.max", f"must exceed min on every axis (min {list(lo)}, max {list(hi)})")
        faces = box_quads(lo, hi, material, _transform(r, spec.get("transform"), f"{path}.transform"))
        for face in faces:
            _check_world(r, path, np.stack(face.world()), "quad")
        quads.extend(faces)
    return quads


def _triangles(r: _Reader, value, materials: dict) -> list[Triangle]:
    triangles = []
    for i, spec in enumerate(_shape_list(r, value, "triangles")):
        path = f"triangles[{i}]"
        spec = r.mapping(spec, path, {"vertices", "material", "transform"}, {"vertices", "material"})
        material = _shape_material(r, spec, path, materials)
        vertices = spec["vertices"]
        if not isinstance(vertices, list) or len(vertices) != 3:
            r.fail(f"{path}.vertices", f"expected a list of 3 points, got {_describe(vertices)}")
        v0, v1, v2 = (r.vec3(p, f"{path}.vertices[{k}]") for k, p in enumerate(vertices))
        e1 = tuple(b - a for a, b in zip(v0, v1))
        e2 = tuple(b - a for a, b in zip(v0, v2))
        area = math.hypot(*_cross(e1, e2))
        if not area > 1e-12 * math.hypot(*e1) * math.hypot(*e2) or not math.isfinite(area):
            r.fail(f"{path}.vertices", "zero-area triangle (its vertices are collinear or repeated)")
        triangle = Triangle((v0, v1, v2), material, _transform(r, spec.get("transform"), f"{path}.transform"))
        w = triangle.world()
        _check_world(r, path, np.stack((w[0], w[1] - w[0], w[2] - w[0])), "triangle")
        triangles.append(triangle)
    return triangles


def _meshes(r: _Reader, value, materials: dict) -> list[Mesh]:
    """Meshes read from files (by trimesh), paths relative to the scene file.

    Every problem with a file names the scene file, the YAML path and the
    mesh file; degenerate faces are dropped with one warning counting them.
    """
    meshes = []
    base = "" if r.source.startswith("<") else os.path.dirname(r.source)
    total = 0
    for i, spec in enumerate(_shape_list(r, value, "meshes")):
        path = f"meshes[{i}]"
        spec = r.mapping(spec, path, {"file", "material", "smooth", "transform"}, {"file", "material"})
        material = _shape_material(r, spec, path, materials)
        smooth = spec.get("smooth", False)
        if not isinstance(smooth, bool):
            r.fail(f"{path}.smooth", f"expected true or false, got {_describe(smooth)}")
        transform = _transform(r, spec.get("transform"), f"{path}.transform")
        name = r.string(spec["file"], f"{path}.file")
        file = os.path.join(base, name)
        try:
            mesh = Mesh.read(file, material, smooth=smooth, transform=transform,
                             max_faces=mesh_files.MAX_MESH_FACES - total)  # the limit is for the scene
        except MeshError as e:
            r.fail(f"{path}.file", f"{file}: {e}")
        if transform is not None or np.abs(mesh.vertices).max() > MAX_COORDINATE:
            world = (transform or Transform()).points(mesh.vertices.T)
            v, f = world, mesh.faces.T
            with np.errstate(over="ignore", invalid="ignore"):
                area2 = np.linalg.norm(np.cross(v[:, f[1]] - v[:, f[0]], v[:, f[2]] - v[:, f[0]], axis=0), axis=0)
            if not np.abs(world).max() <= MAX_COORDINATE or not (np.isfinite(area2) & (area2 > 0)).all():
                r.fail(f"{path}.transform", f"{file}: the transform takes triangles beyond floating-point range "
                                            "(non-finite, or flattened to zero area)")
        total += len(mesh)
        if mesh.dropped:
            warnings.warn(f"{r.source}: {path}.file: {file}: dropped {mesh.dropped} degenerate (zero-area) "
                          "triangles", SceneWarning, stacklevel=3)
        meshes.append(mesh)
    return meshes


def _check_world(r: _Reader, path: str, rows: np.ndarray, kind: str) -> None:
    """A flat shape after its transform: finite, and not flattened to zero area.

    ``rows`` is ``(3, 3)``: a point, then the two edges spanning the shape."""
    with np.errstate(over="ignore", invalid="ignore"):
        area = float(np.linalg.norm(np.cross(rows[1], rows[2])))
    if not np.abs(rows).max() <= MAX_COORDINATE or not math.isfinite(area):  # also false for NaN
        r.fail(path, f"in world space the {kind} reaches beyond {MAX_COORDINATE:g} (its transform overflows)")
    if area <= 0.0:
        r.fail(path, f"in world space the {kind} has zero area (its transform flattens it)")

"""The scene: what is rendered and how, as plain objects.

A ``Scene`` is what :func:`wavefront.load_scene` returns and what
:func:`wavefront.render` consumes; building one in Python gives exactly the
objects a YAML file would::

    from wavefront import Scene, Sphere, Lambertian, Camera, render
    scene = Scene(
        spheres=[Sphere((0, 0, -1), 0.5, "ball"), Sphere((0, -100.5, -1), 100, "ball")],
        materials={"ball": Lambertian((0.5, 0.5, 0.5))},
        camera=Camera(look_from=(0, 0, 0), look_at=(0, 0, -1)),
    )
    image = render(scene)          # (height, width, 3) linear float32

Every object checks its values when it is built (``wavefront.validation``),
by the same rules a scene file is read with: ``Sphere((0, 0, 0), -1, "m")``
raises ``SceneError("<Sphere>", "radius", "must be > 0.0, got -1")``, and a
scene whose sphere names an undefined material raises
``SceneError("<Scene>", "spheres[3].material", ...)``.  ``replace`` and
``with_overrides`` build a new scene, so they are checked too.  The limits
below bound objects, files and command-line flags alike.
"""

from __future__ import annotations

import dataclasses
import math
import unicodedata
from collections.abc import Mapping, Sequence
from dataclasses import dataclass, field

import numpy as np

from .background import Background, Sky, Solid
from .camera import Camera, direction
from .geometry import FLOAT32_EXTENT, FLOAT32_MAX_REACH, Sphere, position, precision_for
from .lights import EmitterTable
from .materials import Dielectric, Emissive, Lambertian, Material, MaterialTable, Metal, Phong
from .media import MAX_MEDIA, Medium, MediumTable, boundary_primitives, contains, volume_order
from .sampling import SAMPLERS
from .shapes import Intersector, Mesh, Primitives, Quad, QuadSet, SphereSet, Triangle, TriangleSet, mesh_triangles
from .shapes.base import exact_pad
from .textures import TextureTable, is_texture
from .validation import SceneError, color, describe, fail, instance, integer, source_of, string

RGB = tuple[float, float, float]

INTEGRATORS = ("path", "whitted")
DEFAULT_MAX_DEPTH = {"path": 50, "whitted": 3}
PRECISIONS = ("auto", "float32", "float64")

# Limits every entry point shares (objects, scene files, command-line flags).
MAX_PIXELS = 1 << 28  # 268 M pixels: the float32 film alone would need 3 GiB
MAX_SAMPLES_PER_PIXEL = 1 << 24  # 16 M: beyond this float32 sums stop resolving one more sample
MAX_DEPTH = 10_000  # far past any converged path; bounds the bounce loop
MAX_SEED = 2**63 - 1  # what SeedSequence entropy and the checkpoint's int64 hold


@dataclass(frozen=True)
class PointLight:
    """A point light for the ``whitted`` integrator (ignored by ``path``).

    ============  =========  ==================================
    parameter     default    meaning
    ============  =========  ==================================
    ``position``  required   where the light is
    ``color``     (1, 1, 1)  its intensity, per channel
    ============  =========  ==================================
    """

    position: tuple[float, float, float]
    color: RGB = (1.0, 1.0, 1.0)

    def __post_init__(self):
        object.__setattr__(self, "position", position(self, self.position, "position"))
        object.__setattr__(self, "color", color(self, self.color, "color"))


@dataclass(frozen=True)
class RussianRoulette:
    """Russian roulette: past ``depth`` segments a path continues with
    probability ``q = min(max throughput component * eta^2, 0.95)`` and its
    throughput is divided by ``q`` (unbiased), as in Mitsuba's ``path``.

    =========  =======  =====================================================
    parameter  default  meaning
    =========  =======  =====================================================
    ``depth``  5        segments every path traces before roulette may end
                        it (1: a path may end at the first surface it sees)
    =========  =======  =====================================================

    ``eta^2`` is the product of the squared relative refraction indices the
    path has crossed, so paths inside glass (whose throughput the engine does
    not scale by ``1 / eta^2``) are not cut more often than outside.
    """

    depth: int = 5

    def __post_init__(self):
        object.__setattr__(self, "depth", integer(self, self.depth, "depth", low=1, high=MAX_DEPTH))


def _roulette_field(settings, value) -> RussianRoulette | None:
    """``render.russian_roulette``: ``false`` or ``None`` (off), ``true`` (the
    defaults), a mapping of :class:`RussianRoulette`'s parameters, or one.
    (``None`` is what a settings object holds for off, so ``replace`` keeps it.)"""
    if value is False or value is None:
        return None
    if value is True:
        return RussianRoulette()
    if isinstance(value, RussianRoulette):
        return value
    if isinstance(value, Mapping):
        unknown = sorted(set(map(str, value)) - {"depth"})
        if unknown:
            fail(settings, f"russian_roulette.{unknown[0]}", "unknown key (expected: depth)")
        try:
            return RussianRoulette(**value)
        except SceneError as e:
            raise e.within(source_of(settings), "russian_roulette") from None
    fail(settings, "russian_roulette", f"expected false, true or a mapping like {{depth: 5}}, got {describe(value)}")


@dataclass(frozen=True)
class RenderSettings:
    """How to render.

    =====================  ========  ===========================================
    parameter              default   meaning
    =====================  ========  ===========================================
    ``samples_per_pixel``  100       jittered samples averaged per pixel
    ``max_depth``          50 / 3    path segments per sample (``path``) or
                                     recursion depth (``whitted``)
    ``seed``               0         the only source of randomness
    ``integrator``         path      ``path`` or ``whitted``
    ``precision``          auto      ``float32``, ``float64``, or ``auto``:
                                     float32 for scenes within 256 units of
                                     the origin (faster), and for small
                                     spheres inside huge ones, few or many
                                     (path integrator, none moving; see
                                     ``geometry.FLOAT32_MAX_REACH``), else
                                     float64
    ``light_sampling``     true      ``path``: next-event estimation towards
                                     emissive shapes, combined with material
                                     sampling by MIS (power heuristic)
    ``russian_roulette``   depth 5   ``path``: :class:`RussianRoulette`
                                     (``{depth: 5}``), or ``false``
    ``sampler``            sobol     where the uniforms come from: ``sobol``
                                     (each pair of a path a scrambled Sobol'
                                     net over the pixel's samples, pbrt-v4's
                                     PaddedSobolSampler) or ``independent``
    =====================  ========  ===========================================

    With ``light_sampling: false``, ``russian_roulette: false`` and
    ``sampler: independent`` the path integrator is the book's estimator, bit
    for bit.  Whitted ignores the first two.
    """

    samples_per_pixel: int = 100
    max_depth: int | None = None
    seed: int = 0
    integrator: str = "path"
    precision: str = "auto"
    light_sampling: bool = True
    russian_roulette: RussianRoulette | None = field(default_factory=RussianRoulette)
    sampler: str = "sobol"

    def __post_init__(self):
        set_field = object.__setattr__
        set_field(self, "samples_per_pixel", integer(self, self.samples_per_pixel, "samples_per_pixel",
                                                     low=1, high=MAX_SAMPLES_PER_PIXEL))
        set_field(self, "integrator", string(self, self.integrator, "integrator", INTEGRATORS))
        if self.max_depth is not None:
            # whitted's depth counts reflections after the first hit (0: none);
            # a path needs at least one segment to see anything
            low = 0 if self.integrator == "whitted" else 1
            set_field(self, "max_depth", integer(self, self.max_depth, "max_depth", low=low, high=MAX_DEPTH))
        set_field(self, "seed", integer(self, self.seed, "seed", low=0, high=MAX_SEED))
        set_field(self, "precision", string(self, self.precision, "precision", PRECISIONS))
        if not isinstance(self.light_sampling, (bool, np.bool_)):
            fail(self, "light_sampling", f"expected true or false, got {describe(self.light_sampling)}")
        set_field(self, "light_sampling", bool(self.light_sampling))
        set_field(self, "russian_roulette", _roulette_field(self, self.russian_roulette))
        set_field(self, "sampler", string(self, self.sampler, "sampler", SAMPLERS))

    @property
    def depth(self) -> int:
        return self.max_depth if self.max_depth is not None else DEFAULT_MAX_DEPTH[self.integrator]


@dataclass(frozen=True)
class Scene:
    """A complete scene.

    ==============  ===================  =======================================
    field           default              meaning
    ==============  ===================  =======================================
    ``spheres``     ()                   list of :class:`Sphere`
    ``materials``   required             name -> material
    ``quads``       ()                   list of :class:`~wavefront.shapes.Quad`
                                         (a box is six quads)
    ``triangles``   ()                   list of :class:`~wavefront.shapes.Triangle`
    ``meshes``      ()                   list of :class:`~wavefront.shapes.Mesh`
    ``media``       ()                   list of :class:`~wavefront.media.Medium`
                                         (``path`` integrator only)
    ``camera``      ``Camera()``         see :class:`wavefront.camera.Camera`
    ``width``       400                  image width in pixels
    ``height``      225                  image height in pixels
    ``render``      ``RenderSettings()``
    ``background``  ``Sky()``            what escaped rays see
    ``lights``      ()                   point lights (``whitted`` only)
    ``ambient``     (0, 0, 0)            ambient light (``whitted`` only)
    ``name``        "scene"              stored in the output's metadata
    ==============  ===================  =======================================
    """

    spheres: list[Sphere] = field(default_factory=list)
    materials: dict[str, Material] = field(default_factory=dict)
    camera: Camera = field(default_factory=Camera)
    width: int = 400
    height: int = 225
    render: RenderSettings = field(default_factory=RenderSettings)
    background: Background = field(default_factory=Sky)
    lights: tuple[PointLight, ...] = ()
    ambient: RGB = (0.0, 0.0, 0.0)
    # metadata only: not part of the checkpoint fingerprint (see film.scene_fingerprint)
    name: str = field(default="scene", metadata={"fingerprint": False})
    quads: list[Quad] = field(default_factory=list)
    triangles: list[Triangle] = field(default_factory=list)
    meshes: list[Mesh] = field(default_factory=list)
    media: list[Medium] = field(default_factory=list)

    def __post_init__(self):
        """Check every field and how they fit together; normalise sequences to
        lists and tuples, and material names to Unicode NFC."""
        set_field = object.__setattr__
        set_field(self, "name", string(self, self.name, "name"))
        for key in ("width", "height"):
            set_field(self, key, integer(self, getattr(self, key), key, low=1, high=MAX_PIXELS))
        if self.width * self.height > MAX_PIXELS:
            fail(self, "", f"an image of {self.width}x{self.height} (width x height) is more than {MAX_PIXELS} pixels")
        instance(self, self.render, "render", RenderSettings, "RenderSettings")
        instance(self, self.background, "background", (Sky, Solid), "Sky or Solid")
        set_field(self, "ambient", color(self, self.ambient, "ambient"))
        instance(self, self.camera, "camera", Camera, "a Camera")
        try:
            self.camera.check_resolution(self.width, self.height)
        except SceneError as e:
            raise e.within(e.source.replace("Camera", "Scene"), "camera") from None

        if not isinstance(self.materials, Mapping):
            fail(self, "materials", f"expected a mapping of names to materials, got {describe(self.materials)}")
        materials, spelled = {}, {}
        kinds = "a material (" + ", ".join(t.__name__ for t in MATERIAL_TYPES) + ")"
        for key, material in self.materials.items():
            if not isinstance(key, str):
                fail(self, "materials", f"material names must be strings, got {describe(key)}")
            normal = unicodedata.normalize("NFC", key)
            if normal in materials:
                fail(self, f"materials.{key}", f"is the same name as {spelled[normal]!r} in another Unicode form")
            instance(self, material, f"materials.{key}", MATERIAL_TYPES, kinds)
            materials[normal], spelled[normal] = material, key
        set_field(self, "materials", materials)

        shapes = {}
        for key, kind in (("spheres", Sphere), ("quads", Quad), ("triangles", Triangle), ("meshes", Mesh)):
            shapes[key] = self._shape_list(key, kind)
            set_field(self, key, shapes[key])
            self._check_references(materials, key, shapes[key])
        media = self._shape_list("media", Medium)
        set_field(self, "media", media)
        if len(media) > MAX_MEDIA:
            fail(self, "media", f"{len(media)} media; at most {MAX_MEDIA} are supported (a path holds its "
                                "media as the bits of one 64-bit mask)")
        if media and self.render.integrator != "path":
            fail(self, "media", "media need the path integrator (render.integrator: path)")
        if not any(shapes.values()) and not media:
            fail(self, "shapes", "the scene has no shapes (give at least one of: spheres, quads, boxes, "
                                 "triangles, meshes, media)")

        lights = self.lights
        if not isinstance(lights, Sequence) or isinstance(lights, str):
            fail(self, "lights", f"expected a list of PointLight, got {describe(lights)}")
        for i, light in enumerate(lights):
            instance(self, light, f"lights[{i}]", PointLight, "a PointLight")
        set_field(self, "lights", tuple(lights))
        if self.render.precision == "float32":
            self._check_float32()

    def _check_float32(self) -> None:
        """A forced ``precision: float32`` must be able to hold the scene:
        intersection squares distances and radii, which overflow float32
        beyond ``FLOAT32_MAX_EXTENT`` and underflow below ``FLOAT32_MIN_SPHERE``."""
        shapes = shape_points(self)
        extent = scene_extent(self, shapes)
        if not extent <= FLOAT32_MAX_EXTENT:
            fail(self, "render.precision", f"float32 cannot hold this scene: it reaches {extent:.3g} from the origin, "
                                           f"beyond {FLOAT32_MAX_EXTENT:g}, where squares of distances overflow "
                                           "float32 (use float64 or auto)")
        radius = shapes[1][:len(self.spheres)]
        if radius.size and not radius.min() >= FLOAT32_MIN_SPHERE:
            fail(self, "render.precision", f"float32 cannot hold this scene: a sphere's radius is {radius.min():.3g}, "
                                           f"below {FLOAT32_MIN_SPHERE:g}, where squares of radii underflow float32 "
                                           "(use float64 or auto)")

    def _shape_list(self, key: str, kind: type) -> list:
        shapes = getattr(self, key)
        if not isinstance(shapes, Sequence) or isinstance(shapes, str):
            fail(self, key, f"expected a list of {kind.__name__}, got {describe(shapes)}")
        if type(shapes) is not list:
            shapes = list(shapes)
        if set(map(type, shapes)) - {kind}:
            i = next(i for i, s in enumerate(shapes) if not isinstance(s, kind))
            instance(self, shapes[i], f"{key}[{i}]", kind, f"a {kind.__name__}")
        return shapes

    def _check_references(self, materials: dict, key: str, shapes: list) -> None:
        """Every shape names a defined material (or indexes one)."""
        material_of = _material_of if key == "spheres" else _attribute_material
        used = set(map(material_of, shapes))
        names = {m for m in used if isinstance(m, str)}
        indices = used - names
        if names <= materials.keys() and all(i < len(materials) for i in indices):
            return
        for i, shape in enumerate(shapes):
            m = shape.material
            if isinstance(m, str) and m not in materials:
                fail(self, f"{key}[{i}].material", unknown_material(m, materials))
            if isinstance(m, int) and m >= len(materials):
                fail(self, f"{key}[{i}].material", f"material index {m} is out of range "
                                                   f"(the scene has {len(materials)} materials)")

    def replace(self, **changes) -> Scene:
        """A copy with ``changes``, validated as a new scene is."""
        return dataclasses.replace(self, **changes)

    def with_overrides(self, *, width=None, height=None, samples_per_pixel=None,
                       max_depth=None, seed=None, sampler=None) -> Scene:
        """Command-line style overrides; ``width`` alone keeps the aspect ratio.

        The result is validated as any scene is: a bad value raises
        :class:`SceneError` naming ``width``, ``height`` or ``render.<field>``
        (``sampler``: ``"sobol"`` or ``"independent"``).
        """
        w = integer(self, width, "width", low=1, high=MAX_PIXELS) if width is not None else None
        h = integer(self, height, "height", low=1, high=MAX_PIXELS) if height is not None else None
        if w is not None and h is None:
            h = max(1, round(w * self.height / self.width))
            if w * h > MAX_PIXELS:  # the derived height is not what the caller got wrong: name the width
                fail(self, "width", f"an image of {w}x{h} (the height keeps the aspect ratio of "
                                    f"{self.width}x{self.height}) is more than {MAX_PIXELS} pixels")
        if h is not None and w is None:
            w = max(1, round(h * self.width / self.height))
            if w * h > MAX_PIXELS:
                fail(self, "height", f"an image of {w}x{h} (the width keeps the aspect ratio of "
                                     f"{self.width}x{self.height}) is more than {MAX_PIXELS} pixels")
        settings = {key: value for key, value in (("samples_per_pixel", samples_per_pixel),
                                                  ("max_depth", max_depth), ("seed", seed), ("sampler", sampler))
                    if value is not None}
        try:
            render = dataclasses.replace(self.render, **settings)
        except SceneError as e:
            raise e.within(source_of(self), "render") from None
        return self.replace(width=w if w is not None else self.width, height=h if h is not None else self.height,
                            render=render)

    def compile(self) -> CompiledScene:
        return CompiledScene.build(self)


@dataclass
class CompiledScene:
    """The scene as arrays for the kernels; built once per render."""

    scene: Scene
    shapes: Intersector  # the Primitives (brute force) or the BVH over them
    materials: MaterialTable
    light_position: np.ndarray  # (3, L)
    light_color: np.ndarray  # (3, L)
    dtype: np.dtype
    emitters: EmitterTable | None = None  # every emissive primitive, for light sampling (path)
    media: MediumTable | None = None  # participating media, None in a scene without

    @classmethod
    def build(cls, scene: Scene) -> CompiledScene:
        from .accel import build_intersector

        # world-space bounds once: a million spheres make them a second's work
        bounds = shape_points(scene)
        dtype = precision_of(scene, bounds)
        names = list(scene.materials)
        index = {name: i for i, name in enumerate(names)}
        table = MaterialTable.build([scene.materials[n] for n in names], names, dtype)
        extent = scene_extent(scene, bounds)
        primitives = compile_shapes(scene, index, dtype, extent)
        media = compile_media(scene, primitives, extent)
        emitters = EmitterTable.build(primitives, table) if scene.render.integrator == "path" else None
        shapes = build_intersector(primitives, extent)
        nl = len(scene.lights)
        light_position = np.array([lt.position for lt in scene.lights], dtype=np.float64).reshape(nl, 3).T
        light_color = np.array([lt.color for lt in scene.lights], dtype=np.float64).reshape(nl, 3).T
        return cls(scene, shapes, table, light_position, light_color, dtype, emitters, media)


def compile_shapes(scene: Scene, index: dict[str, int], dtype, extent: float) -> Primitives:
    """Every shape of ``scene`` in world space (each transform applied once, here) as one :class:`Primitives`."""
    def material(shape):
        return shape.material if isinstance(shape.material, int) else index[shape.material]

    spheres = SphereSet.build(scene.spheres, [material(s) for s in scene.spheres], dtype)
    quads = QuadSet.build(scene.quads, [material(q) for q in scene.quads], dtype, extent)
    # loose triangles and every mesh's triangles form one triangle set
    parts, materials = [], []
    if scene.triangles:
        v = np.array([t.world() for t in scene.triangles], dtype=np.float64)  # (T, 3 vertices, 3)
        parts.append(dict(v0=v[:, 0].T, v1=v[:, 1].T, v2=v[:, 2].T, vertex_normal=None, vertex_uv=None))
        materials.append(np.array([material(t) for t in scene.triangles], dtype=np.int32))
    for m in scene.meshes:
        parts.append(mesh_triangles(m))
        materials.append(np.full(len(m), material(m), dtype=np.int32))
    material_idx = np.concatenate(materials) if materials else np.zeros(0, np.int32)
    joined = {key: np.concatenate([p[key] for p in parts], axis=-1) if parts else np.zeros((3, 0))
              for key in ("v0", "v1", "v2")}
    normals = uvs = None
    if any(p["vertex_normal"] is not None for p in parts):  # flat triangles repeat their face normal
        normals = np.concatenate([p["vertex_normal"] if p["vertex_normal"] is not None else
                                  np.broadcast_to(_face_normal(p), (3, 3, p["v0"].shape[1])) for p in parts], axis=-1)
    if any(p["vertex_uv"] is not None for p in parts):  # without file uv, the barycentrics
        corners = np.array([[0.0, 0.0], [1.0, 0.0], [0.0, 1.0]])[:, :, None]
        uvs = np.concatenate([p["vertex_uv"] if p["vertex_uv"] is not None else
                              np.broadcast_to(corners, (3, 2, p["v0"].shape[1])) for p in parts], axis=-1)
    triangles = TriangleSet(joined["v0"], joined["v1"], joined["v2"], material_idx, dtype, extent, normals, uvs)
    return Primitives([spheres, quads, triangles], dtype, exact_pad(dtype, extent))


def compile_media(scene: Scene, primitives: Primitives, extent: float) -> MediumTable | None:
    """The scene's media as a :class:`MediumTable` (None without media).

    Boundaries are primitives of their own, in their own intersector: the
    scene's intersection is untouched by them (so a ray's hit is found from
    its vertex exactly as without media), and the path integrator walks the
    boundaries between a vertex and its hit.  A boundary primitive identical
    to a visible one is not duplicated: the visible one bounds the medium
    (see :mod:`wavefront.media`).  Media are numbered by their bit in a
    path's mask, largest volume first (the innermost wins); a boundary
    primitive's ``material_idx`` is that number.
    """
    if not scene.media:
        return None
    dtype = primitives.dtype
    volume = volume_order(scene.media)
    medium_of_bit = np.lexsort((np.arange(volume.size), -volume))  # ties: the one listed last gets the higher bit
    bit_of = np.empty_like(medium_of_bit)
    bit_of[medium_of_bit] = np.arange(volume.size)
    visible = {type(k).__name__: k for k in primitives.kinds}
    offset = {type(k).__name__: int(o) for k, o in zip(primitives.kinds, primitives.offsets)}
    interface = np.full(len(primitives), -1, dtype=np.int32)
    # per kind: (medium, rows (B, K) compared with the visible kind's fields, rows (B, K') it is built from)
    rows = {"SphereSet": [], "QuadSet": [], "TriangleSet": []}
    for listed, medium in enumerate(scene.media):
        m = int(bit_of[listed])
        kind, value = boundary_primitives(medium)
        if kind == "sphere":
            center, radius = value
            sphere = np.append(center, radius)[None, :]
            rows["SphereSet"].append((m, sphere, sphere))
        elif kind == "quads":
            quads = np.array([np.concatenate(q.world()) for q in value])
            rows["QuadSet"].append((m, quads, quads))
        else:
            v0, v1, v2 = value["v0"], value["v1"], value["v2"]
            rows["TriangleSet"].append((m, np.concatenate((v0, v1 - v0, v2 - v0)).T, np.concatenate((v0, v1, v2)).T))
    # a moving sphere is never a boundary (the boundary stays where it is):
    # NaN centres match no wanted row (boundaries are finite)
    fields = {"SphereSet": lambda k: np.concatenate((k.center if k.velocity is None else
                                                     np.where((k.velocity != 0).any(axis=0), np.nan, k.center),
                                                     k.radius[None, :])),
              "QuadSet": lambda k: np.concatenate((k.corner, k.u, k.v)),
              "TriangleSet": lambda k: np.concatenate((k.v0, k.e1, k.e2))}
    kinds = []
    # media sealed inside one visible sphere (see MediumTable.sealed): centre, radius
    sealed_center, sealed_radius = np.full((3, volume.size), np.nan), np.full(volume.size, np.nan)
    for name, parts in rows.items():
        if not parts:
            continue
        have = fields[name](visible[name]).T.astype(np.float64) if name in visible else np.zeros((0, 1))
        keep, medium_idx = [], []
        for m, wanted, build in parts:
            # compared at the render's precision, the one the visible shapes are held in
            same = _matching_rows(have, wanted.astype(dtype).astype(np.float64))
            interface[offset.get(name, 0) + same[same >= 0]] = m
            if name == "SphereSet" and same[0] >= 0:  # the sphere's own values, as the intersector holds them
                sealed_center[:, m] = visible[name].center[:, same[0]]
                sealed_radius[m] = visible[name].radius[same[0]]
            keep.append(build[same < 0])
            medium_idx.append(np.full(keep[-1].shape[0], m, dtype=np.int32))
        r, medium_idx = np.concatenate(keep), np.concatenate(medium_idx)
        if name == "SphereSet":
            kinds.append(SphereSet(r[:, :3].T, r[:, 3], medium_idx, dtype))
        elif name == "QuadSet":
            kinds.append(QuadSet(r[:, 0:3].T, r[:, 3:6].T, r[:, 6:9].T, medium_idx, dtype, extent))
        else:
            kinds.append(TriangleSet(r[:, 0:3].T, r[:, 3:6].T, r[:, 6:9].T, medium_idx, dtype, extent))
    from .accel import build_intersector

    boundaries = Primitives(kinds, dtype, exact_pad(dtype, extent))
    bounds = (np.full((3, 1), -np.inf), np.full((3, 1), np.inf))
    if len(boundaries):
        lo, hi = boundaries.bounds()
        # far more than any hit's rounding (flat primitives accept hits up to exact_pad outside their box)
        pad = 1e-6 * max(extent, 1.0) + 4 * exact_pad(np.float32, extent)
        bounds = (lo.min(axis=1, keepdims=True) - pad, hi.max(axis=1, keepdims=True) + pad)
    look_from = scene.camera.look_from
    camera_mask = sum(1 << int(bit_of[m]) for m, medium in enumerate(scene.media) if contains(medium, look_from))
    density = np.array([m.density for m in scene.media], dtype=np.float64)
    textures = TextureTable()
    node = np.array([textures.add(m.albedo) for m in scene.media], dtype=np.int64)
    albedo = np.stack([textures.mean(n) for n in node], axis=1)
    textured = any(is_texture(m.albedo) for m in scene.media)
    return MediumTable(density=density.take(medium_of_bit), albedo=albedo.take(medium_of_bit, axis=1),
                       medium_of_bit=medium_of_bit,
                       boundaries=build_intersector(boundaries, extent) if len(boundaries) else None,
                       interface_of=interface, camera_mask=np.uint64(camera_mask), bounds=bounds,
                       textures=textures if textured else None,
                       albedo_node=node.take(medium_of_bit) if textured else None,
                       sealed=_sealed(sealed_center, sealed_radius, dtype, extent))


def _sealed(center, radius, dtype, extent):
    """``MediumTable.sealed``: (centre (3, K), radius shrunk by a margin,
    radius grown by it, margin), or None when no medium is sealed.  The
    margin is far above the rounding of the exact sphere test in the scene's
    precision: 1e-4 of the radius (the root's error is a few epsilons of it)
    plus 64 exact pads of the scene (the rounding of the points' coordinates)."""
    if np.isnan(radius).all():
        return None
    margin = 1e-4 * radius + 64.0 * exact_pad(dtype, extent)
    return center, radius - margin, margin


def _matching_rows(visible: np.ndarray, wanted: np.ndarray) -> np.ndarray:
    """For each row of ``wanted (B, K)``, the index of an identical row of
    ``visible (M, K)`` (both float64), or -1: sorted byte keys, no Python loop."""
    found = np.full(wanted.shape[0], -1, dtype=np.int64)
    if visible.shape[0] == 0 or wanted.shape[0] == 0 or visible.shape[1] != wanted.shape[1]:
        return found
    key = np.dtype((np.void, 8 * visible.shape[1]))
    have = np.ascontiguousarray(visible + 0.0).view(key).ravel()  # + 0.0: -0.0 and 0.0 get the same bytes
    want = np.ascontiguousarray(wanted + 0.0).view(key).ravel()
    order = np.argsort(have, kind="stable")
    pos = np.minimum(np.searchsorted(have[order], want), have.size - 1)
    hit = have[order[pos]] == want
    found[hit] = order[pos[hit]]
    return found


def _face_normal(part: dict) -> np.ndarray:
    n = np.cross(part["v1"] - part["v0"], part["v2"] - part["v0"], axis=0)
    return n / np.linalg.norm(n, axis=0)


def shape_points(scene: Scene) -> tuple[np.ndarray, np.ndarray]:
    """World-space points and radii that bound every shape: ``(P, 3)``, ``(P,)``
    (sphere centres with their radii, spheres first; then moving spheres'
    centres at time 1; quad corners and vertices with 0)."""
    from .shapes.sphere import world_center1, world_sphere

    points, radii = [np.zeros((0, 3))], [np.zeros(0)]
    if scene.spheres:
        world = [world_sphere(s) for s in scene.spheres]
        points.append(np.array([c for c, _ in world]))
        radii.append(np.array([r for _, r in world]))
        moving = [i for i, s in enumerate(scene.spheres) if s.center1 is not None]
        if moving:
            points.append(np.array([world_center1(scene.spheres[i]) for i in moving]))
            radii.append(np.array([world[i][1] for i in moving]))
    for q in scene.quads:  # per scene object
        c, u, v = q.world()
        points.append(np.array([c, c + u, c + v, c + u + v]))
        radii.append(np.zeros(4))
    if scene.triangles:
        points.append(np.concatenate([t.world() for t in scene.triangles]))
    for m in scene.meshes:
        vertices = m.vertices if m.transform is None else m.transform.points(m.vertices.T).T
        points.append(vertices)
    radii.append(np.zeros(sum(p.shape[0] for p in points) - sum(r.size for r in radii)))
    for medium in scene.media:  # boundaries bound where rays go, too
        kind, value = boundary_primitives(medium)
        if kind == "sphere":
            points.append(value[0][None, :])
            radii.append(np.array([value[1]]))
        else:
            corners = (np.concatenate([_quad_corners(*q.world()) for q in value]) if kind == "quads"
                       else np.concatenate((value["v0"], value["v1"], value["v2"]), axis=1).T)
            points.append(corners)
            radii.append(np.zeros(corners.shape[0]))
    return np.concatenate(points), np.concatenate(radii)


def _quad_corners(c, u, v) -> np.ndarray:
    return np.array([c, c + u, c + v, c + u + v])


def unknown_material(name: str, materials) -> str:
    """The problem of a shape whose material ``name`` is not among ``materials``."""
    return f"unknown material {name!r} (defined: {', '.join(sorted(materials)) or 'none'})"


MATERIAL_TYPES = (Lambertian, Metal, Dielectric, Emissive, Phong)
_material_of = Sphere.material.__get__  # slot getter: map() over a million spheres at C speed


def _attribute_material(shape):
    return shape.material


# A forced float32 render squares distances (up to twice the extent) and
# sums three of them: float32 holds 3.4e38, so 1e18 keeps them finite with
# room; radii square to at least float32's smallest normal number, 1.2e-38.
FLOAT32_MAX_EXTENT = 1e18
FLOAT32_MIN_SPHERE = 1e-18


def scene_extent(scene: Scene, shapes: tuple[np.ndarray, np.ndarray] | None = None) -> float:
    """Distance from the origin within which every ray starts and every hit lies.

    ``shapes`` is :func:`shape_points` of ``scene`` if the caller has it already."""
    cam = scene.camera
    points = [cam.look_from, cam.look_at] + [light.position for light in scene.lights]
    points = np.linalg.norm(np.array(points, dtype=np.float64).reshape(-1, 3), axis=1)
    # camera rays start anywhere on the lens, up to the defocus radius from look_from
    focus = cam.focus_dist if cam.focus_dist is not None else \
        float(np.linalg.norm(np.subtract(cam.look_at, cam.look_from, dtype=np.float64)))
    points[0] += abs(focus) * math.tan(math.radians(min(cam.defocus_angle, 179.0) / 2.0))
    center, radius = shapes if shapes is not None else shape_points(scene)
    with np.errstate(over="ignore"):  # a finite but astronomically large scene has an infinite extent
        reach = np.linalg.norm(center, axis=1) + radius
    return float(max(points.max(), reach.max(initial=0.0)))


def precision_of(scene: Scene, shapes: tuple[np.ndarray, np.ndarray] | None = None) -> np.dtype:
    """The floating-point type the wavefront runs in (see ``geometry.FLOAT32_EXTENT``).

    ``auto`` keeps float64 for any scene with quads, triangles or meshes: their
    exact tests divide by a determinant that float32 would leave with too few
    digits on slivers and grazing rays.  ``shapes`` as for :func:`scene_extent`.
    """
    choice = scene.render.precision
    if choice != "auto":
        return np.dtype(choice)
    if scene.quads or scene.triangles or scene.meshes or scene.media:
        return np.dtype(np.float64)
    shapes = shapes if shapes is not None else shape_points(scene)
    dtype = precision_for(shapes[1][:len(scene.spheres)], scene_extent(scene, shapes))  # spheres come first
    if dtype == np.float32 or not _huge_spheres_fit_float32(scene, shapes):
        return dtype
    return np.dtype(np.float32)


def _huge_spheres_fit_float32(scene: Scene, shapes) -> bool:
    """Whether a scene of spheres that fails the float32 rule only through
    huge spheres (radius above ``FLOAT32_EXTENT``) runs in float32 with them
    anchored (see ``geometry.FLOAT32_MAX_REACH``): everything else (camera,
    lights, the other spheres) passes the rule on its own, and every reach
    ``|c| + r`` is within ``FLOAT32_MAX_REACH``.  The path integrator only:
    Whitted's one ray through each pixel centre sees a huge ground's far
    horizon, where a hit's shading flips with rounding (0.5 % of
    whitted.yaml's pixels moved, by up to 0.12; in a path-traced image such
    flips are noise).  Moving spheres keep float64
    (their anchors would move).  Scenes of ``accel.BVH_THRESHOLD`` spheres or
    more (the cover scene) run anchored too: the BVH gives brute force's hits
    exactly in float32 with anchored roots (see ``bvh.BVH``'s notes on anchored
    sets and tests/test_bvh.py's anchored tests)."""
    if scene.render.integrator != "path" or any(s.center1 is not None for s in scene.spheres):
        return False
    center, radius = shapes
    huge = radius > FLOAT32_EXTENT
    # A huge lamp keeps float64: its light samples' shadow rays stop short of
    # it by 1e-4 of their length, which near the lamp is less than the
    # anchored float32 roots' error (0.02 % of them were shadowed by the lamp itself).
    # So does a huge sphere that reflects specularly (metal, glass): the anchored
    # roots' self-hit error grows as u |o - q| / cos, and a mirror sends the grazing
    # rays near its horizon on at exactly those angles, where 5.5 % of a fuzzy metal
    # ground's reflections found the ground again just past T_MIN (none in float64):
    # the cover scene with a metal ground came out 4-8 % darker along its horizon
    # (per-block z down to -15.6; session 11's review).  A diffuse ground scatters
    # few rays that grazingly, and its images pass the z-tests.
    materials = list(scene.materials.values())
    kept64 = np.array([isinstance(materials[s.material] if isinstance(s.material, int) else
                                  scene.materials[s.material], (Emissive, Metal, Dielectric))
                       for s in scene.spheres], dtype=bool)
    if (huge[:len(scene.spheres)] & kept64).any():
        return False
    with np.errstate(over="ignore"):
        reach = np.linalg.norm(center, axis=1) + radius
    if not huge.any() or not reach.max() <= FLOAT32_MAX_REACH:
        return False
    return precision_for(radius[~huge], scene_extent(scene, (center[~huge], radius[~huge]))) == np.float32


def turntable(scene: Scene, frame: int, frames: int) -> Scene:
    """``scene`` with ``look_from`` turned ``frame / frames`` of a full circle
    around the axis through ``look_at`` along ``vup``."""
    cam = scene.camera
    axis = direction(np.asarray(cam.vup, dtype=np.float64))  # any scale: a vup of 1e-300 too
    pivot = np.asarray(cam.look_at, dtype=np.float64)
    v = np.asarray(cam.look_from, dtype=np.float64) - pivot
    angle = 2.0 * np.pi * frame / frames
    # Rodrigues' rotation formula
    rotated = (v * np.cos(angle) + np.cross(axis, v) * np.sin(angle)
               + axis * np.dot(axis, v) * (1.0 - np.cos(angle)))
    look_from = tuple(float(x) for x in pivot + rotated)
    return scene.replace(camera=dataclasses.replace(cam, look_from=look_from), name=f"{scene.name}#{frame}")

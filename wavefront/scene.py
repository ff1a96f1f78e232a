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
"""

from __future__ import annotations

import dataclasses
import math
from dataclasses import dataclass, field

import numpy as np

from .background import Background, Sky
from .camera import Camera
from .geometry import Sphere, SphereSet, precision_for
from .materials import Material, MaterialTable

RGB = tuple[float, float, float]

INTEGRATORS = ("path", "whitted")
DEFAULT_MAX_DEPTH = {"path": 50, "whitted": 3}
PRECISIONS = ("auto", "float32", "float64")


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
                                     the origin (faster), else float64
    =====================  ========  ===========================================
    """

    samples_per_pixel: int = 100
    max_depth: int | None = None
    seed: int = 0
    integrator: str = "path"
    precision: str = "auto"

    @property
    def depth(self) -> int:
        return self.max_depth if self.max_depth is not None else DEFAULT_MAX_DEPTH[self.integrator]


@dataclass(frozen=True)
class Scene:
    """A complete scene.

    ==============  ===================  =======================================
    field           default              meaning
    ==============  ===================  =======================================
    ``spheres``     required             list of :class:`Sphere`
    ``materials``   required             name -> material
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

    spheres: list[Sphere]
    materials: dict[str, Material]
    camera: Camera = field(default_factory=Camera)
    width: int = 400
    height: int = 225
    render: RenderSettings = field(default_factory=RenderSettings)
    background: Background = field(default_factory=Sky)
    lights: tuple[PointLight, ...] = ()
    ambient: RGB = (0.0, 0.0, 0.0)
    name: str = "scene"

    def replace(self, **changes) -> Scene:
        return dataclasses.replace(self, **changes)

    def with_overrides(self, *, width=None, height=None, samples_per_pixel=None,
                       max_depth=None, seed=None) -> Scene:
        """Command-line style overrides; ``width`` alone keeps the aspect ratio."""
        w, h = self.width, self.height
        if width is not None and height is None:
            h = max(1, round(width * self.height / self.width))
        if height is not None and width is None:
            w = max(1, round(height * self.width / self.height))
        w = width if width is not None else w
        h = height if height is not None else h
        settings = {}
        for key, value in (("samples_per_pixel", samples_per_pixel),
                           ("max_depth", max_depth), ("seed", seed)):
            if value is not None:
                settings[key] = value
        return self.replace(width=w, height=h, render=dataclasses.replace(self.render, **settings))

    def compile(self) -> CompiledScene:
        return CompiledScene.build(self)


@dataclass
class CompiledScene:
    """The scene as arrays for the kernels; built once per render."""

    scene: Scene
    spheres: SphereSet
    materials: MaterialTable
    light_position: np.ndarray  # (3, L)
    light_color: np.ndarray  # (3, L)
    dtype: np.dtype

    @classmethod
    def build(cls, scene: Scene) -> CompiledScene:
        from .accel import build_intersector

        dtype = precision_of(scene)
        names = list(scene.materials)
        index = {name: i for i, name in enumerate(names)}
        table = MaterialTable.build([scene.materials[n] for n in names], names, dtype)
        m = len(scene.spheres)
        center = np.array([s.center for s in scene.spheres], dtype=np.float64).reshape(m, 3).T
        radius = np.array([s.radius for s in scene.spheres], dtype=np.float64)
        material_idx = np.array(
            [s.material if isinstance(s.material, int) else index[s.material] for s in scene.spheres],
            dtype=np.int32,
        )
        spheres = build_intersector(SphereSet(center, radius, material_idx, dtype), scene_extent(scene))
        nl = len(scene.lights)
        light_position = np.array([lt.position for lt in scene.lights], dtype=np.float64).reshape(nl, 3).T
        light_color = np.array([lt.color for lt in scene.lights], dtype=np.float64).reshape(nl, 3).T
        return cls(scene, spheres, table, light_position, light_color, dtype)


def scene_extent(scene: Scene) -> float:
    """Distance from the origin within which every ray starts and every hit lies."""
    cam = scene.camera
    points = [cam.look_from, cam.look_at] + [light.position for light in scene.lights]
    points = np.linalg.norm(np.array(points, dtype=np.float64).reshape(-1, 3), axis=1)
    # camera rays start anywhere on the lens, up to the defocus radius from look_from
    focus = cam.focus_dist if cam.focus_dist is not None else \
        float(np.linalg.norm(np.subtract(cam.look_at, cam.look_from, dtype=np.float64)))
    points[0] += abs(focus) * math.tan(math.radians(min(cam.defocus_angle, 179.0) / 2.0))
    center = np.array([s.center for s in scene.spheres], dtype=np.float64).reshape(-1, 3)
    radius = np.array([s.radius for s in scene.spheres], dtype=np.float64)
    reach = np.linalg.norm(center, axis=1) + radius
    return float(max(points.max(), reach.max(initial=0.0)))


def precision_of(scene: Scene) -> np.dtype:
    """The floating-point type the wavefront runs in (see ``geometry.FLOAT32_EXTENT``)."""
    choice = scene.render.precision
    if choice != "auto":
        return np.dtype(choice)
    return precision_for([s.radius for s in scene.spheres], scene_extent(scene))


def turntable(scene: Scene, frame: int, frames: int) -> Scene:
    """``scene`` with ``look_from`` turned ``frame / frames`` of a full circle
    around the axis through ``look_at`` along ``vup``."""
    cam = scene.camera
    axis = np.asarray(cam.vup, dtype=np.float64)
    axis /= np.linalg.norm(axis)
    pivot = np.asarray(cam.look_at, dtype=np.float64)
    v = np.asarray(cam.look_from, dtype=np.float64) - pivot
    angle = 2.0 * np.pi * frame / frames
    # Rodrigues' rotation formula
    rotated = (v * np.cos(angle) + np.cross(axis, v) * np.sin(angle)
               + axis * np.dot(axis, v) * (1.0 - np.cos(angle)))
    look_from = tuple(float(x) for x in pivot + rotated)
    return scene.replace(camera=dataclasses.replace(cam, look_from=look_from), name=f"{scene.name}#{frame}")

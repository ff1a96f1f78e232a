"""wavefront: a readable, tested NumPy wavefront path tracer for spheres, quads, boxes, triangles and meshes.

>>> from wavefront import load_scene, render
>>> image = render(load_scene("scenes/three_spheres.yaml"))  # (H, W, 3) linear float32
"""

__version__ = "0.1.0"  # the package's version (pyproject.toml reads it from here)

import os as _os
import sys as _sys

# One thread per process: wavefront's parallelism is its worker processes, and
# NumPy's matrix products here are small.  OpenBLAS starts a pool of threads when
# NumPy is imported, and on a 2-core machine its spinning thread took the other
# core from the import itself (0.10 s against 0.05 s, ~50 ms of CPU at every
# command's start: W2's whole command ~5 % slower) and from the workers forked
# after it.  Only if NumPy is not loaded yet, and only where the user has not
# chosen: ``OPENBLAS_NUM_THREADS`` or ``OMP_NUM_THREADS`` (which OpenBLAS reads
# when the first is unset) set beforehand is kept.
if "numpy" not in _sys.modules and not {"OPENBLAS_NUM_THREADS", "OMP_NUM_THREADS"} & _os.environ.keys():
    _os.environ["OPENBLAS_NUM_THREADS"] = "1"

from . import distributed  # so wavefront.distributed.dask_executor works after "import wavefront"
from .background import Sky, Solid
from .camera import Camera
from .geometry import Sphere
from .materials import Dielectric, Emissive, Lambertian, Metal, Phong
from .media import Medium
from .film import CheckpointError
from .output import OutputError
from .render import MemoryBudgetError, RenderResult, render, render_scene
from .scene import PointLight, RenderSettings, Scene
from .scenefile import SceneError, SceneWarning, load_scene, scene_from_dict
from .shapes import Box, Mesh, Quad, Triangle, box_quads
from .textures import Checker, ImageTexture, Noise
from .transform import Transform

__all__ = [
    "Box", "CheckpointError", "Checker", "ImageTexture", "MemoryBudgetError", "Noise", "OutputError",
    "Camera", "Dielectric", "Emissive", "Lambertian", "Medium", "Mesh", "Metal", "Phong", "PointLight", "Quad",
    "RenderResult", "RenderSettings", "Scene", "SceneError", "SceneWarning", "Sky", "Solid",
    "Sphere", "Transform", "Triangle", "box_quads", "load_scene", "render", "render_scene", "scene_from_dict",
]

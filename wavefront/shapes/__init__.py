"""Shapes: spheres, quads, triangles and meshes, and the record of what a ray hit.

One module per kind (:mod:`.sphere`, :mod:`.quad`, :mod:`.triangle`), mesh
files in :mod:`.mesh`, the kinds' shared contract in :mod:`.base`, and all of
a scene's primitives under one index in :mod:`.primitives`.
"""

from .base import Hits, Intersector, ShapeKind, SurfaceHits
from .mesh import Mesh, MeshError, mesh_triangles, read_mesh
from .primitives import Primitives
from .quad import Box, Quad, QuadSet, box_quads
from .sphere import Sphere, SphereSet
from .triangle import Triangle, TriangleSet

__all__ = ["Box", "Hits", "Intersector", "Mesh", "MeshError", "Primitives", "Quad", "QuadSet", "ShapeKind", "Sphere", "SphereSet",
           "SurfaceHits", "Triangle", "TriangleSet", "box_quads", "mesh_triangles", "read_mesh"]

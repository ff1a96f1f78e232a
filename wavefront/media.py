"""Participating media: homogeneous fog inside a closed, invisible boundary.

A :class:`Medium` is RTOW book 2's ``constant_medium`` done the way pbrt-v4
and Mitsuba do it: a homogeneous medium with a grey ``density`` (the
extinction coefficient, per unit length), an RGB single-scattering
``albedo`` and an isotropic phase function, filling the inside of a closed
``boundary`` (a sphere, a box or a closed mesh).

The boundary's primitives are never shaded.  They live in an intersector of
their own (brute force or a BVH, built by the same code as the scene's), not
among the scene's shapes: a path finds its next surface from its vertex as
it would without media, then walks the boundaries between the two.  (With
the boundaries among the shapes, a ray restarted on a boundary skips any
surface within ``T_MIN`` beyond it: fog resting on a floor let light leak
through the floor at one sample in a few thousand.)  A path carries
the set of media it is inside as a bit mask (medium ``i`` is bit ``i``);
crossing a boundary's front (outer) side sets its bit, crossing its back
side clears it.  **Overlapping media: the innermost wins.**  Precisely, where
boundaries overlap, a point belongs to the medium whose boundary encloses the
smallest volume (a tie goes to the one listed last): bits are numbered by
decreasing volume and a path is in the medium of its highest set bit.  Nested
media (a blue ball of fog inside a thin mist, RTOW's final scene) therefore
work in any order, leaving an inner medium returns a path to the one around
it, and a partial overlap consistently belongs to the smaller medium.  Hence
at most :data:`MAX_MEDIA` media.

A scene sphere, quad or mesh triangle that coincides exactly with a
boundary primitive (RTOW's final scene fills a glass ball with blue fog,
using one sphere for both) is not duplicated: the visible primitive becomes
the boundary, and a path that is *transmitted* through it (refraction) enters
or leaves the medium.  Otherwise surfaces never change the medium: a glass
ball inside fog is full of that fog.

Camera rays start in the media that contain the camera's ``look_from``
(sphere: distance; box: in its object space; mesh: generalised winding
number), decided once per scene.
"""

from __future__ import annotations

import math
from collections.abc import Mapping
from dataclasses import dataclass

import numpy as np

from .geometry import Sphere
from .shapes import Box, Mesh, mesh_triangles
from .shapes.sphere import world_sphere
from .textures import Checker, ImageTexture, Texture, TextureTable, is_texture, texture_field
from .validation import SceneError, color, describe, fail, join, number

RGB = tuple[float, float, float]

IMAGE_IN_VOLUME = ("an image texture needs a surface's uv, which a point in a medium has not "
                   "(use a colour, a checker or noise)")
# A path's media are the bits of one uint64.
MAX_MEDIA = 64
# Solid angle density of the isotropic phase function: 1 / (4 pi) per steradian.
ISOTROPIC_PDF = 1.0 / (4.0 * math.pi)


@dataclass(frozen=True, eq=False)
class Medium:
    """A homogeneous, isotropically scattering medium inside a closed boundary.

    ============  =========  ====================================================
    parameter     default    meaning
    ============  =========  ====================================================
    ``boundary``  required   a :class:`~wavefront.geometry.Sphere`,
                             :class:`~wavefront.shapes.Box` or closed
                             :class:`~wavefront.shapes.Mesh` (its ``material``
                             is ignored); invisible
    ``density``   required   extinction per unit length, >= 0 (grey): a ray
                             travels ``-ln(1 - u) / density`` before it scatters
    ``albedo``    (1, 1, 1)  single-scattering albedo, each channel in [0, 1]:
                             the fraction of extinction that is scattering;
                             an RGB triple or a solid texture (checker or
                             noise, read at the scattering point; an image
                             needs a surface's uv, which a volume has not)
    ============  =========  ====================================================

    Compared by identity (a mesh boundary holds arrays).
    """

    boundary: Sphere | Box | Mesh
    density: float
    albedo: RGB | Texture = (1.0, 1.0, 1.0)

    def __post_init__(self):
        set_field = object.__setattr__
        if not isinstance(self.boundary, (Sphere, Box, Mesh)):
            fail(self, "boundary", f"expected a sphere, box or mesh, got {describe(self.boundary)}")
        if isinstance(self.boundary, Sphere) and self.boundary.center1 is not None:  # it would be held still
            fail(self, "boundary.center1", "a medium's boundary cannot move (media are not motion-blurred)")
        set_field(self, "density", number(self, self.density, "density", low=0.0))
        if isinstance(self.albedo, Mapping) and self.albedo.get("type") == "image":  # refused before it is read
            fail(self, "albedo", IMAGE_IN_VOLUME)
        set_field(self, "albedo", volume_albedo(self, texture_field(self, self.albedo, "albedo"), "albedo"))
        if isinstance(self.boundary, Mesh):
            set_field(self, "boundary", closed_outward(self, self.boundary))
        if isinstance(self.boundary, Box):  # its faces are built when the scene is compiled: check them now
            box_faces(self, self.boundary, "boundary")


def box_faces(obj, box: Box, path: str) -> list:
    """``box.quads()``, or a SceneError of ``obj`` at ``path`` saying why the
    box's faces cannot be intersected (a box without a transform checks only
    its corners when built, and a face of edges beyond ~1e77 has an area
    float64 cannot hold)."""
    try:
        return box.quads()
    except SceneError as e:
        if e.path.startswith(("u", "v")):  # an edge, max - min, past the coordinate limit
            problem = f"box too large: an edge (max - min) {e.problem}"
        elif e.problem.startswith("quad too "):
            problem = ("box" + e.problem.removeprefix("quad")).replace("its area", "a face's area").replace(
                "keep edges", "keep its edges, max - min,")
        else:
            problem = f"a face of the box: {join(e.path, '') + ': ' if e.path else ''}{e.problem}"
        fail(obj, path, problem)


def closed_outward(obj, mesh: Mesh) -> Mesh:
    """``mesh`` if it encloses a volume with its faces wound outwards; wound
    inwards it is returned turned outwards (entering must cross front faces);
    open or inconsistently wound, a SceneError naming the file."""
    import trimesh  # the standard mesh library; only scenes with mesh boundaries need it

    # merging coincident vertices (process=True) so that a file storing each
    # face's own corners (STL) is judged by its shape, not its indexing
    shape = trimesh.Trimesh(vertices=mesh.vertices, faces=mesh.faces, process=True)
    where = f"{mesh.file}: " if mesh.file else ""
    if not shape.is_watertight:
        fail(obj, "boundary.mesh.file", f"{where}is not closed (trimesh is_watertight is false): a medium "
                                        "boundary must enclose a volume")
    if not shape.is_winding_consistent:
        fail(obj, "boundary.mesh.file", f"{where}its faces are not wound consistently, so it has no inside")
    # wound inwards in the file (a mirroring transform keeps the sides: mesh_triangles turns its faces back)
    if shape.volume < 0:
        return Mesh(vertices=mesh.vertices, faces=np.ascontiguousarray(mesh.faces[:, ::-1]), material=mesh.material,
                    smooth=mesh.smooth, transform=mesh.transform, vertex_normals=mesh.vertex_normals, uv=mesh.uv,
                    file=mesh.file, dropped=mesh.dropped)
    return mesh


def volume_albedo(obj, value, path: str):
    """``value`` (a colour or texture) if it can be a medium's albedo: every
    constant colour in it within [0, 1] (more would create energy), and no
    image texture (an image is read at a surface's ``uv``; a point in a
    volume has none)."""
    if isinstance(value, ImageTexture):
        fail(obj, path, IMAGE_IN_VOLUME)
    if isinstance(value, Checker):
        volume_albedo(obj, value.even, join(path, "even"))
        volume_albedo(obj, value.odd, join(path, "odd"))
    elif not is_texture(value):
        color(obj, value, path, high=1.0)  # Perlin marble lies in [0, 1] by construction
    return value


def medium_albedo(media, medium_idx: np.ndarray, point: np.ndarray) -> np.ndarray:
    """Single-scattering albedo ``(3, N)`` of media ``medium_idx (N,)`` (bit
    numbers) at ``point (3, N)``: the one place a medium's colour is looked up.
    Solid textures are evaluated at the scattering point."""
    if media.textures is None:
        return np.take(media.albedo, medium_idx, axis=1)
    return media.textures.evaluate(media.albedo_node.take(medium_idx), point, None)


# -- the path's media as a bit mask --------------------------------------------

_LOW32 = np.uint64(0xFFFFFFFF)
_S32 = np.uint64(32)


def current_medium(mask: np.ndarray) -> np.ndarray:
    """The medium each path is in: the highest set bit of ``mask (N,)`` uint64
    (the last listed medium wins an overlap); -1 where it is in none.

    ``frexp`` of each 32-bit half, exact in float64, gives its highest bit
    without a loop over bits."""
    high = (mask >> _S32).astype(np.float64)
    low = (mask & _LOW32).astype(np.float64)
    top = np.frexp(high)[1] + 31
    bottom = np.frexp(low)[1] - 1  # frexp(0) has exponent 0: -1, no medium
    return np.where(high > 0, top, bottom).astype(np.int64)


def cross(mask: np.ndarray, medium_idx: np.ndarray, entering: np.ndarray) -> np.ndarray:
    """``mask`` after crossing the boundaries of ``medium_idx``: entering sets
    the medium's bit, leaving clears it (both idempotent, so a boundary hit
    twice by rounding cannot unbalance the mask)."""
    bit = np.left_shift(np.uint64(1), medium_idx.astype(np.uint64))
    return np.where(entering, mask | bit, mask & ~bit)


def transmittance(density: np.ndarray, length: np.ndarray) -> np.ndarray:
    """Beer-Lambert: the fraction of light a homogeneous grey medium lets through ``length``."""
    return np.exp(-density * length)


# -- geometry of the boundaries --------------------------------------------------

def boundary_primitives(medium: Medium):
    """The boundary as primitives: ``("sphere", (center (3,), radius))``,
    ``("quads", [Quad, ...])`` (a box's six outward faces) or
    ``("triangles", dict of v0, v1, v2 (3, F))`` in world space."""
    b = medium.boundary
    if isinstance(b, Sphere):
        return "sphere", world_sphere(b)
    if isinstance(b, Box):
        return "quads", b.quads()  # outward in world space, under a mirror too
    return "triangles", mesh_triangles(b)


def boundary_volume(medium: Medium) -> float:
    """The volume the boundary encloses, in world space (what orders media
    for the innermost-wins rule)."""
    b = medium.boundary
    if isinstance(b, Sphere):
        return 4.0 / 3.0 * math.pi * world_sphere(b)[1] ** 3
    if isinstance(b, Box):
        scale = 1.0 if b.transform is None else abs(float(np.linalg.det(b.transform.array[:3, :3])))
        return float(np.prod(np.subtract(b.max, b.min))) * scale
    t = mesh_triangles(b)  # divergence theorem: signed tetrahedra from the origin
    return abs(float(np.einsum("ij,ij->", t["v0"], np.cross(t["v1"], t["v2"], axis=0)))) / 6.0


def boundary_log_volume(medium: Medium) -> float:
    """The natural logarithm of :func:`boundary_volume`, computed without
    overflow (a sphere of radius 1e120 encloses more than float64 holds)."""
    b = medium.boundary
    if isinstance(b, Sphere):
        return math.log(4.0 / 3.0 * math.pi) + 3.0 * math.log(world_sphere(b)[1])
    if isinstance(b, Box):
        log_scale = 0.0 if b.transform is None else float(np.linalg.slogdet(b.transform.array[:3, :3])[1])
        return float(np.sum(np.log(np.subtract(b.max, b.min)))) + log_scale
    t = mesh_triangles(b)
    # scaled by a power of two (exact) so that the triple products stay finite
    scale = math.ldexp(1.0, math.frexp(max(float(np.abs(t[k]).max()) for k in ("v0", "v1", "v2")) or 1.0)[1])
    v0, v1, v2 = (t[k] / scale for k in ("v0", "v1", "v2"))
    volume = abs(float(np.einsum("ij,ij->", v0, np.cross(v1, v2, axis=0)))) / 6.0
    return (math.log(volume) if volume > 0 else -math.inf) + 3.0 * math.log(scale)


def volume_order(media) -> np.ndarray:
    """(K,) keys ordering ``media`` by the volume each encloses: the volumes,
    or, when one of them overflows float64, every one's logarithm (the same
    order; the volumes themselves where they fit, so that near-ties order as
    they always did)."""
    try:
        with np.errstate(over="raise", invalid="raise"):
            volume = np.array([boundary_volume(m) for m in media], dtype=np.float64)
        if np.isfinite(volume).all():
            return volume
    except (OverflowError, FloatingPointError):
        pass
    return np.array([boundary_log_volume(m) for m in media], dtype=np.float64)


def contains(medium: Medium, point) -> bool:
    """Whether ``point (3,)`` lies inside the medium's boundary."""
    p = np.asarray(point, dtype=np.float64)
    b = medium.boundary
    if isinstance(b, Sphere):
        center, radius = world_sphere(b)
        return bool(np.linalg.norm(p - center) < radius)
    if isinstance(b, Box):
        if b.transform is not None:  # into the box's object space
            p = np.linalg.solve(b.transform.array, np.append(p, 1.0))[:3]
        return bool(np.all(np.asarray(b.min) < p) and np.all(p < np.asarray(b.max)))
    return bool(winding_number(mesh_triangles(b), p) > 0.5)


# Triangles per pass of the winding number: bounds its temporaries (~10
# arrays of 3 x this many float64) for boundaries of millions of faces.
WINDING_BLOCK = 1 << 18


def winding_number(triangles: dict, point: np.ndarray) -> float:
    """Generalised winding number of a closed, outward-wound triangle mesh at
    ``point``: 1 inside, 0 outside (Jacobson et al. 2013), from each triangle's
    signed solid angle by Van Oosterom & Strackee's formula, in blocks of
    faces."""
    p = np.asarray(point, dtype=np.float64)[:, None]
    total = 0.0
    for first in range(0, triangles["v0"].shape[1], WINDING_BLOCK):
        a, b, c = (triangles[k][:, first:first + WINDING_BLOCK] - p for k in ("v0", "v1", "v2"))
        la, lb, lc = (np.sqrt(np.einsum("ij,ij->j", x, x)) for x in (a, b, c))
        triple = np.einsum("ij,ij->j", a, np.cross(b, c, axis=0))
        dot = lambda x, y: np.einsum("ij,ij->j", x, y)  # noqa: E731
        denominator = la * lb * lc + dot(a, b) * lc + dot(a, c) * lb + dot(b, c) * la
        total += float(np.sum(2.0 * np.arctan2(triple, denominator)))
    return total / (4.0 * math.pi)


@dataclass(slots=True)
class MediumTable:
    """A scene's media as arrays, built once when the scene is compiled.

    Media are numbered here by their bit in a path's mask (largest volume
    first, see the module docstring), not as listed: ``density``, ``albedo``,
    the boundaries' ``material_idx``, ``interface_of`` and ``camera_mask`` all
    use that number; ``medium_of_bit`` maps it back to the scene's list.

    ``boundaries`` intersects the invisible boundary primitives (their own
    brute force or BVH, apart from the scene's shapes; a hit's
    ``material_idx`` is its medium), None when every boundary is a visible
    primitive too.  ``interface_of`` maps each of the scene's primitives to
    the medium it also bounds (-1: none; see the module docstring).
    """

    density: np.ndarray  # (K,) float64
    albedo: np.ndarray  # (3, K) float64
    medium_of_bit: np.ndarray  # (K,) int64: the scene's index of each bit's medium
    boundaries: object | None  # an Intersector over the boundary primitives
    interface_of: np.ndarray  # (M,) int32, per scene primitive
    camera_mask: np.uint64  # the media containing the camera
    # a box around every boundary primitive, padded: lo, hi (3, 1) float64
    bounds: tuple[np.ndarray, np.ndarray] = (np.full((3, 1), -np.inf), np.full((3, 1), np.inf))
    # Textured albedos: each bit's node of ``textures`` (None when every
    # albedo is a plain colour; ``albedo`` then holds them, else the means).
    textures: TextureTable | None = None
    albedo_node: np.ndarray | None = None  # (K,) int64
    # Media sealed inside one visible sphere (RTOW's fog in a glass ball):
    # per bit, the sphere's centre (3, K) float64, its radius less a margin
    # (K,) and the margin (K,), NaN for other media; None when there are none.
    # A shadow ray that certainly leaves such a sphere is certainly blocked
    # by it (see path.sealed_in): it need not be traced.
    sealed: tuple[np.ndarray, np.ndarray, np.ndarray] | None = None

    def __len__(self) -> int:
        return self.density.shape[0]

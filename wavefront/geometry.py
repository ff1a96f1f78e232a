"""What every shape shares: the ray's ``T_MIN``, the precision rule, and the
exact ray-sphere arithmetic.

The shapes themselves (spheres, quads, triangles, meshes) and their
structure-of-arrays sets live in :mod:`wavefront.shapes`; ``wavefront.accel``
builds one BVH over all of them with exactly the answers of brute force.
"""

from __future__ import annotations

import itertools
import math
import numbers
import unicodedata
from dataclasses import dataclass

import numpy as np

from .transform import Transform, transform_field
from .validation import SceneError, fail, integer, number, vec3
from .validation import name as material_name

T_MIN = 1e-3  # skip self-intersection at the ray's own origin (shadow acne)

# float32 is accurate enough when every point a ray can start from or reach
# (sphere extents, the camera, lights) lies within FLOAT32_EXTENT of the
# origin and no sphere is smaller than FLOAT32_MIN_RADIUS of that extent.
# Positions then round by at most ~3e-5, far below T_MIN, so surfaces stay
# free of acne (a ground of radius 1000 does not fit); and with
# :func:`sphere_roots`' error of ``eps |oc| / r`` of a radius, silhouettes
# move by at most ~1e-4 of the smallest sphere's radius.
FLOAT32_EXTENT = 256.0
FLOAT32_MIN_RADIUS = 1e-3
# Huge spheres (walls of radius 1000 around a small room, as in
# cornell_spheres) put the extent far past FLOAT32_EXTENT, yet float32 is
# still accurate enough when the camera, the lights and every sphere of
# radius up to FLOAT32_EXTENT pass the rule above on their own, and the huge
# spheres are tested with :func:`anchored_roots`, whose error does not grow
# with the radius:
#
# * the root a ray starting on a surface would find again (the self-hit) is
#   ``power / big_root``, with the power of the origin ``|o - c|^2 - r^2``
#   taken as ``(o - q).(o - q')`` from two antipodal points of the sphere,
#   ``q`` the one nearest the world origin: its error is a few float32
#   epsilons u of ``|o - q| |o - q'|`` (plus ``q``'s own rounding, u |q|),
#   and ``big_root`` is about ``2 r cos``, so the self-hit comes out at
#   ``~u |o - q| / cos``: within 1e-6 / cos of 0 for rays starting near the
#   room, where Haines' form errs by u |o - c| ~ 6e-5 (measured: one wall
#   bounce in 700 found its own wall again just past T_MIN);
# * rays can still start far out on a huge sphere (cornell_spheres' open
#   front: 8 vertices in 1.4 million beyond 1000 units), where positions
#   round by u |o|: there a ray skips roots below
#   ``RELATIVE_T_MIN * max|o_i|`` rather than T_MIN (as Mitsuba's
#   ``RayEpsilon * (1 + |p|)``), the same ratio of rounding to epsilon as at
#   FLOAT32_EXTENT under the rule above; rays within FLOAT32_EXTENT keep T_MIN;
# * a small sphere seen from far out keeps Haines' discriminant: its
#   silhouette moves by ~u in angle, far below any pixel.
#
# The reach ``|c| + r`` of every sphere stays within FLOAT32_MAX_REACH.  The
# anchored near root is exact to ~u |o - q|, but the discriminant is still
# Haines', whose error grows with the radius: a ray grazing a huge ground
# near its horizon lands off the surface by ~1e-8 r (measured: 2e-5 at
# r = 1000, 1e-4 at 4000, 4e-4 at 1e4, 5e-3 at 1e5), and past ~1e-4 rays
# leaving the hit point at glancing angles find the ground again just past
# T_MIN (none of cos >= 0.05 at r <= 2000; 2 % at 4000; 28 % at 1e4).  So
# only walls up to ~2000 units (a reach of 4096) run anchored; grounds of
# radius 1e5 and beyond, as some scenes use for a flat floor, keep float64.
RELATIVE_T_MIN = T_MIN / FLOAT32_EXTENT
FLOAT32_MAX_REACH = 4096.0

# Elements of one (spheres x rays) temporary; bounds the memory of brute force
# and keeps blocks in cache.
BLOCK_ELEMENTS = 1 << 18


def precision_for(radius: np.ndarray, extent: float) -> np.dtype:
    """float32 where it is accurate enough for these radii within ``extent``
    of the origin (see ``FLOAT32_EXTENT``), else float64."""
    radius = np.asarray(radius, dtype=np.float64)
    small = radius.min() if radius.size else np.inf
    fits = extent <= FLOAT32_EXTENT and small >= FLOAT32_MIN_RADIUS * extent
    return np.dtype(np.float32 if fits else np.float64)


# Ray-sphere intersection squares radii and distances and divides by the
# radius in float64: keeping radii and coordinates within 1e-150..1e150 keeps
# every square, sum of three squares and reciprocal finite and normal
# (float64 squares overflow past ~1.3e154 and underflow below ~1.5e-154).
MIN_RADIUS = 1e-150
MAX_COORDINATE = 1e150


@dataclass(frozen=True, slots=True)
class Sphere:
    """A sphere with a material name (or index once a scene is compiled).

    ============  ======================================================
    parameter     meaning
    ============  ======================================================
    ``center``    three finite numbers, each within +-1e150
    ``radius``    a number in [1e-150, 1e150]
    ``material``  the name of a material of the scene (Unicode NFC), or
                  its index in the scene's materials
    ``transform`` ``None``, a :class:`~wavefront.transform.Transform` or a
                  scene file's list of steps: translate, rotate and
                  uniform scale only (anything else would not be a
                  sphere); applied when the scene is compiled (to both
                  centres of a moving sphere)
    ``center1``   ``None`` (still), or the centre at time 1: the sphere
                  moves linearly from ``center`` at time 0, and every
                  camera sample sees it at its own time in [0, 1)
                  (RTOW book 2's motion blur)
    ============  ======================================================

    Invalid values raise :class:`~wavefront.validation.SceneError` naming the field.
    """

    center: tuple[float, float, float]
    radius: float
    material: str | int
    transform: Transform | None = None
    center1: tuple[float, float, float] | None = None

    def __post_init__(self):
        set_field = object.__setattr__
        set_field(self, "center", position(self, self.center, "center"))
        if self.center1 is not None:
            set_field(self, "center1", position(self, self.center1, "center1"))
        set_field(self, "radius", radius(self, self.radius, "radius"))
        set_field(self, "material", material_field(self, self.material))
        set_field(self, "transform", transform_field(self, self.transform, "transform", similarity_only=True))
        if self.transform is not None:  # where the ray tests will see it
            scale = self.transform.uniform_scale()
            centers = [self.center] + ([self.center1] if self.center1 is not None else [])
            center = self.transform.points(np.asarray(centers, dtype=np.float64).T)
            world_radius = self.radius * scale
            with np.errstate(invalid="ignore"):
                in_range = np.abs(center).max() <= MAX_COORDINATE
            if not (in_range and MIN_RADIUS <= world_radius <= MAX_COORDINATE):
                # name the centre that is out of range: center1's when only it is
                moved = np.abs(center[:, 0]).max() <= MAX_COORDINATE < np.abs(center).max()
                which, center = ("centre at time 1 (center1)", center[:, -1]) if moved else ("centre", center[:, 0])
                fail(self, "transform", f"in world space the sphere's {which} {center.tolist()} or radius "
                                        f"{world_radius:g} "
                                        f"is out of range (coordinates within {MAX_COORDINATE:g}, radius at least "
                                        f"{MIN_RADIUS:g})")

    @classmethod
    def many(cls, centers, radii, materials) -> list[Sphere]:
        """Spheres from parallel sequences, as ``[Sphere(c, r, m) for ...]`` but
        checked in bulk with NumPy (a million in well under a second).

        The bulk check only recognises the common case where every value is
        plainly fine (numbers of type int or float, in range, string names);
        anything else goes through the constructor one sphere at a time, so
        what is refused, and the message, are the constructor's.  An error's
        path is prefixed with the sphere's index: ``[3].radius``.
        """
        fast = _many_unchecked(centers, radii, materials)
        if fast is not None:
            return fast
        spheres = []
        for i, (c, r, m) in enumerate(zip(centers, radii, materials, strict=True)):
            try:
                spheres.append(cls(c, r, m))
            except SceneError as e:
                raise e.within(e.source, f"[{i}]") from None
        return spheres


def radius(obj, value, path: str) -> float:
    """A sphere's radius: > 0, and within the range where float64 can square it
    and take its reciprocal (see ``MIN_RADIUS``)."""
    r = number(obj, value, path, low=0.0, low_open=True)
    if r < MIN_RADIUS:
        fail(obj, path, f"{value!r} is too small to intersect in float64 (its square "
                        f"{'underflows to 0' if r * r == 0.0 else 'loses precision'}"
                        f"{' and its reciprocal overflows' if not math.isfinite(1.0 / r) else ''}); "
                        f"the smallest radius is {MIN_RADIUS:g}")
    if r > MAX_COORDINATE:
        fail(obj, path, f"{value!r} is too large to intersect in float64 (its square "
                        f"{'overflows' if not math.isfinite(r * r) else 'leaves no room for distances'}); "
                        f"the largest radius is {MAX_COORDINATE:g}")
    return r


def check_world_flat(obj, rows: np.ndarray, kind: str) -> None:
    """A flat shape after its transform: within range and not flattened.

    ``rows (3, 3)`` are a world-space point and the two edges spanning the
    shape; the ray tests square them, so they must stay within
    ``MAX_COORDINATE``."""
    with np.errstate(over="ignore", invalid="ignore"):
        area = float(np.linalg.norm(np.cross(rows[1], rows[2])))
    if not np.abs(rows).max() <= MAX_COORDINATE or not math.isfinite(area):  # also false for NaN
        fail(obj, "transform", f"in world space the {kind} reaches beyond {MAX_COORDINATE:g} "
                               "(its transform overflows)")
    if area <= 0.0:
        fail(obj, "transform", f"in world space the {kind} has zero area (its transform flattens it)")


def material_field(obj, value, path: str = "material") -> str | int:
    """A shape's material: a name (Unicode NFC) or an index into the scene's materials."""
    if isinstance(value, numbers.Integral) and not isinstance(value, bool):
        return integer(obj, value, path, low=0)
    return material_name(obj, value, path)


def position(obj, value, path: str) -> tuple[float, float, float]:
    """A point in the scene: three finite numbers within +-MAX_COORDINATE."""
    return vec3(obj, value, path, low=-MAX_COORDINATE, high=MAX_COORDINATE)


def _chunked_tolist(array: np.ndarray, rows: int = 1 << 16):
    """``array.tolist()`` row by row without holding every row's list at once."""
    for start in range(0, len(array), rows):
        yield from array[start:start + rows].tolist()


def _many_unchecked(centers, radii, materials) -> list[Sphere] | None:
    """The spheres if every value is plainly valid, else None (see ``Sphere.many``)."""
    n = len(radii)
    if len(centers) != n or len(materials) != n:
        return None
    # type() of every value at C speed: only int and float (never bool), only str names
    if not set(map(type, radii)) <= {int, float} or set(map(type, materials)) - {str}:
        return None
    if set(map(type, centers)) - {list, tuple} or set(map(len, centers)) - {3}:
        return None
    if not set(map(type, itertools.chain.from_iterable(centers))) <= {int, float}:
        return None
    try:
        center = np.array(centers, dtype=np.float64).reshape(n, 3)
        radius = np.array(radii, dtype=np.float64).reshape(n)
    except (OverflowError, ValueError):
        return None
    with np.errstate(invalid="ignore"):
        ok = (np.all(np.abs(center) <= MAX_COORDINATE) and np.all(radius >= MIN_RADIUS)
              and np.all(radius <= MAX_COORDINATE))
    if not ok:
        return None
    normal = {m: unicodedata.normalize("NFC", m) for m in set(materials)}
    # the values are Python floats already when the file wrote every number with
    # a point or exponent: reuse them rather than make a million new ones
    if set(map(type, itertools.chain.from_iterable(centers))) == {float}:
        center_tuples = map(tuple, centers)
    else:
        center_tuples = (tuple(c) for c in _chunked_tolist(center))
    radius_values = radii if set(map(type, radii)) == {float} else _chunked_tolist(radius)
    del center, radius
    new, set_field = object.__new__, object.__setattr__
    spheres = []
    append = spheres.append
    for c, r, m in zip(center_tuples, radius_values, materials):
        s = new(Sphere)
        set_field(s, "center", c)
        set_field(s, "radius", r)
        set_field(s, "material", normal[m])
        set_field(s, "transform", None)
        set_field(s, "center1", None)
        append(s)
    return spheres


def sphere_roots(center, radius_squared, origin, direction):
    """Both ray parameters where unit-direction rays meet spheres (broadcasting).

    With ``oc = c - o`` and ``|d| = 1`` the roots are ``h -/+ sqrt(r^2 - |l|^2)``
    where ``h = d.oc`` and ``l = oc - h d`` is the offset of the sphere's
    centre from the ray's line (Haines et al., "Precision Improvements for
    Ray/Sphere Intersection", Ray Tracing Gems, 2019).  The textbook
    discriminant ``h^2 - (|oc|^2 - r^2)`` subtracts two numbers of size
    ``|oc|^2`` to get one of size ``r^2``, so a small sphere far from the ray's
    origin loses ``(|oc| / r)^2`` of its digits: in float32 a ball of radius
    0.01 a hundred units away vanished.  Here the error is ``eps |oc| / r`` of
    the radius.  Both the brute-force and the BVH intersectors call this with
    the same operands, so they agree bit for bit.

    Returns ``(h, sqrt_disc)``: the roots are ``h - sqrt_disc`` and
    ``h + sqrt_disc``.  A miss (negative discriminant) yields a NaN
    ``sqrt_disc`` rather than a separate mask: every comparison with NaN is
    false, so :func:`nearest_root` turns it into ``inf`` with no extra pass.
    """
    h, sqrt_disc, _ = _sphere_roots(center, radius_squared, origin, direction)
    return h, sqrt_disc


def _sphere_roots(center, radius_squared, origin, direction):
    """:func:`sphere_roots`, and a spent temporary of ``h``'s shape (or None)
    that :func:`sphere_root_keys` writes a root into.

    A coordinate that every sphere of a block shares may come as one row
    (``(1, 1)`` where the others are ``(M, 1)``; see
    :meth:`~wavefront.shapes.SphereSet.key_block`), the x and y not both:
    its difference and its term of ``h`` are then rows of the rays, two
    passes over the block fewer, and the numbers are those of full blocks
    (each sum is written into its full operand: addition commutes exactly).
    """
    ox = center[0] - origin[0]
    oy = center[1] - origin[1]
    oz = center[2] - origin[2]
    # in place through one scratch block: the same operations in the same
    # order as with a temporary each, in five (spheres, rays) blocks instead of
    # nine, which a float64 block of 4 x 8192 (W2's outsized spheres) keeps in L2
    h = np.multiply(direction[0], ox)
    scratch = np.multiply(direction[1], oy)
    if h.shape[0] < scratch.shape[0]:  # a shared x: its row's term is added to y's
        h, scratch = scratch, h
    h += scratch
    if scratch.shape[0] < h.shape[0]:  # the shared coordinate's row: a block to work in
        scratch = np.empty_like(h)
    h += np.multiply(direction[2], oz, out=scratch if oz.shape == h.shape else None)
    # each component of l = oc - h d, squared and taken off r^2 in turn
    lx = _offset_squared(ox, h, direction[0], scratch)
    disc = np.subtract(radius_squared, lx, out=lx if lx is ox else None)  # (else scratch, needed again)
    disc -= _offset_squared(oy, h, direction[1], scratch)
    disc -= _offset_squared(oz, h, direction[2], scratch)
    with np.errstate(invalid="ignore"):
        sqrt_disc = np.sqrt(disc, out=disc)
    # (rays of mixed types, as some tests pass, leave one of another type or shape)
    spare = oy if oy.shape == h.shape == sqrt_disc.shape and oy.dtype == h.dtype == sqrt_disc.dtype else None
    return h, sqrt_disc, spare


def _offset_squared(oc, h, direction, scratch):
    """``(oc - h d)^2``, one component of the centre's offset from the ray's
    line squared: in ``oc``'s block, or in ``scratch`` where ``oc`` is a row."""
    np.multiply(h, direction, out=scratch)
    offset = np.subtract(oc, scratch, out=oc if oc.shape == scratch.shape else scratch)
    offset *= offset
    return offset


def sphere_root_keys(center, radius_squared, origin, direction, out=None):
    """``nearest_root_key(*sphere_roots(...))``, the same keys, with the two
    roots written into :func:`sphere_roots`' spent temporaries (``h``'s and
    one of its own) rather than into two new arrays: a new array's first
    writes miss the cache.  (W2's outsized spheres, its recorded calls:
    ~3 % faster than the two calls; see ``KEY_BLOCK_BYTES`` in
    :mod:`wavefront.shapes.sphere` for the larger gain of its ray chunks.)
    ``out``: an array of keys to write the result into (else a new one)."""
    h, sqrt_disc, spare = _sphere_roots(center, radius_squared, origin, direction)
    bits, first, _ = _ROOT_KEYS[h.dtype]
    near = np.subtract(h, sqrt_disc, out=spare).view(bits)
    near -= first
    far = np.add(h, sqrt_disc, out=h).view(bits)
    far -= first
    return np.minimum(near, far, out=near if out is None else out)


# each float type's unsigned twin and its sign bit (anchored_roots' copysign)
_SIGN_BIT = {np.float32: (np.uint32, np.uint32(1 << 31)), np.float64: (np.uint64, np.uint64(1 << 63))}


def anchored_roots(center, radius_squared, near_point, far_point, origin, direction, zeros=((), ())):
    """Both roots of unit-direction rays against spheres, for float32 huge
    spheres (see ``FLOAT32_MAX_REACH`` above for the error argument), and
    each ray's ``t_min``.

    ``near_point`` and ``far_point`` are antipodal points of each sphere
    (``near_point`` nearest the world origin).  The discriminant is Haines'
    (:func:`sphere_roots`); the root of larger magnitude is
    ``h + sign(h) sqrt_disc`` (no cancellation) and the other comes from
    the product of the roots, the power of the origin, computed by Thales:
    ``|o - c|^2 - r^2 = (o - near_point).(o - far_point)``, capped at
    ``|big_root|`` (which the true small root never exceeds).  Returns
    ``(small_root, big_root, t_min)``, the roots in either order; a miss
    gives NaN roots.  ``t_min`` is ``max(T_MIN, RELATIVE_T_MIN max_i |o_i|)``.
    ``zeros``: the axes on which every ``near_point``, and those on which
    every ``far_point``, is +0.0 (see ``SphereSet._anchor_zeros``).
    """
    # rays of another type (Whitted's float64 light directions in a float32
    # scene) in the anchors' own: the sign bit below is moved between arrays
    # by viewing their bits, which needs one type (no copy where they have it)
    origin = origin.astype(near_point.dtype, copy=False)
    direction = direction.astype(near_point.dtype, copy=False)
    h, sqrt_disc = sphere_roots(center, radius_squared, origin, direction)
    # (o - near) (o - far) summed over the axes, in place (products commute
    # exactly: the same numbers as with a temporary per factor).  Where a
    # point's coordinate is +0.0 (the cover's ground touches the origin from
    # below: near (0, 0, 0), far (0, -2000, 0)) the factor is o itself, bit
    # for bit (x - +0.0 is x for every x, -0.0 and NaN too): five of the
    # power's eleven passes fewer; the ground's anchored roots 139 -> 121 us
    # on the cover's recorded 16,384-ray calls (each call's least of 21).
    near_zero, far_zero = zeros
    factors = [(origin[i] if i in near_zero else origin[i] - near_point[i],
                origin[i] if i in far_zero else origin[i] - far_point[i]) for i in range(3)]
    power = np.multiply(*factors[0], out=np.empty(np.broadcast_shapes(origin[0].shape, near_point[0].shape,
                                                                       far_point[0].shape), dtype=near_point.dtype))
    for i in (1, 2):
        # (in place in the near factor's difference, never in the rays themselves)
        power += np.multiply(*factors[i], out=None if i in near_zero else factors[i][0])
    # copysign(sqrt_disc, h) by bits, h's sign onto sqrt_disc (>= 0, or a
    # miss's NaN, which stays NaN): two integer passes took 7.7 us of an
    # 8 x 4096 float32 block where np.copysign, a scalar loop, took 16
    bits, sign_bit = _SIGN_BIT[h.dtype.type]
    big = np.bitwise_and(h.view(bits), sign_bit)
    big |= sqrt_disc.view(bits)
    big = big.view(h.dtype)
    big += h
    with np.errstate(divide="ignore", invalid="ignore"):
        power /= big  # now the small root
    # The small root never exceeds |big| = |h| + sqrt_disc in magnitude: capped
    # there.  A ray leaving a surface within ~1e-9 of tangent has both roots
    # ~0: its big root is ~1e-10 and its power rounding noise (~u |o - q|
    # |o - q'|), and the quotient landed anywhere (measured: self-hits up to
    # 273 units from a ball of radius 0.2, 2.5 % of such rays); capped, it
    # stays below T_MIN with big.  Only impossible roots change (where big >
    # t_min it was already the nearest root), and below -|big| a root is no
    # hit either way.  Two passes, in sqrt_disc's spent block: ~1.3 % of this
    # function, 2-4 % of brute force over cornell_spheres' or the cover's
    # anchored spheres (their recorded calls), none seen in whole renders.
    cap = np.abs(big, out=sqrt_disc)  # (one type and shape: the rays were cast to the anchors' type above)
    np.minimum(power, cap, out=power)
    # every ray within FLOAT32_EXTENT: one pass over the three coordinates
    # (where the largest of each ray's took five and a pass more)
    if origin.size == 0 or np.abs(origin).max() <= FLOAT32_EXTENT:  # max(initial=0) goes through a Python wrapper
        return power, big, T_MIN  # the same comparisons as with T_MIN per ray, with no broadcast
    reach = np.maximum(np.maximum(np.abs(origin[0]), np.abs(origin[1])), np.abs(origin[2]))
    return power, big, np.maximum(reach * RELATIVE_T_MIN, T_MIN)


def first_root(a, b, t_min):
    """The smaller of roots ``a`` and ``b`` (either order) past ``t_min``;
    ``inf`` or NaN where neither is (as :func:`nearest_root`, whose arithmetic
    it shares).  Overwrites ``a`` and ``b`` (no temporaries)."""
    a_valid, b_valid = a > t_min, b > t_min
    with np.errstate(divide="ignore", invalid="ignore"):
        np.abs(a, out=a)
        a /= a_valid
        np.abs(b, out=b)
        b /= b_valid
    return np.fmin(a, b, out=a)


def nearest_root(h, sqrt_disc):
    """The first root ``h -/+ sqrt_disc`` past ``T_MIN``; ``inf`` or NaN where there is none.

    Written without ``np.where``, which measured 2-4 ns per element here
    against ~0.1-0.2 ns for arithmetic: dividing a root's absolute value by
    the mask ``root > T_MIN`` keeps a valid root bit for bit (it is positive,
    divided by 1) and sends the others to ``inf`` (or NaN for 0/0 and for a
    miss's NaN); ``fmin``, which ignores NaN, then picks the near root when it
    is valid, since the far one is never nearer.  A NaN result compares false
    with everything, so callers treat it as a miss and reduce with ``fmin``.
    """
    near = h - sqrt_disc
    far = h + sqrt_disc
    near_valid, far_valid = near > T_MIN, far > T_MIN
    with np.errstate(divide="ignore", invalid="ignore"):
        np.abs(near, out=near)
        near /= near_valid
        np.abs(far, out=far)
        far /= far_valid
    return np.fmin(near, far, out=near)


# Roots as unsigned integer keys (see :func:`nearest_root_key`): each float
# type's unsigned twin, the bits of the smallest root past T_MIN (the
# comparison ``root > T_MIN`` is made in the root's own type) and the key of
# ``+inf``, above which every key is a miss.
def _root_key_constants(float_type, bits_type):
    first = np.array([T_MIN], dtype=float_type).view(bits_type)[0] + bits_type(1)
    return bits_type, first, np.array([np.inf], dtype=float_type).view(bits_type)[0] - first


_ROOT_KEYS = {np.dtype(f): _root_key_constants(f, b) for f, b in ((np.float32, np.uint32), (np.float64, np.uint64))}


def nearest_root_key(h, sqrt_disc):
    """:func:`nearest_root` as an unsigned integer key: a hit's key is its
    root's bits minus those of the smallest float past ``T_MIN`` (wrapping),
    so keys order as the roots do, and every root that is no hit (at or
    below ``T_MIN``, negative, a miss's NaN) wraps or lands above the key
    of ``inf``.  The smaller key of the near and far root is the nearest
    root past ``T_MIN``, with no mask: five passes over the (primitives,
    rays) block where :func:`nearest_root`'s comparisons, absolute values
    and divisions by a mask took nine: 25 against 48-58 us on W1's 5 x
    8192 float32 blocks (three_spheres).  Overwrites nothing; returns a new array of
    keys, which :func:`key_root` turns back into roots (``inf`` for none)."""
    bits, first, _ = _ROOT_KEYS[h.dtype]
    near = np.subtract(h, sqrt_disc).view(bits)
    near -= first
    far = np.add(h, sqrt_disc).view(bits)
    far -= first
    return np.minimum(near, far, out=near)


def roots_key(a, b=None, out=None):
    """:func:`nearest_root_key` of roots already formed: each root's key, or
    the smaller key of ``a``'s and ``b``'s (roots in either order), the
    nearest of the two past ``T_MIN``.  Overwrites ``a`` and ``b`` (their
    bits become the keys) and returns the keys, a view of ``a`` (or ``out``,
    where given with ``b``)."""
    bits, first, _ = _ROOT_KEYS[a.dtype]
    key = a.view(bits)
    key -= first
    if b is None:
        return key
    other = b.view(bits)
    other -= first
    return np.minimum(key, other, out=key if out is None else out)


def limit_key(t_max):
    """The key (see :func:`nearest_root_key`) below which a root of
    ``t_max``'s type lies in ``(T_MIN, t_max)``: ``key < limit_key(t_max)``
    exactly when ``T_MIN < root < t_max``, and 0 (nothing below it) where
    that interval is empty or ``t_max`` is NaN.  ``t_max``: an array of
    float32 or float64, any shape; returns a new array of its shape."""
    bits, first, _ = _ROOT_KEYS[t_max.dtype]
    key = np.subtract(t_max.view(bits), first)
    key *= t_max > T_MIN  # compared in t_max's type, as the roots are
    return key


def key_root(key):
    """The root of each :func:`nearest_root_key` key (of ``dtype`` float32 or
    float64 by the key's width), bit for bit :func:`nearest_root`'s where
    it is a hit, and ``inf`` where it is none.  Returns a new array."""
    float_type = np.float32 if key.dtype == np.uint32 else np.float64
    _, first, key_inf = _ROOT_KEYS[np.dtype(float_type)]
    root = np.minimum(key, key_inf)  # every miss to inf's key
    root += first
    return root.view(float_type)


def escaped_at_inf(best_t, hit, t_max):
    """``best_t`` with ``inf`` where nothing was hit.  Without a finite
    ``t_max`` it is already ``inf`` there, and an ``np.where`` over every ray
    (~2 ns each) is skipped."""
    if np.ndim(t_max) == 0 and t_max == np.inf:
        return best_t
    return np.where(hit, best_t, np.inf)

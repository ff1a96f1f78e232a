"""Spheres as a shape kind (the sphere object itself is :class:`wavefront.geometry.Sphere`)."""

from __future__ import annotations

import numpy as np

from ..geometry import (FLOAT32_EXTENT, T_MIN, Sphere, anchored_roots, first_root, key_root, limit_key,
                        roots_key, sphere_root_keys, sphere_roots)
from ..vecmath import gather
from .base import ShapeKind

__all__ = ["Sphere", "SphereSet", "world_sphere", "world_center1", "world_rotation"]

# Bytes of one (spheres, rays) temporary of :meth:`SphereSet.key_block`: a
# larger block is keyed in equal chunks of rays, so that the exact test's
# five temporaries stay in L2.  W2's outsized spheres (4 in float64, calls of
# up to 16,384 rays inside the BVH's batches), its recorded calls of a 600x338
# render replayed through brute force in one process, alternating: the keys
# alone ~15 % faster in chunks of 5,000-8,192 rays than at once (4,096 or
# fewer: no faster); the whole brute force at this budget (16,384 rays in
# three chunks) 0.92-0.96 of 1 << 18 (two chunks), 1.07-1.13 of 1 << 30
# (none).  W1's 5 x 32,768 float32 blocks (primitives.BRUTE_FORCE_RAYS) are
# keyed in four chunks of 8,192 rays (160 KiB).
KEY_BLOCK_BYTES = 3 << 16
KEY_MIN_RAYS = 1024  # never chunks of fewer rays: each costs ~26 NumPy calls
# Tried in session 11, not kept (the same recorded calls):
# - cheap pre-culls before the exact test.  A ray starting above a ground's
#   top plane and heading up cannot hit it, but that is 18 % of W1's rays and
#   21 % of W2's, while the ground is hit by 59 % and 49 % (no cull can leave
#   fewer survivors than that); a ray heading away from a sphere (h <= 0):
#   30-43 % per sphere.  W2's three balls (hit by 15 % of the rays) in their
#   common box: a float64 slab test of 16,384 rays took 150-230 us against
#   ~450 us for the balls' keys, and camera batches keep 81-91 % of their rays
#   (the camera looks at the balls): 291-365 us with the cull where 17 % or
#   fewer enter, 615-760 us where most do;
# - W1's 5 x 8,192 float32 blocks in chunks of 4,096 or 2,731 rays: 1.23x and
#   1.35x slower; the five temporaries as 64-byte aligned views of one
#   workspace (with and without aligned copies of the rays): no faster.
# Tried in session 12, not kept:
# - spheres sharing a centre (W1's hollow glass ball) with h and the offset
#   from the ray's line computed once per centre, the twin's discriminant
#   and roots in rows of their own: W1's keys 120.7 -> 118.7 us a 5 x 8,192
#   block (each twin costs five calls of a row, for fifteen rows of passes),
#   and the whole nearest-hit query 5-7 % slower with the keys put back in
#   row order (three calls into a new block);
# - float32 key blocks four times larger (W1's 5 x 32,768 keys whole, one
#   call each where four chunks took ~26 each): W1's recorded queries 0.89-
#   0.95 of the chunks, but whole W1 renders 1.016 and 0.996 (two interleaved
#   A/Bs of 9 fresh processes each); alternating in one process 0.974 and
#   0.981 (medians of 12 and 14 renders), pairwise 0.983 and 1.005: not
#   measurably faster.


def world_sphere(sphere: Sphere) -> tuple[np.ndarray, float]:
    """Centre (at time 0) and radius in world space (``transform`` must be a
    similarity, which the scene loader and :func:`SphereSet.build` check)."""
    center = np.asarray(sphere.center, dtype=np.float64)
    if sphere.transform is None or sphere.transform.is_identity:
        return center, float(sphere.radius)
    scale = sphere.transform.uniform_scale()
    if scale is None:
        raise ValueError("a sphere's transform may only translate, rotate and scale uniformly")
    return sphere.transform.points(center[:, None])[:, 0], float(sphere.radius) * scale


def world_center1(sphere: Sphere) -> np.ndarray | None:
    """The centre at time 1 in world space (the transform moves both centres alike); None for a still sphere."""
    if sphere.center1 is None:
        return None
    center1 = np.asarray(sphere.center1, dtype=np.float64)
    if sphere.transform is None or sphere.transform.is_identity:
        return center1
    return sphere.transform.points(center1[:, None])[:, 0]


def world_rotation(sphere: Sphere) -> np.ndarray | None:
    """The rotation ``(3, 3)`` of the sphere's transform (its linear part over
    the scale), or None when it does not turn the sphere: it carries the
    sphere's ``uv`` (and so an image on it) round with the sphere, as RTOW's
    ``rotate_y`` does by intersecting in object space."""
    if sphere.transform is None or sphere.transform.is_identity:
        return None
    rotation = sphere.transform.array[:3, :3] / sphere.transform.uniform_scale()
    return None if np.array_equal(rotation, np.eye(3)) else rotation


def object_normal(rotation: np.ndarray | None, idx, outward: np.ndarray) -> np.ndarray:
    """World-space unit normals ``(3, N)`` of spheres ``idx`` turned back into
    their object space (``R^T n``), where ``uv`` is defined."""
    if rotation is None:
        return outward
    r = np.take(rotation, idx, axis=-1).astype(outward.dtype, copy=False)  # (3, 3, N)
    return np.stack([r[0, i] * outward[0] + r[1, i] * outward[1] + r[2, i] * outward[2] for i in range(3)])


class SphereSet(ShapeKind):
    """Spheres as arrays: ``center (3, M)``, ``radius (M,)``, at the render's precision.

    Moving spheres (motion blur) add ``velocity (3, M)`` = ``center1 - center``
    (``None`` when nothing moves): at time ``t`` a sphere's centre is
    ``center + t velocity``, computed in the render's precision, so a still
    sphere (velocity 0) meets every ray exactly as it would without motion.
    """

    FIELDS = ("center", "radius_squared")
    # the anchored spheres' (see geometry.FLOAT32_MAX_REACH and ``anchor`` below)
    ANCHORED_FIELDS = ("center", "radius_squared", "near_point", "far_point")
    name = "sphere"

    def __init__(self, center, radius, material_idx, dtype=np.float64, velocity=None):
        center = np.asarray(center, dtype=np.float64).reshape(3, -1)
        radius = np.asarray(radius, dtype=np.float64)
        # derived terms in float64 first, then stored at the render's precision
        self.dtype = np.dtype(dtype)
        self.center = np.ascontiguousarray(center, dtype=dtype)
        self.radius = np.ascontiguousarray(radius, dtype=dtype)
        self.material_idx = np.ascontiguousarray(material_idx, dtype=np.int32)
        self.radius_squared = (radius * radius).astype(dtype)
        self.inverse_radius = (1.0 / radius).astype(dtype)
        self.rotation = None  # (3, 3, M) float64 where some sphere is turned (for uv); see world_rotation
        self.velocity = None
        # A float32 sphere reaching past FLOAT32_EXTENT (forced, or a huge
        # sphere under auto precision) is tested with anchored_roots, from two
        # antipodal points: the one nearest the world origin and its opposite.
        # Still spheres only (moving ones keep sphere_roots).  The others of
        # its set keep sphere_roots' keys, as in a set without huge spheres
        # (the float32 rule holds for them on their own: see
        # scene._huge_spheres_fit_float32), on rays in the set's type as the
        # anchored ones.  The arithmetic is each sphere's own, in brute force
        # and the BVH alike.  (Every sphere of such a set was anchored before:
        # the cover's 7.5 M (ray, small ball) pairs in its BVH's leaves at
        # 600x338 16 spp took 0.19 s of CPU anchored, 0.09 s so; the whole
        # render 5-6 % less, interleaved A/B.)
        reach = np.sqrt((center * center).sum(axis=0)) + radius
        self.anchor = (reach > FLOAT32_EXTENT) if self.dtype == np.float32 and velocity is None else \
            np.zeros(reach.shape, dtype=bool)  # (M,): which spheres are anchored
        self.anchored = bool(self.anchor.any())  # some are: rays are then taken in the set's type
        if self.anchored:
            distance = reach - radius
            toward = np.divide(center, distance, out=np.zeros_like(center), where=distance > 0)
            toward[2, distance == 0] = 1.0  # a sphere centred on the origin: any pair of antipodes
            self.near_point = np.ascontiguousarray((center - radius * toward).astype(dtype))
            self.far_point = np.ascontiguousarray((center + radius * toward).astype(dtype))
        if velocity is not None:
            # the end centre rounded to the render's precision, and the velocity
            # taken from the rounded centres: c + 1 * v then lands on it
            end = np.asarray(velocity, dtype=np.float64).reshape(3, -1) + center
            self.velocity = np.ascontiguousarray(end.astype(dtype) - self.center)
        self.shared_axes = self._shared_axes()
        self._plans = {}  # (start, stop): the fields of a block's plain spheres (see _key_plan)
        self._freeze()

    def _freeze(self) -> None:
        """shared_axes, anchor, the antipodes and the plans are derived from
        the centres and radii once: writing to them in place would leave those
        stale, so they are read-only (a changed set is a new SphereSet), in a
        subset too."""
        for field in (self.center, self.radius, self.radius_squared):
            field.flags.writeable = False

    def _shared_axes(self) -> tuple[int, ...]:
        """The coordinates (0, 1, 2 for x, y, z) that every sphere of the set
        shares, bit for bit, where there are two or more spheres: W1's and
        W2's grounds and balls all stand at one z.  :meth:`key_block` passes
        each as one row (see ``geometry._sphere_roots``), the x and y not
        both.  Measured on their recorded brute-force calls, alternating in
        one process: the keys 7-9 % faster (W1, 5 x 8,192 float32 blocks)
        and ~7 % (W2's outsized spheres, 4 in float64, in chunks)."""
        m = len(self.radius)
        if m < 2:
            return ()
        bits = self.center.view(f"u{self.dtype.itemsize}")  # bits, not values: -0.0 is not 0.0 here
        axes = [i for i in range(3) if (bits[i] == bits[i, 0]).all()]
        if 0 in axes and 1 in axes:
            axes.remove(1)
        return tuple(axes)

    def subset(self, idx):
        part = super().subset(idx)
        part.shared_axes = part._shared_axes()
        part.anchored = bool(part.anchor.any())
        part._plans = {}
        part._freeze()
        return part

    def _key_plan(self, start, stop):
        """The fields with which :meth:`key_block` keys the plain (not
        anchored) spheres of block ``start:stop``, and their rows of the
        block (a slice where they are a run of rows), worked out once per
        block; None where every sphere of the block is anchored.  A
        coordinate those spheres share (bit for bit) is one row, as
        ``shared_axes`` (the x and y not both), but among them alone: the
        cover's three outsized balls share y as well as z, which its
        anchored ground does not (two passes over their block fewer)."""
        key = (start, stop)
        if key not in self._plans:
            _, plain = self._split(start, stop)
            if plain is None:
                self._plans[key] = None
                return None
            rows = np.arange(stop - start) if isinstance(plain, slice) else plain
            bits = self.center[:, start + rows].view(f"u{self.dtype.itemsize}")  # bits: -0.0 is not 0.0 here
            shared = [i for i in range(3) if rows.size > 1 and (bits[i] == bits[i, 0]).all()]
            if 0 in shared and 1 in shared:
                shared.remove(1)
            center = self.center[:, start + rows, None]
            radius_squared = self.radius_squared[start + rows, None]
            if rows.size and rows[-1] - rows[0] == rows.size - 1:
                rows = slice(int(rows[0]), int(rows[-1]) + 1)
            self._plans[key] = ([center[i, :1] if i in shared else center[i] for i in range(3)], radius_squared, rows)
        return self._plans[key]

    def _anchor_zeros(self, start, stop, rows):
        """The axes on which every anchored sphere of block ``start:stop`` (its
        ``rows``, or all) has its ``near_point``, and those on which it has
        its ``far_point``, at +0.0 (bits, not values: not -0.0), once per
        block: :func:`~wavefront.geometry.anchored_roots` then takes the ray's
        own coordinate for the difference."""
        key = ("zeros", start, stop)
        if key not in self._plans:
            where = slice(start, stop) if rows is None else start + rows
            self._plans[key] = tuple(tuple(i for i in range(3) if not point[i, where].view(f"u{self.dtype.itemsize}").any())
                                     for point in (self.near_point, self.far_point))
        return self._plans[key]

    def _own_type(self, origin, direction):
        """Rays in an anchored set's type (see ``anchor``; no copy where they have it)."""
        if not self.anchored:
            return origin, direction
        return origin.astype(self.dtype, copy=False), direction.astype(self.dtype, copy=False)

    def _split(self, start, stop):
        """Rows of block ``start:stop`` whose spheres are anchored, and the
        others', or None for the second where all are, for the first where none is."""
        if not self.anchored:
            return None, slice(None)
        flags = self.anchor[start:stop]
        return (np.flatnonzero(flags) if flags.any() else None), (np.flatnonzero(~flags) if not flags.all() else None)

    def _fields(self, names, start, stop, rows=None):
        """Fields ``names`` of spheres ``start:stop`` (of its ``rows`` only), shaped as :meth:`block`'s."""
        where = slice(start, stop) if rows is None else start + rows
        return [getattr(self, f)[..., where, None] for f in names]

    @classmethod
    def build(cls, spheres: list[Sphere], material_idx, dtype) -> SphereSet:
        m = len(spheres)
        center = np.zeros((3, m))
        radius = np.zeros(m)
        for i, s in enumerate(spheres):  # per scene object, at compile time
            center[:, i], radius[i] = world_sphere(s)
        velocity = None
        moving = [i for i, s in enumerate(spheres) if s.center1 is not None]
        if moving:
            velocity = np.zeros((3, m))
            for i in moving:
                velocity[:, i] = world_center1(spheres[i]) - center[:, i]
            if not velocity.any():  # every centre1 is its centre: nothing moves
                velocity = None
        spheres_set = cls(center, radius, material_idx, dtype, velocity)
        turned = [(i, r) for i, r in ((i, world_rotation(s)) for i, s in enumerate(spheres)
                                      if s.transform is not None) if r is not None]
        if turned:
            spheres_set.rotation = np.repeat(np.eye(3)[:, :, None], m, axis=2)
            for i, r in turned:
                spheres_set.rotation[:, :, i] = r
        return spheres_set

    @property
    def moving(self) -> bool:
        return self.velocity is not None

    def center_at(self, idx, time) -> np.ndarray:
        """Centres ``(3, N)`` of spheres ``idx`` at times ``time (N,)`` (or their
        still centres when nothing moves or no time is given)."""
        center = gather(self.center, idx)
        if self.velocity is None or time is None:
            return center
        return center + gather(self.velocity, idx) * np.asarray(time).astype(self.dtype, copy=False)

    def bounds(self):
        """Boxes holding each sphere over the whole shutter interval [0, 1]."""
        c, r = self.center.astype(np.float64), self.radius.astype(np.float64)
        if self.velocity is None:
            return c - r, c + r
        end = c + self.velocity.astype(np.float64)
        return np.minimum(c, end) - r, np.maximum(c, end) + r

    def bounding_sphere(self):
        """A sphere holding each sphere over [0, 1]: centred half-way, grown by half the path."""
        c, r = self.center.astype(np.float64), self.radius.astype(np.float64)
        if self.velocity is None:
            return c, r
        v = self.velocity.astype(np.float64)
        return c + 0.5 * v, r + 0.5 * np.sqrt(v[0] * v[0] + v[1] * v[1] + v[2] * v[2])

    def t_block(self, start, stop, origin, direction, time=None):
        if self.anchored:  # each sphere's own arithmetic, as key_block's
            origin, direction = self._own_type(origin, direction)
            o, d = origin[:, None, :], direction[:, None, :]
            anchored, plain = self._split(start, stop)
            t = np.empty((stop - start, origin.shape[1]), dtype=self.dtype)
            if anchored is not None:
                t[anchored] = _anchored_t(*self._fields(self.ANCHORED_FIELDS, start, stop, anchored), o, d)
            if plain is not None:
                t[plain] = self.exact_t(*self._fields(self.FIELDS, start, stop, plain), o, d)
            return t
        if self.velocity is None or time is None:
            return super().t_block(start, stop, origin, direction)
        center, radius_squared = self.block(start, stop)
        center = center + self.velocity[:, start:stop, None] * np.asarray(time).astype(self.dtype, copy=False)
        return self.exact_t(center, radius_squared, origin[:, None, :], direction[:, None, :])

    def key_block(self, start, stop, origin, direction, time=None):
        """:meth:`t_block`'s roots as :func:`~wavefront.geometry.nearest_root_key`
        keys.  Anchored spheres key their two roots (three passes, where
        :func:`~wavefront.geometry.first_root` took seven); where some ray
        has a ``t_min`` of its own (beyond ``FLOAT32_EXTENT``) they key
        ``first_root``'s root, past each ray's ``t_min`` and so past ``T_MIN``.
        A block of anchored and other spheres keys each kind in its own rows."""
        if self.velocity is not None and time is not None:
            center, radius_squared = self.block(start, stop)
            center = center + self.velocity[:, start:stop, None] * np.asarray(time).astype(self.dtype, copy=False)
            return sphere_root_keys(center, radius_squared, origin[:, None, :], direction[:, None, :])
        origin, direction = self._own_type(origin, direction)
        anchored, plain = self._split(start, stop)
        if plain is None:
            return _anchored_keys(*self._fields(self.ANCHORED_FIELDS, start, stop), origin, direction,
                                  zeros=self._anchor_zeros(start, stop, None))
        if not origin.dtype == direction.dtype == self.dtype:  # (rays of mixed types, as some tests pass)
            return self._plain_keys(*self.block(start, stop), origin, direction)
        center, radius_squared, rows = self._key_plan(start, stop)
        if anchored is None:
            return self._plain_keys(center, radius_squared, origin, direction, planned=True)
        # each kind's keys written into its rows of the block (in place where they are a run of rows)
        keys = np.empty((stop - start, origin.shape[1]), dtype=f"u{self.dtype.itemsize}")
        fields = self._fields(self.ANCHORED_FIELDS, start, stop, anchored)
        zeros = self._anchor_zeros(start, stop, anchored)
        if anchored[-1] - anchored[0] == anchored.size - 1:
            _anchored_keys(*fields, origin, direction, out=keys[anchored[0]:anchored[-1] + 1], zeros=zeros)
        else:
            keys[anchored] = _anchored_keys(*fields, origin, direction, zeros=zeros)
        if isinstance(rows, slice):
            self._plain_keys(center, radius_squared, origin, direction, out=keys[rows], planned=True)
        else:
            keys[rows] = self._plain_keys(center, radius_squared, origin, direction, planned=True)
        return keys

    def _plain_keys(self, center, radius_squared, origin, direction, out=None, planned=False):
        """:func:`~wavefront.geometry.sphere_root_keys` of still spheres (fields
        as :meth:`block`'s, or ``planned``: a :meth:`_key_plan`'s, its shared
        coordinates rows already) against all rays, in chunks of rays
        (``KEY_BLOCK_BYTES``); written into ``out`` where given."""
        m = radius_squared.shape[0]
        o, d = origin[:, None, :], direction[:, None, :]
        if not planned and self.shared_axes and m > 1 and origin.dtype == direction.dtype == self.dtype:
            center = [center[i][:1] if i in self.shared_axes else center[i] for i in range(3)]
        n = origin.shape[1]
        step = max(KEY_MIN_RAYS, KEY_BLOCK_BYTES // (max(1, m) * self.dtype.itemsize))  # (an empty block too)
        if n <= step:
            return sphere_root_keys(center, radius_squared, o, d, out)
        step = -(-n // -(-n // step))  # chunks of equal size
        if out is None:
            width = np.result_type(self.dtype, origin.dtype, direction.dtype).itemsize  # the roots' (unsigned twin: keys)
            out = np.empty((m, n), dtype=f"u{width}")
        for a in range(0, n, step):
            sphere_root_keys(center, radius_squared, o[..., a:a + step], d[..., a:a + step], out=out[:, a:a + step])
        return out

    def t_pairs(self, idx, origin, direction, time=None):
        if self.anchored:  # each sphere's own arithmetic, as key_block's
            origin, direction = self._own_type(origin, direction)
            flags = self.anchor.take(idx)
            anchored = np.flatnonzero(flags)
            if anchored.size == 0:
                return self.exact_t(*self.gather(idx), origin, direction)
            if anchored.size == idx.size:
                return _anchored_t(*[np.take(getattr(self, f), idx, axis=-1) for f in self.ANCHORED_FIELDS],
                                   origin, direction)
            plain = np.flatnonzero(~flags)
            t = np.empty(idx.shape, dtype=self.dtype)
            t[anchored] = self.t_pairs(idx.take(anchored), origin.take(anchored, axis=1),
                                       direction.take(anchored, axis=1))
            t[plain] = self.t_pairs(idx.take(plain), origin.take(plain, axis=1), direction.take(plain, axis=1))
            return t
        if self.velocity is None or time is None:
            return super().t_pairs(idx, origin, direction)
        center, radius_squared = self.gather(idx)
        return self.exact_t(self.center_at(idx, time), radius_squared, origin, direction)

    def any_hit_block(self, start, stop, origin, direction, t_max, time=None):
        """Whether a root of :func:`~wavefront.geometry.sphere_roots` lies in
        ``(T_MIN, t_max)`` for some sphere of ``start:stop``: the roots of
        :meth:`t_block`, compared without choosing the nearest (as
        :meth:`exact_t` does, through keys).  ``nearest_root < t_max`` exactly
        when either root is in the interval: the far root is never below the
        near one, so a near root at or past ``t_max`` leaves none.

        Every sphere of the block is tested against every ray at once.  (A
        probe of every 16th ray that put the sphere blocking most of them
        first, and tested the others only on the rays it left, saved ~25 %
        of cornell_spheres' shadow rays in float64 before its walls were
        float32; now it costs more than it saves: one 4096-ray chunk of its
        shadow rays 0.33 ms with it, 0.19 ms without, and a whole 32768-path
        task 2-8 % longer, in float64 as well.)
        """
        if self.velocity is not None and time is not None:
            return super().any_hit_block(start, stop, origin, direction, t_max, time)
        origin, direction = self._own_type(origin, direction)
        anchored, plain = self._split(start, stop)
        if plain is None:
            return self._blocking(self._fields(self.ANCHORED_FIELDS, start, stop), origin, direction, t_max, True)
        if anchored is None:
            return self._blocking(self.block(start, stop), origin, direction, t_max)
        blocked = self._blocking(self._fields(self.ANCHORED_FIELDS, start, stop, anchored), origin, direction, t_max,
                                 True)
        blocked |= self._blocking(self._fields(self.FIELDS, start, stop, plain), origin, direction, t_max)
        return blocked

    def _blocking(self, fields, origin, direction, t_max, anchored=False):
        """``(N,)``: whether some sphere (``fields`` as :meth:`block`'s, or
        ``ANCHORED_FIELDS`` for anchored ones) has a root in ``(t_min, t_max)`` along each ray."""
        o, d = origin[:, None, :], direction[:, None, :]
        if anchored:
            a, b, t_min = anchored_roots(*fields, o, d)
        elif isinstance(t_max, np.ndarray) and t_max.dtype == np.result_type(self.dtype, origin.dtype, direction.dtype):
            # keyed: a root in (T_MIN, t_max) is a key below t_max's, six
            # passes over the block where the two roots' comparisons took nine
            # (key_block's keys: fused, and chunked in a large block)
            return (self._plain_keys(*fields, origin, direction) < limit_key(t_max)).any(axis=0)
        else:
            h, sqrt_disc = sphere_roots(*fields, o, d)
            a, b, t_min = h - sqrt_disc, h + sqrt_disc, T_MIN
        if np.ndim(t_min) == 0 and isinstance(t_max, np.ndarray) and t_max.dtype == a.dtype:
            # every ray's t_min is T_MIN, and the comparisons were in the roots' type: keyed,
            # four passes over the block where root_within's took seven
            return (roots_key(a, b) < limit_key(t_max)).any(axis=0)
        blocked = root_within(a, t_min, t_max)
        blocked |= root_within(b, t_min, t_max)
        return blocked.any(axis=0)

    @staticmethod
    def exact_t(center, radius_squared, origin, direction):
        """The first root past ``T_MIN`` (``inf`` for none): see
        :func:`wavefront.geometry.sphere_roots` for why this arithmetic.  Through the
        roots' keys (:func:`~wavefront.geometry.nearest_root_key`, as :meth:`key_block`):
        the same roots as :func:`~wavefront.geometry.nearest_root`, in seven passes
        instead of nine and without its error-state context (~6 against ~11 us for a
        BVH batch's ~1,700 leaf tests)."""
        return key_root(sphere_root_keys(center, radius_squared, origin, direction))

    def surface(self, idx, origin, direction, t, uv: bool, time=None):
        point = t * direction
        point += origin  # origin + t direction (addition commutes exactly)
        center = self.center_at(idx, time)  # a new array: the outward normal is formed in it
        outward = np.subtract(point, center, out=center)
        outward *= gather(self.inverse_radius, idx)
        return point, outward, outward, (sphere_uv(object_normal(self.rotation, idx, outward)) if uv else None)


def root_within(t, t_min, t_max):
    """``t_min < t < t_max`` (false for NaN, a miss)."""
    inside = t > t_min
    inside &= t < t_max
    return inside


def _anchored_keys(center, radius_squared, near_point, far_point, origin, direction, out=None, zeros=((), ())):
    """Anchored spheres' keys (fields as :meth:`SphereSet.block`'s): see
    :meth:`SphereSet.key_block`; written into ``out`` where given (``zeros``:
    see :func:`~wavefront.geometry.anchored_roots`)."""
    a, b, t_min = anchored_roots(center, radius_squared, near_point, far_point, origin[:, None, :],
                                 direction[:, None, :], zeros)
    if np.ndim(t_min):
        keys = roots_key(first_root(a, b, t_min))
        if out is not None:
            np.copyto(out, keys)
        return keys if out is None else out
    return roots_key(a, b, out)


def _anchored_t(center, radius_squared, near_point, far_point, origin, direction):
    """An anchored set's exact test: the first root past each ray's ``t_min``
    (see :func:`wavefront.geometry.anchored_roots`)."""
    return first_root(*anchored_roots(center, radius_squared, near_point, far_point, origin, direction))


def sphere_uv(outward: np.ndarray) -> np.ndarray:
    """RTOW's ``get_sphere_uv``: ``u`` is the angle around the y axis from
    x = -1, ``v`` the angle from y = -1, both scaled to [0, 1]."""
    theta = np.arccos(np.clip(-outward[1], -1.0, 1.0))
    phi = np.arctan2(-outward[2], outward[0]) + np.pi
    return np.stack((phi / (2 * np.pi), theta / np.pi))


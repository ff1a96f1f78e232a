"""The scene's emitters as one table, and the samplers next-event estimation draws from.

Every emissive sphere, quad and triangle (mesh triangles included) becomes
one row of an :class:`EmitterTable`, built once when the scene is compiled.
A light sample is drawn in two steps, as in pbrt-v4's ``PowerLightSampler``:
an emitter is chosen with probability proportional to its emitted power
(mean radiance over the RGB channels x area x pi, the flux of a one-sided
Lambertian emitter), then a point on it:

* spheres by the cone of directions they subtend (pbrt-v4 ``Sphere::Sample``,
  Mitsuba's ``Sphere::sample_direction``): uniform in solid angle inside the
  cone, so the pdf is the constant ``1 / (2 pi (1 - cos theta_max))``; a
  point inside the sphere samples the whole sphere by area instead;
* quads uniformly by area, ``corner + u0 u + u1 v``;
* triangles uniformly by area through the square-root barycentric map
  (``b0 = 1 - sqrt(u0)``, ``b1 = u1 sqrt(u0)``; Shirley & Chiu / pbrt);

area densities are converted to solid angle at the reference point
(``pdf_area * distance^2 / |cos theta_light|``).  Every sampler takes its
uniforms as arguments and owns no state, so ``tests/test_lights.py`` can
check each with chi-square tests and wrong samplers that must fail.

Emission is one-sided (RTOW book 3, pbrt, Mitsuba): a sample on the back of
a quad or triangle, or on a sphere seen from inside, carries no radiance.

A textured emitter is chosen by the power of its texture's mean colour
(:meth:`wavefront.textures.TextureTable.mean`: an image's mean pixel, a
checker's mean of its two colours, the marble's 0.5), and its radiance is
the texture evaluated at the sampled point and its ``uv``.  Choosing by the
mean rather than the exact integral over the surface only changes the noise,
never the expectation: the pmf just has to be positive wherever light is
emitted.  A moving sphere is sampled where it is at the shading path's time.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from .materials import MaterialTable
from .sampling import cos_sin_2pi, random_unit_vector
from .shapes import Primitives, QuadSet, SphereSet, TriangleSet
from .shapes.sphere import object_normal, sphere_uv
from .textures import TextureTable
from .vecmath import dot, gather, length, true_rows

SPHERE, QUAD, TRIANGLE = 0, 1, 2  # emitter kinds
# Below sin^2(1.5 degrees) the cone's 1 - cos(theta_max) cancels in floating
# point; pbrt-v4 switches to the small-angle series there (sin^2 / 2).
SMALL_CONE_SIN2 = 0.00068523
_TINY = np.finfo(np.float64).tiny  # a distance floor: no division by zero
# A triangle without file uv has the barycentrics (b1, b2) as its uv: corners (0, 0), (1, 0), (0, 1).
_BARYCENTRIC_UV = np.array([[0.0, 0.0], [1.0, 0.0], [0.0, 1.0]])[:, :, None]


@dataclass(slots=True)
class LightSample:
    """Points sampled on emitters as seen from reference points; one column per reference point.

    ``pdf`` is per unit solid angle at the reference point and includes the
    probability of choosing the emitter; ``radiance`` is zero where the sample
    shows the emitter's back (one-sided emission) or the pdf is zero.
    """

    point: np.ndarray  # (3, N) on the emitter, float64
    direction: np.ndarray  # (3, N) unit, reference point -> point
    distance: np.ndarray  # (N,)
    pdf: np.ndarray  # (N,) solid angle, emitter choice included
    # (N,) whether ``radiance`` has a positive channel, where that is known
    # without reading it (untextured emitters: there it is exactly the
    # sample's lit mask, see EmitterTable.sample); None: read ``radiance``
    carries: np.ndarray | None = None
    # ``radiance`` as given, or (untextured emitters) the emitters' columns
    # ``(3, N)`` or ``(3, 1)`` whose product with ``carries`` it is, formed
    # on first use: next-event estimation with one emitter never reads it
    # (it broadcasts the column), a (3, N) pass and array saved per bounce
    given_radiance: np.ndarray | None = None
    emitter_radiance: np.ndarray | None = None

    @property
    def radiance(self) -> np.ndarray:
        """``(3, N)`` emitted towards the reference point."""
        if self.given_radiance is None:
            self.given_radiance = self.emitter_radiance * self.carries
        return self.given_radiance


@dataclass(slots=True)
class EmitterTable:
    """Every emissive primitive of a scene, one column each (float64).

    For a sphere ``origin`` is its centre and ``radius`` its radius; for a
    quad ``origin, edge1, edge2`` are ``corner, u, v``; for a triangle
    ``v0, v1 - v0, v2 - v0``.  ``normal`` is the front side's unit normal
    (unused for spheres).  ``emitter_of`` maps a scene-wide primitive index to
    its row (-1: not an emitter), which is how a path that hits an emitter by
    scattering finds the light-sampling pdf its MIS weight needs.
    """

    kind: np.ndarray  # (E,) int8: SPHERE, QUAD or TRIANGLE
    origin: np.ndarray  # (3, E)
    edge1: np.ndarray  # (3, E)
    edge2: np.ndarray  # (3, E)
    normal: np.ndarray  # (3, E)
    radius: np.ndarray  # (E,)
    area: np.ndarray  # (E,)
    radiance: np.ndarray  # (3, E)
    pmf: np.ndarray  # (E,) probability of choosing each emitter, by power
    cdf: np.ndarray  # (E,) its running sum, last entry exactly 1
    emitter_of: np.ndarray  # (M,) int32, per scene-wide primitive
    # motion blur: a sphere's centre moves by ``velocity`` over [0, 1] (None: nothing moves)
    velocity: np.ndarray | None = None  # (3, E)
    # textured emission: the texture node per emitter (-1: ``radiance`` as is)
    texture: np.ndarray | None = None  # (E,) int
    textures: TextureTable | None = None
    vertex_uv: np.ndarray | None = None  # (3, 2, E) a triangle's corner uv (barycentrics where the mesh has none)
    rotation: np.ndarray | None = None  # (3, 3, E) a turned sphere's rotation (for its uv), identity elsewhere
    # the one kind of every emitter (SPHERE, QUAD or TRIANGLE), or -1 for a
    # mix: decided once here, not per light sample (see :meth:`sample`)
    one_kind: int = -1

    def __len__(self) -> int:
        return self.kind.shape[0]

    @classmethod
    def build(cls, primitives: Primitives, materials: MaterialTable) -> EmitterTable:
        """The emitters among ``primitives`` (in scene-wide index order).

        A primitive is an emitter when its material is emissive with some
        non-zero channel; zero-power emitters are left out (they could never
        contribute, and a zero pmf would make their MIS weight undefined).
        """
        emissive = materials.kind == materials.code("emissive")
        power_of_material = np.where(emissive, materials.emission.astype(np.float64).mean(axis=0), 0.0)
        parts, emitter_of = [], np.full(len(primitives), -1, dtype=np.int32)
        for shapes, offset in zip(primitives.kinds, primitives.offsets):
            sel = np.flatnonzero(power_of_material[shapes.material_idx] > 0)
            if sel.size == 0:
                continue
            f64 = lambda a: np.asarray(a, dtype=np.float64).take(sel, axis=-1)  # noqa: E731
            zeros = np.zeros((3, sel.size))
            velocity, corner_uv = zeros, np.broadcast_to(_BARYCENTRIC_UV, (3, 2, sel.size))
            rotation = np.broadcast_to(np.eye(3)[:, :, None], (3, 3, sel.size))
            if isinstance(shapes, SphereSet):
                radius = f64(shapes.radius)
                part = (SPHERE, f64(shapes.center), zeros, zeros, zeros, radius, 4.0 * np.pi * radius * radius)
                if shapes.velocity is not None:
                    velocity = f64(shapes.velocity)
                if shapes.rotation is not None:
                    rotation = f64(shapes.rotation)
            elif isinstance(shapes, QuadSet):
                u, v = f64(shapes.u), f64(shapes.v)
                area = np.linalg.norm(np.cross(u, v, axis=0), axis=0)
                part = (QUAD, f64(shapes.corner), u, v, f64(shapes.normal), np.zeros(sel.size), area)
            elif isinstance(shapes, TriangleSet):
                e1, e2 = f64(shapes.e1), f64(shapes.e2)
                area = 0.5 * np.linalg.norm(np.cross(e1, e2, axis=0), axis=0)
                part = (TRIANGLE, f64(shapes.v0), e1, e2, f64(shapes.normal), np.zeros(sel.size), area)
                if shapes.vertex_uv is not None:
                    corner_uv = f64(shapes.vertex_uv)
            else:  # pragma: no cover - a new shape kind must say how it is sampled
                raise TypeError(f"no light sampler for {type(shapes).__name__}")
            material = shapes.material_idx.take(sel)
            parts.append(part + (materials.emission.astype(np.float64)[:, material], velocity,
                                 materials.emission_texture.take(material), corner_uv, rotation))
            emitter_of[offset + sel] = sum(p[1].shape[1] for p in parts[:-1]) + np.arange(sel.size)
        if not parts:
            empty3 = np.zeros((3, 0))
            return cls(np.zeros(0, np.int8), empty3, empty3, empty3, empty3, np.zeros(0), np.zeros(0),
                       empty3, np.zeros(0), np.zeros(0), emitter_of)
        kind = np.concatenate([np.full(p[1].shape[1], p[0], dtype=np.int8) for p in parts])
        origin, edge1, edge2, normal = (np.concatenate([p[k] for p in parts], axis=1) for k in (1, 2, 3, 4))
        radius, area = (np.concatenate([p[k] for p in parts]) for k in (5, 6))
        radiance = np.concatenate([p[7] for p in parts], axis=1)
        velocity = np.concatenate([p[8] for p in parts], axis=1)
        texture = np.concatenate([p[9] for p in parts])
        textured = materials.textures is not None and bool((texture >= 0).any())
        # Relative power, each factor scaled by its maximum first: emission and
        # area have no upper bound, and an overflow to inf made the pmf NaN
        # (the light vanished).  pi is common to all and left out.
        mean = radiance.mean(axis=0)
        with np.errstate(over="ignore"):
            power = (mean / mean.max()) * (area / area.max())
        pmf = power / power.sum()
        cdf = np.cumsum(pmf)
        cdf[-1] = 1.0  # so a uniform below 1 always finds an emitter
        return cls(kind, origin, edge1, edge2, normal, radius, area, radiance, pmf, cdf, emitter_of,
                   one_kind=int(kind[0]) if kind.min() == kind.max() else -1,
                   velocity=velocity if velocity.any() else None,
                   texture=texture if textured else None, textures=materials.textures if textured else None,
                   vertex_uv=np.concatenate([p[10] for p in parts], axis=-1) if textured else None,
                   rotation=np.concatenate([p[11] for p in parts], axis=-1) if textured else None)

    # -- sampling ------------------------------------------------------------

    def choose(self, u: np.ndarray) -> np.ndarray:
        """Emitter indices for uniforms ``u (N,)``, each with probability ``pmf``."""
        return np.minimum(np.searchsorted(self.cdf, u, side="right"), len(self) - 1)

    def sample(self, reference: np.ndarray, u_choice: np.ndarray, u: np.ndarray, time=None) -> LightSample:
        """One light sample per reference point.

        Parameters
        ----------
        reference : ndarray of shape (3, N)
            The points being lit.
        u_choice : ndarray of shape (N,)
            Uniform choosing the emitter.
        u : ndarray of shape (2, N)
            Uniforms choosing the point on it.
        time : None or ndarray of shape (N,)
            The paths' times (where moving spheres are).
        """
        ref = reference.astype(np.float64, copy=False)
        u = u.astype(np.float64, copy=False)
        n = ref.shape[1]
        # one emitter (RTOW's scenes, cornell_spheres): every sample chooses
        # it, and the caller need not draw ``u_choice`` (None); a still,
        # untextured one is read through its broadcast columns only (e None)
        if len(self) > 1:
            e = self.choose(u_choice)
        else:
            e = None if self.velocity is None and self.texture is None else np.zeros(n, dtype=np.intp)
        samplers = ((SPHERE, self._sample_spheres), (QUAD, self._sample_quads), (TRIANGLE, self._sample_triangles))
        kind = None
        if self.one_kind >= 0:
            # one kind of emitter (RTOW's scenes: quad lights): no routing,
            # no gathers and scatters of every sample (each sampler returns new arrays)
            point, normal, pdf = samplers[self.one_kind][1](e, ref, u, time)
        else:
            point, normal, pdf = np.empty((3, n)), np.empty((3, n)), np.empty(n)
            kind = self.kind.take(e)
            for code, sampler in samplers:
                sel = true_rows(kind == code)
                if sel.size:
                    p, nrm, pd = sampler(e.take(sel), gather(ref, sel), gather(u, sel),
                                         None if time is None else time.take(sel))
                    point[:, sel], normal[:, sel], pdf[sel] = p, nrm, pd
        direction = point - ref
        distance = length(direction)
        direction /= np.maximum(distance, _TINY)
        front = dot(normal, direction) < 0.0  # the light faces the reference point
        single = len(self) == 1  # its one column broadcasts: no gathers per sample
        if not single:
            pdf *= self.pmf.take(e)
        elif self.pmf[0] != 1.0:  # a lone emitter's pmf is 1: x * 1 is x
            pdf *= self.pmf[0]
        lit = front & (pdf > 0) & np.isfinite(pdf)
        if self.texture is not None:
            radiance = gather(self.radiance, e)
            if kind is None:
                kind = np.full(n, self.one_kind, dtype=self.kind.dtype)
            self._texture(radiance, e, kind, point, normal, u)
            radiance *= lit
            return LightSample(point, direction, distance, pdf, given_radiance=radiance)
        # Every emitter's column has a positive channel (its mean power is
        # positive, build's rule), so a channel of ``column * lit`` is positive
        # exactly where lit (inf * True is inf, inf * False NaN: not positive):
        # the caller need not reduce the (3, N) radiance to know which carry light.
        return LightSample(point, direction, distance, pdf, carries=lit,
                           emitter_radiance=self.radiance[:, :1] if single else gather(self.radiance, e))

    def _texture(self, radiance, e, kind, point, normal, u) -> None:
        """Textured emitters' radiance at their sampled points, written into ``radiance``.

        The sampled point's ``uv`` is the shape's own: a sphere's from its
        outward normal, a quad's ``(a, b)`` are the two uniforms, a
        triangle's its corners' uv at the square-root map's barycentrics."""
        rows = true_rows(self.texture.take(e) >= 0)
        if rows.size == 0:
            return
        er, k, ur = e.take(rows), kind.take(rows), gather(u, rows)
        uv = np.empty((2, rows.size))
        spheres = true_rows(k == SPHERE)
        uv[:, spheres] = sphere_uv(object_normal(self.rotation, er.take(spheres), gather(normal, rows.take(spheres))))
        quads = true_rows(k == QUAD)
        uv[:, quads] = gather(ur, quads)
        tris = true_rows(k == TRIANGLE)
        if tris.size:
            s = np.sqrt(ur[0].take(tris))
            b1 = ur[1].take(tris) * s
            b2 = s - b1
            corner = np.take(self.vertex_uv, er.take(tris), axis=-1)
            uv[:, tris] = (1.0 - s) * corner[0] + b1 * corner[1] + b2 * corner[2]
        radiance[:, rows] = self.textures.evaluate(self.texture.take(er), gather(point, rows), uv)

    def _columns(self, e, *arrays):
        """Each array's columns ``e``; with one emitter its single column, which
        broadcasts (the same numbers without gathering them per sample: RTOW's
        scenes have one light)."""
        if len(self) == 1:
            return [a[..., :1] for a in arrays]
        return [np.take(a, e, axis=-1) for a in arrays]

    def _centers(self, e, time):
        still = self.velocity is None or time is None
        if still and len(self) == 1:
            return self.origin[:, :1]  # broadcasts (see _columns)
        center = self.origin.take(e, axis=1)
        if still:
            return center
        return center + self.velocity.take(e, axis=1) * time

    def _sample_spheres(self, e, ref, u, time=None):
        return sample_sphere(self._centers(e, time), self.radius[:1] if len(self) == 1 else self.radius.take(e),
                             ref, u)

    def _sample_flat(self, sampler, e, ref, u):
        corner, edge1, edge2, area, normal = self._columns(e, self.origin, self.edge1, self.edge2, self.area,
                                                           self.normal)
        point, pdf_area = sampler(corner, edge1, edge2, u, area)
        return point, np.broadcast_to(normal, point.shape), area_to_solid_angle(pdf_area, ref, point, normal)

    def _sample_quads(self, e, ref, u, time=None):
        return self._sample_flat(sample_quad, e, ref, u)

    def _sample_triangles(self, e, ref, u, time=None):
        return self._sample_flat(sample_triangle, e, ref, u)

    def pdf(self, e: np.ndarray, reference: np.ndarray, point: np.ndarray, time=None) -> np.ndarray:
        """Solid-angle pdf (emitter choice included) with which :meth:`sample`
        picks the direction from ``reference (3, N)`` to ``point (3, N)`` on
        emitter ``e (N,)``: what a path that found the emitter by scattering
        needs for its MIS weight."""
        ref = reference.astype(np.float64, copy=False)
        point = point.astype(np.float64, copy=False)
        kind = self.kind.take(e)
        pdf = np.empty(e.shape[0])
        spheres = true_rows(kind == SPHERE)
        if spheres.size:
            es = e.take(spheres)
            pdf[spheres] = sphere_pdf(self._centers(es, None if time is None else time.take(spheres)),
                                      self.radius[es], gather(ref, spheres), gather(point, spheres))
        flat = true_rows(kind != SPHERE)
        if flat.size:
            ef = e.take(flat)
            pdf[flat] = area_to_solid_angle(1.0 / self.area[ef], gather(ref, flat), gather(point, flat),
                                            self.normal[:, ef])
        return pdf * self.pmf.take(e)


# -- the samplers: uniforms in, (point, [normal,] pdf) out ---------------------

def area_to_solid_angle(pdf_area, reference, point, normal):
    """``pdf_area * distance^2 / |cos theta_light|`` (0 where the direction grazes the surface)."""
    d = point - reference
    distance_squared = dot(d, d)
    cos_light = np.abs(dot(normal, d)) / np.sqrt(np.maximum(distance_squared, np.finfo(np.float64).tiny))
    with np.errstate(divide="ignore", invalid="ignore"):
        pdf = pdf_area * distance_squared / cos_light
    return np.where(cos_light > 0, pdf, 0.0)


def sample_quad(corner, u_edge, v_edge, u, area=None):
    """Points uniform on the parallelograms ``corner + a u_edge + b v_edge``; ``(point (3, N), pdf_area (N,))``.

    ``area (N,)``, if given, is the quads' area (the emitter table holds it,
    so no cross product per sample)."""
    point = corner + u[0] * u_edge + u[1] * v_edge
    if area is None:
        area = np.linalg.norm(np.cross(u_edge, v_edge, axis=0), axis=0)
    return point, 1.0 / area


def sample_triangle(v0, e1, e2, u, area=None):
    """Points uniform on triangles ``(v0, v0 + e1, v0 + e2)`` by the square-root
    map: ``b0 = 1 - sqrt(u0)`` has the density ``2 (1 - b0)`` of a uniform
    point's barycentric, and ``b1 = u1 sqrt(u0)`` is uniform along the slice.
    Returns ``(point (3, N), pdf_area (N,))``; ``area`` as for :func:`sample_quad`."""
    s = np.sqrt(u[0])
    b1 = u[1] * s
    b2 = s - b1  # b0 = 1 - s
    point = v0 + b1 * e1 + b2 * e2
    if area is None:
        area = 0.5 * np.linalg.norm(np.cross(e1, e2, axis=0), axis=0)
    return point, 1.0 / area


def _cone(center, radius, reference):
    """Axis (unit, reference -> centre), the rows whose reference lies inside
    the sphere, sin^2 and 1 - cos of the cone's half-angle, and the rows of
    small cones (None: there are none)."""
    axis = center - reference
    distance = length(axis)
    inside = true_rows(distance <= radius)
    clamped = np.maximum(distance, _TINY, out=distance)  # the distance's last use
    axis /= clamped
    sin2_max = radius / clamped
    sin2_max *= sin2_max
    small = sin2_max < SMALL_CONE_SIN2
    cos2_max = 1.0 - sin2_max
    if inside.size:  # only a reference inside has sin^2 > 1 (outside, radius / distance rounds to at most 1)
        np.maximum(0.0, cos2_max, out=cos2_max)
    one_minus_cos_max = 1.0 - np.sqrt(cos2_max, out=cos2_max)
    if small.any():  # a lamp 40 radii away: the series only where it is needed, row by row
        small = true_rows(small)
        one_minus_cos_max[small] = 0.5 * sin2_max.take(small)
    else:
        small = None
    return axis, inside, sin2_max, one_minus_cos_max, small


def _negated_frame(z):
    """``-x, -y`` for the two unit vectors ``x, y`` completing unit ``z (3,
    N)`` to an orthonormal basis (Duff et al. 2017, "Building an
    Orthonormal Basis, Revisited": branch-free), yielded row by row as
    ``(-x[i], -y[i])``: the caller combines each row before the next is
    made, so at most two rows are held (the basis whole was 5 of
    sample_sphere's ~30 (N,) arrays).

    Negated because sample_sphere wants ``-w``; each is Duff's expression
    negated exactly (``na = 1 / (sign + z2)`` is ``-a``, and ``x[2] = -sign
    z0``, ``y[2] = -z1`` come negated for free), so ``-x[i]`` here is
    bit for bit the negation of Duff's ``x[i]``, four passes fewer than
    negating the normal or the sines."""
    sign = np.copysign(1.0, z[2])
    na = 1.0 / (sign + z[2])
    nb = z[0] * z[1] * na
    s0 = sign * z[0]
    yield s0 * z[0] * na - 1.0, nb
    yield sign * nb, z[1] * z[1] * na - sign
    yield s0, z[1]


def sample_sphere(center, radius, reference, u):
    """Points on spheres seen from ``reference``, uniform in the cone they subtend.

    pbrt-v4's ``Sphere::Sample(ctx, u)``: ``cos theta`` uniform in
    ``[cos theta_max, 1]`` about the axis to the centre, then the point where
    that direction meets the sphere, computed from the angle ``alpha`` at the
    centre (more accurate than intersecting a ray).  A reference point inside
    a sphere samples it uniformly by area instead (its inside emits nothing,
    so only the pdf matters there).  ``center (3, N)`` and ``radius (N,)`` may
    also be one sphere's, ``(3, 1)`` and ``(1,)``, broadcasting.

    Returns
    -------
    point, normal : ndarray of shape (3, N)
        ``normal`` is the outward normal at ``point``.
    pdf : ndarray of shape (N,), per unit solid angle
    """
    axis, inside, sin2_max, one_minus_cos_max, small = _cone(center, radius, reference)
    cos_theta = 1.0 - one_minus_cos_max * u[0]
    sin2_theta = 1.0 - cos_theta * cos_theta
    if small is not None:
        # small cones' rows rewritten by index (elementwise: the numbers a
        # where over every row would give them, at a pass over those rows only)
        sin2_small = sin2_max.take(small) * u[0].take(small)
        cos_theta[small] = np.sqrt(np.maximum(0.0, 1.0 - sin2_small))
        sin2_theta[small] = sin2_small
    # From here each step writes into an array that is not read again (the
    # same operations, in place) and drops what it no longer needs: a light
    # sample of 29 Ki paths peaked at 13 MiB in this function, the most of any
    # stage, and a fresh worker faults in every page of its peak
    with np.errstate(divide="ignore", invalid="ignore"):
        cos_alpha = sin2_theta / sin2_max
        np.subtract(1.0, cos_alpha, out=cos_alpha)
        np.maximum(cos_alpha, 0.0, out=cos_alpha)
        np.sqrt(cos_alpha, out=cos_alpha)
        cos_alpha *= cos_theta
        sin2_theta /= np.sqrt(sin2_max, out=cos_theta)  # cos_theta's last use was the line above
        cos_alpha += sin2_theta
    del cos_theta, sin2_theta
    sin_alpha = cos_alpha * cos_alpha
    np.subtract(1.0, sin_alpha, out=sin_alpha)
    np.maximum(sin_alpha, 0.0, out=sin_alpha)
    np.sqrt(sin_alpha, out=sin_alpha)
    cos_phi, sin_phi = cos_sin_2pi(u[1])  # two float64 libm calls per sample cost ~15 % of a lamp's sample
    # The outward normal at the sampled point faces the reference point: -w
    # in the cone's frame, built row by row into one array (no (3, N)
    # temporaries).  -w = along_x (-x) + along_y (-y) - cos_alpha z, the
    # numbers of negating w (negation is exact and rounding symmetric)
    # without a pass to negate it.
    along_x, along_y = np.multiply(sin_alpha, cos_phi, out=cos_phi), np.multiply(sin_alpha, sin_phi, out=sin_phi)
    del sin_alpha
    normal = np.empty(axis.shape)
    for row, ((xi, yi), zi) in enumerate(zip(_negated_frame(axis), axis)):
        out = normal[row]
        np.multiply(along_x, xi, out=out)
        out += along_y * yi
        out -= cos_alpha * zi
    pdf = 1.0 / (2.0 * np.pi * one_minus_cos_max)
    if inside.size:
        outward = random_unit_vector(u[0].take(inside), u[1].take(inside))
        normal[:, inside] = outward
        pdf[inside] = 0.0  # set below, from the point
    point = radius * normal
    point += center
    if inside.size:
        r = np.broadcast_to(radius, pdf.shape).take(inside)
        pdf[inside] = area_to_solid_angle(1.0 / (4.0 * np.pi * r * r), gather(reference, inside),
                                          gather(point, inside), gather(normal, inside))
    return point, normal, pdf


def sphere_pdf(center, radius, reference, point):
    """The solid-angle pdf of :func:`sample_sphere` for the direction from
    ``reference`` to ``point`` on the sphere (a point of the visible cap when
    the reference is outside)."""
    _, inside, _, one_minus_cos_max, _ = _cone(center, radius, reference)
    pdf = 1.0 / (2.0 * np.pi * one_minus_cos_max)
    if inside.size:
        c, r = gather(center, inside), radius.take(inside)
        p = gather(point, inside)
        normal = (p - c) / r
        pdf[inside] = area_to_solid_angle(1.0 / (4.0 * np.pi * r * r), gather(reference, inside), p, normal)
    return pdf

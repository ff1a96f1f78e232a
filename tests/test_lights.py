"""The light samplers: chi-square tests of where their samples land, the pdf
they report against where they land and against the direction space it must
integrate to one over, each with a wrong sampler or pdf that must fail; and
the emitter table (which primitives, chosen by power)."""

import numpy as np
import pytest
from scipy import stats

from wavefront import Emissive, Lambertian, Quad, Scene, Sphere, Triangle
from wavefront.lights import (EmitterTable, area_to_solid_angle, sample_quad, sample_sphere, sample_triangle,
                              sphere_pdf)
from wavefront.sampling import random_unit_vector
from wavefront.shapes import QuadSet, TriangleSet

from .test_sampling import ACCEPT, REJECT, chi2_pvalue, project_uniforms

N = 200_000


def column(*x):
    return np.array(x, dtype=np.float64)[:, None]


def tile(v, n=N):
    return np.repeat(np.asarray(v, dtype=np.float64).reshape(-1, 1), n, axis=1)


# -- spheres: uniform in the cone they subtend -----------------------------------

CENTER, RADIUS, REF = (0.3, -0.2, 1.5), 0.7, (0.1, 0.4, -2.0)


def cone_coordinates(point, center, ref):
    """``(cos theta, phi)`` of the directions ref -> point about the axis ref -> centre,
    in a frame built here independently of the sampler's."""
    axis = center - ref
    axis /= np.linalg.norm(axis, axis=0)
    d = point - ref
    d /= np.linalg.norm(d, axis=0)
    helper = np.array([[1.0], [0.0], [0.0]])
    x = helper - (helper * axis).sum(axis=0) * axis
    x /= np.linalg.norm(x, axis=0)
    y = np.cross(axis, x, axis=0)
    cos_theta = (d * axis).sum(axis=0)
    phi = np.arctan2((d * y).sum(axis=0), (d * x).sum(axis=0)) % (2 * np.pi)
    return cos_theta, phi


def cone_pvalue(sampler, center=CENTER, radius=RADIUS, ref=REF, n=N):
    c, r, p = tile(center, n), np.full(n, radius), tile(ref, n)
    u = np.stack(project_uniforms(2, n=n))
    point, normal, pdf = sampler(c, r, p, u)
    sin2_max = radius**2 / np.sum((np.subtract(center, ref)) ** 2)
    one_minus_cos_max = sin2_max / (1 + np.sqrt(1 - sin2_max))  # 1 - cos without cancellation
    cos_theta, phi = cone_coordinates(point, c, p)
    s = np.clip((1 - cos_theta) / one_minus_cos_max, 0, 1 - 1e-12)  # uniform in [0, 1) for a uniform cone
    h, _, _ = np.histogram2d(s, phi, bins=(10, 12), range=((0, 1), (0, 2 * np.pi)))
    return chi2_pvalue(h), point, normal, pdf, one_minus_cos_max


def test_sphere_samples_are_uniform_in_the_cone_on_the_visible_cap():
    pvalue, point, normal, pdf, one_minus_cos_max = cone_pvalue(sample_sphere)
    assert pvalue > ACCEPT
    c = column(*CENTER)
    np.testing.assert_allclose(np.linalg.norm(point - c, axis=0), RADIUS, rtol=1e-12)
    np.testing.assert_allclose(normal, (point - c) / RADIUS, atol=1e-12)
    assert ((normal * (column(*REF) - point)).sum(axis=0) > -1e-12).all()  # every point faces the reference
    np.testing.assert_allclose(pdf, 1 / (2 * np.pi * one_minus_cos_max), rtol=1e-12)


def test_small_cone_branch_is_uniform_too():
    """Far away (sin^2 theta_max below pbrt's 1.5 degree threshold) the series branch runs."""
    pvalue, _, _, pdf, one_minus_cos_max = cone_pvalue(sample_sphere, radius=0.05, ref=(0.1, 0.4, -60.0))
    assert pvalue > ACCEPT
    np.testing.assert_allclose(pdf, 1 / (2 * np.pi * one_minus_cos_max), rtol=1e-6)


def wrong_cap_by_area(center, radius, ref, u):
    """A plausible bug: points uniform by *area* on the visible cap, reported with the cone's pdf."""
    axis = center - ref
    dist = np.linalg.norm(axis, axis=0)
    axis /= dist
    cos_alpha_max = radius / dist  # the cap's edge, seen from the centre
    cos_alpha = 1 - u[0] * (1 - cos_alpha_max)  # uniform in area on a spherical cap
    sin_alpha = np.sqrt(1 - cos_alpha**2)
    helper = np.array([[0.0], [0.0], [1.0]])
    x = np.cross(axis, helper, axis=0)
    x /= np.linalg.norm(x, axis=0)
    y = np.cross(axis, x, axis=0)
    phi = 2 * np.pi * u[1]
    normal = -(sin_alpha * np.cos(phi) * x + sin_alpha * np.sin(phi) * y + cos_alpha * axis)
    point = center + radius * normal
    _, good_normal, pdf = sample_sphere(center, radius, ref, u)
    return point, normal, pdf


def test_negative_control_sphere_cap_sampled_by_area_is_rejected():
    assert cone_pvalue(wrong_cap_by_area)[0] < REJECT


def test_sphere_seen_from_inside_is_sampled_by_area():
    n = N
    u = np.stack(project_uniforms(2, n=n))
    c, r, ref = tile(CENTER, n), np.full(n, RADIUS), tile((0.5, -0.1, 1.4), n)
    point, normal, pdf = sample_sphere(c, r, ref, u)
    z = ((point - c) / RADIUS)[2]
    assert chi2_pvalue(np.histogram(z, bins=20, range=(-1, 1))[0]) > ACCEPT  # Archimedes: z uniform
    assert np.isfinite(pdf).all() and (pdf > 0).all()
    np.testing.assert_allclose(sphere_pdf(c, r, ref, point), pdf, rtol=1e-12)


# -- quads and triangles: uniform by area ----------------------------------------

CORNER, U_EDGE, V_EDGE = (0.2, 1.0, -0.4), (1.3, 0.1, 0.2), (-0.3, 0.2, 0.9)


def quad_pvalue(sampler, n=N):
    u = np.stack(project_uniforms(2, n=n))
    point, pdf_area = sampler(tile(CORNER, n), tile(U_EDGE, n), tile(V_EDGE, n), u)
    basis = np.stack((U_EDGE, V_EDGE), axis=1)  # (3, 2)
    ab, *_ = np.linalg.lstsq(basis, point - column(*CORNER), rcond=None)
    h, _, _ = np.histogram2d(ab[0], ab[1], bins=12, range=((0, 1), (0, 1)))
    return chi2_pvalue(h), ab, pdf_area


def test_quad_samples_are_uniform_by_area():
    pvalue, ab, pdf_area = quad_pvalue(sample_quad)
    assert pvalue > ACCEPT
    assert ab.min() >= -1e-12 and ab.max() <= 1 + 1e-12
    np.testing.assert_allclose(pdf_area, 1 / np.linalg.norm(np.cross(U_EDGE, V_EDGE)), rtol=1e-12)


def test_negative_control_quad_sampler_squaring_a_uniform_is_rejected():
    def wrong(corner, u_edge, v_edge, u):
        return sample_quad(corner, u_edge, v_edge, np.stack((u[0], u[1] ** 2)))

    assert quad_pvalue(wrong)[0] < REJECT


V0, V1, V2 = np.array((0.1, 0.0, 0.3)), np.array((1.2, 0.3, -0.2)), np.array((0.4, 1.1, 0.5))


def triangle_pvalue(sampler, n=N, bins=10):
    """Barycentrics ``(b1, b2)`` binned on a grid over the unit square: cells
    below the diagonal hold area ``h^2``, cells on it ``h^2 / 2``."""
    u = np.stack(project_uniforms(2, n=n))
    point, pdf_area = sampler(tile(V0, n), tile(V1 - V0, n), tile(V2 - V0, n), u)
    basis = np.stack((V1 - V0, V2 - V0), axis=1)
    b, *_ = np.linalg.lstsq(basis, point - V0[:, None], rcond=None)
    assert b.min() >= -1e-9 and b.sum(axis=0).max() <= 1 + 1e-9
    i = np.minimum((b[0] * bins).astype(int), bins - 1)
    j = np.minimum((b[1] * bins).astype(int), bins - 1)
    counts = np.bincount(i * bins + j, minlength=bins * bins).reshape(bins, bins)
    ii, jj = np.meshgrid(np.arange(bins), np.arange(bins), indexing="ij")
    weight = np.where(ii + jj < bins - 1, 1.0, np.where(ii + jj == bins - 1, 0.5, 0.0))
    inside = weight > 0
    assert counts[~inside].sum() <= n * 1e-6  # only rounding puts a sample past the diagonal
    expected = weight[inside] / weight[inside].sum() * counts[inside].sum()
    return chi2_pvalue(counts[inside], expected), pdf_area


def test_triangle_samples_are_uniform_by_area():
    pvalue, pdf_area = triangle_pvalue(sample_triangle)
    assert pvalue > ACCEPT
    np.testing.assert_allclose(pdf_area, 2 / np.linalg.norm(np.cross(V1 - V0, V2 - V0)), rtol=1e-12)


def test_negative_control_triangle_without_the_square_root_is_rejected():
    def wrong(v0, e1, e2, u):  # b0 = 1 - u0: the classic mistake, crowding the v0 corner
        b1 = u[1] * u[0]
        return v0 + b1 * e1 + (u[0] - b1) * e2, 2 / np.linalg.norm(np.cross(e1, e2, axis=0), axis=0)

    assert triangle_pvalue(wrong)[0] < REJECT


# -- the pdfs MIS uses: consistent with the samples, integrating to one ----------

def single_emitter(scene_shape, kind_key):
    materials = {"lamp": Emissive((4, 4, 4))}
    scene = Scene(materials=materials, **{kind_key: [scene_shape]})
    cs = scene.compile()
    return cs.emitters


EMITTERS = {
    "sphere": lambda: single_emitter(Sphere(CENTER, RADIUS, "lamp"), "spheres"),
    "quad": lambda: single_emitter(Quad(CORNER, U_EDGE, V_EDGE, "lamp"), "quads"),
    "triangle": lambda: single_emitter(Triangle((tuple(V0), tuple(V1), tuple(V2)), "lamp"), "triangles"),
}
# reference points in front of each light (the quad's and triangle's front is cross(u, v)'s side)
_QUAD_FRONT = np.cross(U_EDGE, V_EDGE) / np.linalg.norm(np.cross(U_EDGE, V_EDGE))
REFS = {"sphere": REF, "quad": tuple(np.add(CORNER, 0.5 * np.add(U_EDGE, V_EDGE)) + 1.5 * _QUAD_FRONT),
        "triangle": (0.3, 0.2, 2.0)}


def hits_light(kind, emitters, ref, direction):
    """Whether rays from ``ref`` hit the light, by the engine's exact tests
    (spheres: the quadratic), and where."""
    n = direction.shape[1]
    if kind == "sphere":
        oc = column(*CENTER) - ref
        h = (direction * oc).sum(axis=0)
        disc = h * h - ((oc * oc).sum(axis=0) - RADIUS**2)
        t = np.where(disc >= 0, h - np.sqrt(np.maximum(disc, 0)), np.inf)
        t = np.where(t > 0, t, np.inf)
    elif kind == "quad":
        qs = QuadSet(column(*CORNER), column(*U_EDGE), column(*V_EDGE), [0])
        t = qs.t_pairs(np.zeros(n, dtype=np.int64), ref, direction)
    else:
        ts = TriangleSet(V0[:, None], V1[:, None], V2[:, None], [0])
        t = ts.t_pairs(np.zeros(n, dtype=np.int64), ref, direction)
    hit = np.isfinite(t)
    return hit, ref + np.where(hit, t, 0.0) * direction


def pdf_integral(kind, pdf_of, n=400_000, ref=None):
    """``int pdf dw`` over all directions from the reference point, by uniform
    direction sampling: ``4 pi E[pdf(w)]``; returns (estimate, standard error)."""
    emitters = EMITTERS[kind]()
    u0, u1 = project_uniforms(2, n=n, seed=11)
    direction = random_unit_vector(u0, u1)
    ref = tile(REFS[kind] if ref is None else ref, n)
    hit, point = hits_light(kind, emitters, ref, direction)
    values = np.zeros(n)
    idx = np.flatnonzero(hit)
    values[idx] = 4 * np.pi * pdf_of(emitters, np.zeros(idx.size, dtype=np.int64), ref[:, idx], point[:, idx])
    return values.mean(), values.std() / np.sqrt(n)


@pytest.mark.parametrize("kind", sorted(EMITTERS))
def test_light_pdf_integrates_to_one_over_directions(kind):
    estimate, error = pdf_integral(kind, EmitterTable.pdf)
    assert abs(estimate - 1) < 5 * error + 1e-3, (estimate, error)


def test_negative_control_a_pdf_without_the_cosine_does_not_integrate_to_one():
    def wrong(emitters, e, ref, point):  # area pdf times distance^2, the cosine forgotten
        d2 = ((point - ref) ** 2).sum(axis=0)
        return d2 / emitters.area[e]

    # close to the quad and off to one side, where the cosine varies most
    oblique = np.add(CORNER, 0.5 * np.add(U_EDGE, V_EDGE)) + 0.3 * _QUAD_FRONT + 0.8 * np.asarray(U_EDGE)
    estimate, error = pdf_integral("quad", EmitterTable.pdf, ref=oblique)
    assert abs(estimate - 1) < 5 * error + 1e-3, (estimate, error)
    estimate, error = pdf_integral("quad", wrong, ref=oblique)
    assert abs(estimate - 1) > 10 * error + 1e-3, (estimate, error)


@pytest.mark.parametrize("kind", sorted(EMITTERS))
def test_sampled_pdf_is_the_pdf_mis_evaluates(kind):
    """``sample`` and ``pdf`` agree on every sample, and the samples face the reference point."""
    emitters = EMITTERS[kind]()
    n = 20_000
    u0, u1, u2 = project_uniforms(3, n=n)
    ref = tile(REFS[kind], n)
    s = emitters.sample(ref, u0, np.stack((u1, u2)))
    assert (s.radiance > 0).all()  # front side seen from REFS
    np.testing.assert_allclose(emitters.pdf(np.zeros(n, dtype=np.int64), ref, s.point), s.pdf, rtol=1e-9)
    np.testing.assert_allclose(np.linalg.norm(s.direction, axis=0), 1, rtol=1e-12)
    np.testing.assert_allclose(ref + s.distance * s.direction, s.point, atol=1e-9)


def test_light_sample_from_behind_a_one_sided_emitter_carries_nothing():
    emitters = EMITTERS["quad"]()
    n = 1000
    u0, u1, u2 = project_uniforms(3, n=n)
    behind = tile(np.add(CORNER, 0.5 * np.add(U_EDGE, V_EDGE)) - _QUAD_FRONT, n)
    s = emitters.sample(behind, u0, np.stack((u1, u2)))
    assert (s.radiance == 0).all() and (s.pdf > 0).all()


def test_area_to_solid_angle_is_zero_at_grazing():
    pdf = area_to_solid_angle(np.ones(1), column(0, 0, 0), column(1, 0, 0), column(0, 1, 0))
    assert pdf[0] == 0


# -- the emitter table -----------------------------------------------------------

def mixed_scene():
    materials = {"white": Lambertian((0.5, 0.5, 0.5)), "lamp": Emissive((4, 4, 4)), "dim": Emissive((0, 1, 0)),
                 "off": Emissive((0, 0, 0))}
    return Scene(
        materials=materials,
        spheres=[Sphere((0, 0, 0), 1, "white"), Sphere((3, 0, 0), 0.5, "lamp"), Sphere((0, 5, 0), 1, "off")],
        quads=[Quad((0, 3, 0), (1, 0, 0), (0, 0, 2), "dim"), Quad((0, -3, 0), (1, 0, 0), (0, 0, 1), "white")],
        triangles=[Triangle(((0, 0, 4), (2, 0, 4), (0, 2, 4)), "lamp")],
    )


def test_emitter_table_holds_every_emissive_primitive_and_chooses_by_power():
    cs = mixed_scene().compile()
    e = cs.emitters
    # scene-wide order: spheres 0-2, quads 3-4, triangle 5; the black emitter is left out
    np.testing.assert_array_equal(e.emitter_of, [-1, 0, -1, 1, -1, 2])
    np.testing.assert_array_equal(e.kind, [0, 1, 2])
    area = np.array([4 * np.pi * 0.25, 2.0, 2.0])
    power = np.array([4.0, 1 / 3, 4.0]) * area
    np.testing.assert_allclose(e.pmf, power / power.sum(), rtol=1e-12)
    u = project_uniforms(1)[0]
    counts = np.bincount(e.choose(u), minlength=3)
    assert stats.chisquare(counts, e.pmf * u.size).pvalue > ACCEPT


def test_scene_without_emitters_has_an_empty_table():
    scene = Scene(materials={"m": Lambertian()}, spheres=[Sphere((0, 0, 0), 1, "m")])
    assert len(scene.compile().emitters) == 0


def test_an_emitter_of_astronomical_power_is_still_sampled():
    """Power = radiance x area overflowed to inf and made the pmf NaN: the light vanished."""
    import numpy as np

    from wavefront import Emissive, Lambertian, Quad, Scene

    # the brightest colour allowed (MAX_COLOR, 1e30) on the largest quad allowed (edges ~1e76): power
    # 4e182 stays finite now, but the pmf must still be a distribution (it was NaN at 1e300 x 4e12)
    scene = Scene(quads=[Quad((-1e76, 10, -1e76), (2e76, 0, 0), (0, 0, 2e76), "lamp"),
                         Quad((-1, 0, -1), (0, 0, 2), (2, 0, 0), "floor")],
                  materials={"lamp": Emissive((1e30, 1e30, 1e30)), "floor": Lambertian()}, width=4, height=4)
    table = scene.compile().emitters
    assert np.isfinite(table.pmf).all() and np.isclose(table.pmf.sum(), 1.0)

"""Laws of reflection and refraction, checked by hypothesis."""

import numpy as np
from hypothesis import assume, given
from hypothesis import strategies as st

from wavefront.vecmath import dot, length, normalize, reflect, refract, schlick

coord = st.floats(-1e3, 1e3, allow_nan=False, allow_infinity=False)
vectors = st.tuples(coord, coord, coord).map(lambda t: np.array(t, dtype=np.float64)[:, None])


def unit(v):
    assume(length(v)[0] > 1e-6)
    return normalize(v)


@given(vectors, vectors)
def test_reflect_preserves_length(v, n):
    n = unit(n)
    r = reflect(v, n)
    np.testing.assert_allclose(length(r), length(v), rtol=1e-9, atol=1e-9)


@given(vectors, vectors)
def test_reflect_angle_of_incidence_equals_angle_of_reflection(v, n):
    n = unit(n)
    r = reflect(v, n)
    np.testing.assert_allclose(dot(r, n), -dot(v, n), rtol=1e-9, atol=1e-9 * (1 + length(v)[0]))


@given(vectors, vectors)
def test_reflect_is_coplanar_and_keeps_tangential_part(v, n):
    n = unit(n)
    r = reflect(v, n)
    diff = r - v  # parallel to n
    np.testing.assert_allclose(np.cross(diff[:, 0], n[:, 0]), 0.0, atol=1e-9 * (1 + length(v)[0]))
    tangential = lambda x: x - dot(x, n) * n  # noqa: E731
    np.testing.assert_allclose(tangential(r), tangential(v), atol=1e-9 * (1 + length(v)[0]))


@given(vectors, vectors)
def test_reflect_is_an_involution(v, n):
    n = unit(n)
    np.testing.assert_allclose(reflect(reflect(v, n), n), v, atol=1e-9 * (1 + length(v)[0]))


def incident_and_normal(v, n):
    """A unit incident direction and a unit normal facing against it."""
    v, n = unit(v), unit(n)
    c = dot(v, n)[0]
    assume(abs(c) > 1e-3)
    return v, (n if c < 0 else -n)


@given(vectors, vectors, st.floats(0.2, 5.0), st.floats(0.0, 0.999999))
def test_refract_obeys_snell_and_stays_unit(v, n, ratio, below_critical):
    v, n = incident_and_normal(v, n)
    sin_i = np.linalg.norm(np.cross(v[:, 0], n[:, 0]))  # well conditioned near 0 and 90 degrees
    if ratio * sin_i >= 1:  # choose a ratio short of total internal reflection instead of rejecting
        ratio = below_critical / sin_i
    t = refract(v, n, ratio)
    np.testing.assert_allclose(length(t), 1.0, rtol=1e-9)
    assert -dot(t, n)[0] > 0  # goes through the surface
    sin_t = np.linalg.norm(np.cross(t[:, 0], n[:, 0]))
    np.testing.assert_allclose(ratio * sin_i, sin_t, atol=1e-7)
    # the refracted ray stays in the plane of incidence
    np.testing.assert_allclose(np.dot(np.cross(v[:, 0], n[:, 0]), t[:, 0]), 0.0, atol=1e-9)


@given(vectors, vectors)
def test_refract_with_ratio_one_is_identity(v, n):
    v, n = incident_and_normal(v, n)
    np.testing.assert_allclose(refract(v, n, 1.0), v, atol=1e-9)


@given(vectors, vectors, st.floats(1.01, 5.0), st.floats(0.0, 1.0))
def test_dielectric_reflects_past_the_critical_angle(v, n, ratio, u):
    """Past the critical angle (ratio * sin > 1) the glass kernel always mirrors."""
    from wavefront.materials import scatter_dielectric

    v, n = incident_and_normal(v, n)
    sin_i = np.linalg.norm(np.cross(v[:, 0], n[:, 0]))
    assume(abs(ratio * sin_i - 1) > 1e-6)
    # back face: the ray leaves glass of index `ratio` into air
    _, d, absorbed = scatter_dielectric(v, n, np.array([False]), np.array([ratio]), np.array([[u]]))
    assert not absorbed[0]
    if ratio * sin_i > 1:
        np.testing.assert_allclose(d, reflect(v, n), atol=1e-9)
    else:
        assert dot(d, n)[0] != 0


@given(st.floats(0.1, 10.0))
def test_schlick_endpoints(ratio):
    r0 = ((1 - ratio) / (1 + ratio)) ** 2
    np.testing.assert_allclose(schlick(1.0, ratio), r0)  # normal incidence, theta = 0
    np.testing.assert_allclose(schlick(0.0, ratio), 1.0)  # grazing, theta = 90 degrees


@given(st.floats(0.1, 10.0))
def test_schlick_is_monotone_in_angle(ratio):
    cosines = np.linspace(1.0, 0.0, 200)  # theta increasing from 0 to 90 degrees
    r = schlick(cosines, ratio)
    assert np.all(np.diff(r) >= -1e-15)
    assert np.all((r >= 0) & (r <= 1))


@given(vectors)
def test_normalize_gives_unit_length(v):
    assume(length(v)[0] > 1e-9)
    np.testing.assert_allclose(length(normalize(v)), 1.0, rtol=1e-12)

"""Transforms: composition order, the right-hand rule, what a sphere may undergo."""

import math

import numpy as np
import pytest
from hypothesis import given
from hypothesis import strategies as st
from scipy.spatial.transform import Rotation

from wavefront import SceneError
from wavefront.transform import Transform

finite = st.floats(-10, 10)
vec = st.tuples(finite, finite, finite)


def test_rotate_y_is_rtows_rotate_y():
    # RTOW book 2: x' = cos(t) x + sin(t) z, z' = -sin(t) x + cos(t) z
    t = np.radians(15)
    p = np.array([[1.0], [2.0], [3.0]])
    expect = [np.cos(t) * 1 + np.sin(t) * 3, 2, -np.sin(t) * 1 + np.cos(t) * 3]
    np.testing.assert_allclose(Transform.rotate((0, 1, 0), 15).points(p)[:, 0], expect, atol=1e-12)


def test_right_hand_rule():
    x = np.array([[1.0], [0], [0]])
    np.testing.assert_allclose(Transform.rotate((0, 0, 1), 90).points(x)[:, 0], [0, 1, 0], atol=1e-12)
    np.testing.assert_allclose(Transform.rotate((0, 0, 5), 90).points(x)[:, 0], [0, 1, 0], atol=1e-12)  # axis length


@given(vec, st.floats(-720, 720), vec)
def test_rotation_matches_scipy(axis, angle, point):
    axis = np.asarray(axis)
    if np.linalg.norm(axis) < 1e-3:
        axis = np.array([0.0, 0, 1])
    ours = Transform.rotate(axis, angle).points(np.asarray(point)[:, None])[:, 0]
    theirs = Rotation.from_rotvec(axis / np.linalg.norm(axis) * np.radians(angle)).apply(point)
    np.testing.assert_allclose(ours, theirs, atol=1e-9)


def test_steps_apply_first_to_last():
    t = Transform.scale(2).then(Transform.translate((1, 0, 0)))  # scale, then move
    np.testing.assert_allclose(t.points(np.array([[1.0], [1], [1]]))[:, 0], [3, 2, 2])
    u = Transform.translate((1, 0, 0)).then(Transform.scale(2))  # move, then scale
    np.testing.assert_allclose(u.points(np.array([[1.0], [1], [1]]))[:, 0], [4, 2, 2])


@given(vec, st.floats(-180, 180), st.floats(0.1, 5), vec, st.floats(0.5, 2))
def test_similarities_are_recognised_and_stretches_are_not(axis, angle, scale, offset, stretch):
    axis = np.asarray(axis) if np.linalg.norm(axis) > 1e-3 else np.array([1.0, 0, 0])
    t = Transform.rotate(axis, angle).then(Transform.scale(scale)).then(Transform.translate(offset))
    assert np.isclose(t.uniform_scale(), scale)
    if abs(stretch - 1) > 1e-3:
        assert t.then(Transform.scale((1, stretch, 1))).uniform_scale() is None


@given(st.tuples(st.floats(0.2, 5), st.floats(0.2, 5), st.floats(0.2, 5)), vec, vec, st.floats(-180, 180))
def test_normals_stay_perpendicular_under_any_scale(scale, a, b, angle):
    """A transformed normal is perpendicular to every transformed tangent."""
    a, b = np.asarray(a), np.asarray(b)
    n = np.cross(a, b)
    if np.linalg.norm(n) < 1e-3:
        return
    t = Transform.scale(scale).then(Transform.rotate((1, 2, 3), angle))
    tn = t.normals(n[:, None])[:, 0]
    for tangent in (a, b):
        tt = t.vectors(tangent[:, None])[:, 0]
        assert abs(np.dot(tn, tt)) <= 1e-9 * np.linalg.norm(tn) * np.linalg.norm(tt) + 1e-12


def test_a_huge_or_tiny_axis_is_just_a_direction():
    x = np.array([[1.0], [0], [0]])
    for scale in (1e300, 1e-300):
        np.testing.assert_allclose(Transform.rotate((0, 0, scale), 90).points(x)[:, 0], [0, 1, 0], atol=1e-12)


@pytest.mark.parametrize("make,where,problem", [
    # a zero axis gave a matrix of NaN (the scene file refused it; Python did not)
    (lambda: Transform.rotate((0, 0, 0), 30), "<Transform.rotate>: axis: ", "must not be zero"),
    (lambda: Transform.rotate((math.nan, 0, 1), 30), "<Transform.rotate>: axis[0]: ", "finite"),
    (lambda: Transform.rotate((0, math.inf, 1), 30), "<Transform.rotate>: axis[1]: ", "finite"),
    (lambda: Transform.rotate((0, 1), 30), "<Transform.rotate>: axis: ", "3 numbers"),
    (lambda: Transform.rotate((0, 1, 0), math.nan), "<Transform.rotate>: angle_degrees: ", "finite"),
    (lambda: Transform.rotate((0, 1, 0), math.inf), "<Transform.rotate>: angle_degrees: ", "finite"),
    (lambda: Transform.rotate((0, 1, 0), "30"), "<Transform.rotate>: angle_degrees: ", "expected a number"),
    (lambda: Transform.translate((math.nan, 0, 0)), "<Transform.translate>: offset[0]: ", "finite"),
    (lambda: Transform.translate((0, 0, -math.inf)), "<Transform.translate>: offset[2]: ", "finite"),
    (lambda: Transform.translate((0, 1)), "<Transform.translate>: offset: ", "3 numbers"),
    (lambda: Transform.scale(math.nan), "<Transform.scale>: factor: ", "finite"),
    (lambda: Transform.scale((1, math.inf, 1)), "<Transform.scale>: factor[1]: ", "finite"),
    (lambda: Transform.scale(0), "<Transform.scale>: factor: ", "must not be zero"),
    (lambda: Transform.scale((1, 0.0, 1)), "<Transform.scale>: factor: ", "must not be zero"),
    (lambda: Transform.scale(True), "<Transform.scale>: factor: ", "expected a number"),
    (lambda: Transform.from_array(np.eye(3)), "<Transform>: matrix: ", "4x4"),
])
def test_python_constructors_refuse_what_the_scene_file_refuses(make, where, problem):
    with pytest.raises(SceneError) as e:  # a ValueError
        make()
    assert str(e.value).startswith(where) and problem in str(e.value), str(e.value)


def test_constructors_take_numpy_values_and_huge_axes():
    assert Transform.scale(np.array(2.0)) == Transform.scale(2) == Transform.scale(np.array([2, 2, 2]))
    assert Transform.translate(np.array([1, 2, 3])) == Transform.translate((1.0, 2.0, 3.0))
    assert Transform.rotate(np.array([0, 1, 0]), np.float32(30)) == Transform.rotate((0, 1, 0), 30)
    # scaled to about 1 before its norm is taken: no overflow, and the YAML path does not call it zero
    np.testing.assert_allclose(Transform.rotate((1e308, 1e308, 0), 30).array, Transform.rotate((1, 1, 0), 30).array)

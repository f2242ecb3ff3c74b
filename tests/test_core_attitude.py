"""Attitude conversions through the bindings, against SciPy's Rotation as an independent implementation."""

import math

import numpy as np
from hypothesis import given, settings
from hypothesis import strategies as st
from hypothesis.extra.numpy import arrays
from scipy.spatial.transform import Rotation

from gpsins import _core

RNG = np.random.default_rng(2)


def to_scipy_quat(q_wxyz):
    return np.asarray(q_wxyz)[..., [1, 2, 3, 0]]


def test_rotvec_and_dcm_match_scipy():
    rv = RNG.normal(size=(1000, 3))
    rv *= (RNG.uniform(0, math.pi, 1000) / np.linalg.norm(rv, axis=1))[:, None]
    q = _core.quat_from_rotvec(rv)
    np.testing.assert_allclose(_core.dcm_from_quat(q), Rotation.from_rotvec(rv).as_matrix(), atol=1e-14)
    np.testing.assert_allclose(_core.rotvec_from_quat(q), rv, atol=1e-12)


def test_euler_is_intrinsic_zyx_like_scipy():
    ypr = np.column_stack([RNG.uniform(-math.pi, math.pi, 500), RNG.uniform(-1.5, 1.5, 500),
                           RNG.uniform(-math.pi, math.pi, 500)])
    ref = Rotation.from_euler("ZYX", ypr).as_matrix()  # capitals: intrinsic
    np.testing.assert_allclose(_core.dcm_from_euler(ypr), ref, atol=1e-14)
    np.testing.assert_allclose(_core.euler_from_dcm(ref), ypr, atol=1e-10)
    q = _core.quat_from_euler(ypr)
    np.testing.assert_allclose(np.abs(np.sum(to_scipy_quat(q) * Rotation.from_matrix(ref).as_quat(), axis=1)), 1.0,
                               atol=1e-12)


def test_hamilton_product_matches_scipy_composition():
    a = Rotation.random(100, random_state=3)
    b = Rotation.random(100, random_state=4)
    qa = a.as_quat()[:, [3, 0, 1, 2]]
    qb = b.as_quat()[:, [3, 0, 1, 2]]
    np.testing.assert_allclose(_core.dcm_from_quat(_core.quat_multiply(qa, qb)), (a * b).as_matrix(), atol=1e-14)
    # One quaternion broadcast against many.
    np.testing.assert_allclose(_core.quat_multiply(qa[0], qb)[5], _core.quat_multiply(qa[0], qb[5]), atol=0)


def test_body_to_ecef_round_trip_along_a_trajectory():
    llh = np.column_stack([np.radians(np.linspace(-80, 80, 50)), np.radians(np.linspace(-170, 170, 50)),
                           np.linspace(0, 1000, 50)])
    ypr = np.column_stack([np.linspace(-3, 3, 50), np.linspace(-1.2, 1.2, 50), np.linspace(-2, 2, 50)])
    q = _core.quat_body_to_ecef(ypr, llh)
    np.testing.assert_allclose(_core.euler_from_body_to_ecef(q, llh), ypr, atol=1e-10)


unit_quats = arrays(np.float64, 4, elements=st.floats(-1, 1)).filter(lambda v: np.linalg.norm(v) > 1e-3)


@settings(max_examples=300, deadline=None)
@given(unit_quats)
def test_quat_matrix_rotvec_round_trip_property(v):
    q = v / np.linalg.norm(v)
    c = _core.dcm_from_quat(q)
    np.testing.assert_allclose(c @ c.T, np.eye(3), atol=1e-14)
    q2 = _core.quat_from_dcm(c)
    assert abs(abs(np.dot(q, q2)) - 1.0) < 1e-12
    q3 = _core.quat_from_rotvec(_core.rotvec_from_quat(q))
    assert abs(abs(np.dot(q, q3)) - 1.0) < 1e-12


@settings(max_examples=300, deadline=None)
@given(st.floats(-math.pi, math.pi), st.floats(-math.pi / 2, math.pi / 2), st.floats(-math.pi, math.pi))
def test_euler_round_trip_property_including_gimbal_lock(yaw, pitch, roll):
    c = _core.dcm_from_euler([yaw, pitch, roll])
    back = _core.euler_from_dcm(c)
    np.testing.assert_allclose(_core.dcm_from_euler(back), c, atol=1e-12)

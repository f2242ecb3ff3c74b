"""The C++ Earth model through the bindings, against pymap3d and published values."""

import math

import numpy as np
import pymap3d
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from gpsins import _core

RNG = np.random.default_rng(1)


def random_llh(n):
    lat = np.arcsin(RNG.uniform(-1, 1, n))
    lon = RNG.uniform(-math.pi, math.pi, n)
    h = RNG.uniform(-5000.0, 100000.0, n)
    return np.column_stack([lat, lon, h])


def test_geodetic_to_ecef_matches_pymap3d():
    llh = random_llh(2000)
    x, y, z = pymap3d.geodetic2ecef(llh[:, 0], llh[:, 1], llh[:, 2], deg=False)
    np.testing.assert_allclose(_core.geodetic_to_ecef(llh), np.column_stack([x, y, z]), rtol=0, atol=1e-7)


def test_ecef_to_geodetic_matches_pymap3d():
    llh = random_llh(2000)
    xyz = _core.geodetic_to_ecef(llh)
    lat, lon, h = pymap3d.ecef2geodetic(xyz[:, 0], xyz[:, 1], xyz[:, 2], deg=False)
    out = _core.ecef_to_geodetic(xyz)
    np.testing.assert_allclose(out[:, 0], lat, atol=1e-11)
    np.testing.assert_allclose(out[:, 1], lon, atol=1e-11)
    np.testing.assert_allclose(out[:, 2], h, atol=1e-4)  # pymap3d's own iteration stops near 1e-5 m
    np.testing.assert_allclose(out, llh, atol=1e-8)


def test_enu_and_ned_match_pymap3d():
    ref = np.array([math.radians(59.37), math.radians(17.95), 40.0])
    llh = ref + np.column_stack([RNG.normal(0, 1e-3, 500), RNG.normal(0, 1e-3, 500), RNG.normal(0, 50, 500)])
    xyz = _core.geodetic_to_ecef(llh)
    e, n, u = pymap3d.ecef2enu(xyz[:, 0], xyz[:, 1], xyz[:, 2], *ref, deg=False)
    np.testing.assert_allclose(_core.ecef_to_enu(xyz, ref), np.column_stack([e, n, u]), atol=1e-7)
    nn, ee, d = pymap3d.ecef2ned(xyz[:, 0], xyz[:, 1], xyz[:, 2], *ref, deg=False)
    ned = _core.ecef_to_ned(xyz, ref)
    np.testing.assert_allclose(ned, np.column_stack([nn, ee, d]), atol=1e-7)
    np.testing.assert_allclose(_core.ned_to_ecef(ned, ref), xyz, atol=1e-7)
    np.testing.assert_allclose(_core.enu_to_ecef(np.column_stack([e, n, u]), ref), xyz, atol=1e-7)


def test_rotation_columns_are_the_local_axes():
    lat, lon = 0.3, -1.2
    c = _core.rot_ned_to_ecef(lat, lon)
    ref = np.array([lat, lon, 0.0])
    # One metre north, east, down expressed in ECEF must be the matrix columns.
    for k in range(3):
        step = np.zeros(3)
        step[k] = 1.0
        np.testing.assert_allclose(_core.ned_to_ecef(step, ref) - _core.geodetic_to_ecef(ref), c[:, k], atol=1e-8)


def test_normal_gravity_published_values():
    assert _core.normal_gravity(0.0, 0.0) == pytest.approx(9.7803253359, abs=1e-10)
    assert _core.normal_gravity(math.pi / 2, 0.0) == pytest.approx(9.8321849378, abs=1e-10)
    # The report's 9.8185 at 59 deg 21' N (its printed formula is approximate, ERRATA.md).
    assert abs(_core.normal_gravity(math.radians(59 + 21 / 60), 0.0) - 9.8185) < 1e-3
    # The report's corrected 1967-style formula (ERRATA: '+' is a product) gives 9.8187 (ERRATA.md), 6e-5 above WGS-84.
    phi = math.radians(59 + 21 / 60)
    report = 9.78049 * (1 + 0.0052884 * math.sin(phi) ** 2 - 0.0000059 * math.sin(2 * phi) ** 2)
    assert report == pytest.approx(9.8187, abs=5e-5)
    assert _core.normal_gravity(phi, 0.0) == pytest.approx(9.81866, abs=5e-6)


def test_gravity_vector_points_down_the_normal():
    llh = random_llh(200)
    llh[:, 2] = RNG.uniform(-100, 3000, 200)
    g = _core.normal_gravity_ecef(_core.geodetic_to_ecef(llh))
    for row, gv in zip(llh, g):
        down = _core.rot_ned_to_ecef(row[0], row[1])[:, 2]
        np.testing.assert_allclose(gv, _core.normal_gravity(row[0], row[2]) * down, atol=1e-12)


def test_shape_errors_name_the_argument():
    with pytest.raises(ValueError, match=r"geodetic_to_ecef: argument 'llh' must have shape \(\.\.\., 3\), got \(4,\)"):
        _core.geodetic_to_ecef(np.zeros(4))
    with pytest.raises(ValueError, match="ref_llh"):
        _core.ecef_to_ned(np.zeros((2, 3)), np.zeros((2, 3)))


def test_leading_shapes_are_kept():
    llh = random_llh(24).reshape(2, 4, 3, 3)[..., 0, :]
    assert _core.geodetic_to_ecef(llh).shape == (2, 4, 3)


@settings(max_examples=300, deadline=None)
@given(
    st.floats(-90, 90), st.floats(-180, 180, exclude_max=True), st.floats(-5000, 100000)
)
def test_geodetic_round_trip_property(lat_deg, lon_deg, h):
    llh = np.array([math.radians(lat_deg), math.radians(lon_deg), h])
    back = _core.ecef_to_geodetic(_core.geodetic_to_ecef(llh))
    assert abs(back[2] - h) < 1e-8
    assert abs(back[0] - llh[0]) < 1e-12
    if abs(lat_deg) < 90:
        assert abs(math.remainder(back[1] - llh[1], 2 * math.pi)) * math.cos(llh[0]) < 1e-12

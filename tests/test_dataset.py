"""Data-set TOML loading (the walk, synthetic sets with known mounting and time offset, errors)
and the outage schedule and scoring against hand-computed values."""

import os
import shutil
from pathlib import Path

import numpy as np
import pytest

from gpsins import _core
from gpsins.dataset import load
from gpsins.dataset import fixes as dataset_fixes
from gpsins.evaluate import outages
from gpsins.dataset.load import DatasetError
from gpsins.formats import ubx

WALK = Path(__file__).parent / "data" / "walk_0827"


# --- the walk ------------------------------------------------------------------------------------------------

def test_walk_dataset_loads_with_mounting_reference_and_schedule():
    ds = load.load(WALK / "walk_0827.toml")
    assert ds.name == "walk_0827" and ds.gnss_format == "rtklib-pos" and ds.vehicle_kind == "none"
    assert len(ds.imu) == 20454 and len(ds.fixes) == 536
    assert len(ds.reference) == 349 and set(ds.reference.q) == {1}  # the README's fix epochs
    # Roll 180, pitch 0, yaw -90 by hand: Rz(-90) = [[0, 1, 0], [-1, 0, 0], [0, 0, 1]], Rx(180) = diag(1, -1, -1).
    np.testing.assert_allclose(ds.imu_to_body, [[0, -1, 0], [-1, 0, 0], [0, 0, -1]], atol=1e-15)
    # Standing at the start: the body's specific force is up (-g along down), the IMU's z axis pointed up.
    first = ds.imu.t_abs < ds.imu.t_abs[0] + 1.0
    f = ds.imu.dv_mps[first].sum(0) / (ds.imu.t_abs[first][-1] - ds.imu.t_abs[0] + np.median(np.diff(ds.imu.t_abs)))
    assert f[2] == pytest.approx(-9.9, abs=0.2) and np.hypot(f[0], f[1]) < 0.5
    # Heights above the geoid made ellipsoidal (first epoch printed as 1601.435 m).
    assert ds.reference.llh()[0, 2] == pytest.approx(1601.435 - 21.387, abs=1e-6)
    assert ds.fixes.llh()[0, 2] == pytest.approx(1601.435 - 21.387, abs=1e-6)
    t0, t1 = ds.gnss_span()
    np.testing.assert_allclose(ds.outage_schedule() - t0, [[25, 40], [70, 85]])  # two 15 s outages (issue 16)
    assert t1 - t0 == pytest.approx(133.75)
    cfg = ds.filter_config()
    assert cfg["imu_noise"]["gyro_arw_rad_per_sqrt_s"] == 6.63e-5 and cfg["gyro_bias_cal_rad_per_s"] == [0, 0, 0]


def test_walk_ubx_dataset_has_pseudoranges_ephemerides_and_fixes():
    ds = load.load(WALK / "walk_0827_ubx.toml")
    n_gps = 3842
    n = len(ds.pseudoranges)
    assert n > n_gps and (ds.pseudoranges.prn <= 32).sum() == n_gps and len(ds.fixes) == 536
    assert ds.navigation.prns() == [10, 23, 27, 32, 39, 40, 45, 46, 58, 61, 65]
    assert any("(G10, G23, G27, G32, E07, E08, E13, E14, E26, E29, E33)" in x for x in ds.notes)
    assert not ds.skipped
    assert ds.pseudoranges.table(ds.gnss_span()[0]).shape == (n, 6)


def test_gnss_systems_pick_what_a_ubx_stream_gives(tmp_path):
    text = (WALK / "walk_0827_ubx.toml").read_text()
    for systems, ids in ((["gps"], [10, 23, 27, 32]), (["galileo"], [39, 40, 45, 46, 58, 61, 65])):
        p = tmp_path / "walk_0827_ubx.toml"
        p.write_text(text.replace('format = "ubx"', f'format = "ubx"\nsystems = {systems!r}'.replace("'", '"')))
        for f in ("gnss_1730.ubx", "imu_1730_sf.csv", "gnss_1730_sf.pos"):
            (tmp_path / f).unlink(missing_ok=True)
            (tmp_path / f).symlink_to((WALK / f).resolve())
        ds = load.load(p)
        assert ds.navigation.prns() == ids and set(ubx.system_of(ds.pseudoranges.prn)) == set(systems)
    p.write_text(text.replace('format = "ubx"', 'format = "ubx"\nsystems = ["glonass"]'))
    with pytest.raises(DatasetError, match=r"\[gnss\] systems"):
        load.load(p)


# --- synthetic sets: mounting, time offset, formats -----------------------------------------------------------

def _write(tmp: Path, name: str, text: str) -> Path:
    p = tmp / name
    p.write_text(text)
    return p


def test_mounting_rotation_and_time_offset_on_known_increments(tmp_path):
    rng = np.random.default_rng(3)
    n = 50
    t = 1_000_000.0 + 0.01 * np.arange(n)
    dth, dv = rng.normal(0, 1e-3, (n, 3)), rng.normal(0, 1e-1, (n, 3))
    _write(tmp_path, "imu.txt", "".join(f"{a:.3f} 0 " + " ".join(f"{x:.17g}" for x in (*b, *c)) + "\n"
                                        for a, b, c in zip(t, dv, dth)))
    _write(tmp_path, "gnss.txt", "1000.0 59.3 18.1 30.0 0.01 0.01 0.02\n1001.0 59.3 18.1 30.0 0 0 0\n")
    _write(tmp_path, "set.toml", """
name = "synthetic"
[imu]
file = "imu.txt"
columns = ["t", "-", "ax", "ay", "az", "gx", "gy", "gz"]
time = "gps_abs"
accel_unit = "m/s"
gyro_unit = "rad"
time_offset_s = 0.25
imu_to_body = [[0, 1, 0], [-1, 0, 0], [0, 0, 1]]
[gnss]
file = "gnss.txt"
format = "kf-gins"
week = 1653
antenna_m = [0.5, -0.2, -1.0]
[vehicle]
kind = "car"
""")
    ds = load.load(tmp_path / "set.toml")
    np.testing.assert_allclose(ds.imu.t_abs, t + 0.25)
    # v_body = M v_imu, by hand: x_b = y_i, y_b = -x_i, z_b = z_i.
    np.testing.assert_allclose(ds.imu.dv_mps, np.column_stack([dv[:, 1], -dv[:, 0], dv[:, 2]]), rtol=1e-15)
    np.testing.assert_allclose(ds.imu.dtheta_rad, np.column_stack([dth[:, 1], -dth[:, 0], dth[:, 2]]), rtol=1e-15)
    assert ds.imu_time_offset_s == 0.25 and ds.vehicle_kind == "car"
    np.testing.assert_array_equal(ds.antenna_m, [0.5, -0.2, -1.0])
    np.testing.assert_allclose(ds.fixes.t_abs, [1653 * 604800 + 1000.0, 1653 * 604800 + 1001.0])
    assert np.all(ds.fixes.sigma_ned_m[1] == 0)  # kept as zero: the filter applies floors
    assert ds.filter_config()["preset"] == "default"


def test_rinex_dataset(shared_data, tmp_path):
    rel = Path(os.path.relpath(shared_data, tmp_path))
    _write(tmp_path, "imu.csv", "0,0,0,0,0,0,0\n0.01,0,0,0,0,0,0\n")
    _write(tmp_path, "set.toml", f"""
[imu]
file = "imu.csv"
columns = ["t", "ax", "ay", "az", "gx", "gy", "gz"]
time = "gps_sow"
week = 1316
[gnss]
file = "{(rel / '07590920.05o').as_posix()}"
format = "rinex"
nav = "{(rel / '07590920.05n').as_posix()}"
[scoring]
outages = "600:60:900"
""")
    ds = load.load(tmp_path / "set.toml")
    assert len(ds.pseudoranges.epochs()) == 120 and len(ds.navigation.ephemerides) > 20
    assert len(ds.navigation.alpha) == 4
    t0 = ds.gnss_span()[0]
    np.testing.assert_allclose(ds.outage_schedule() - t0, [[600, 660], [1500, 1560], [2400, 2460], [3300, 3360]])


@pytest.mark.parametrize("edit, match", [
    (lambda s: s + "\nspeed = 3\n", "unknown key"),
    (lambda s: s.replace('file = "imu.csv"', 'file = "nope.csv"'), r"\[imu\] file: nope\.csv: no such file"),
    (lambda s: s.replace("[imu]", "[imu]\nimu_to_body = [[1, 0, 0], [0, 1, 0], [0, 0, -1]]"), "not a rotation"),
    (lambda s: s.replace('format = "kf-gins"', 'format = "nmea"'), r"\[gnss\] format: unknown format 'nmea'"),
    (lambda s: s.replace("week = 1653\n", ""), r"\[gnss\] week"),
    (lambda s: s + '\n[scoring]\noutages = "5:10"\n', r"\[scoring\] outages"),
    (lambda s: s.replace('kind = "none"', 'kind = "boat"'), r"\[vehicle\] kind"),
    (lambda s: s.replace("columns =", "colums ="), r"\[imu\]: unknown key\(s\) colums"),
])
def test_dataset_errors_name_the_field(tmp_path, edit, match):
    _write(tmp_path, "imu.csv", "0,0,0,0,0,0,0\n0.01,0,0,0,0,0,0\n")
    _write(tmp_path, "gnss.txt", "1000.0 59.3 18.1 30.0 0.01 0.01 0.02\n")
    text = """name = "bad"
[imu]
file = "imu.csv"
columns = ["t", "ax", "ay", "az", "gx", "gy", "gz"]
time = "gps_abs"
[gnss]
file = "gnss.txt"
format = "kf-gins"
week = 1653
[vehicle]
kind = "none"
"""
    load.load(_write(tmp_path, "ok.toml", text))  # the unedited file is fine
    with pytest.raises(DatasetError, match=match) as e:
        load.load(_write(tmp_path, "bad.toml", edit(text)))
    assert "bad.toml" in str(e.value)


# --- outages: schedule ----------------------------------------------------------------------------------------

def test_schedule_exactly_as_specified():
    # t0 = 100, last epoch 300: starts 110, 160, 210, 260 (each earlier than 300 - 0).
    np.testing.assert_array_equal(outages.schedule("10:5:50", 100.0, 300.0),
                                  [[110, 115], [160, 165], [210, 215], [260, 265]])
    # END = 40: a start must be earlier than 260; 260 itself is not.
    np.testing.assert_array_equal(outages.schedule("10:5:50:40", 100.0, 300.0), [[110, 115], [160, 165], [210, 215]])
    np.testing.assert_array_equal(outages.schedule("10:5:50:39.999", 100.0, 300.0)[-1], [260, 265])
    # The walk (issue 16): 25:15:45:45 over 133.75 s of epochs gives two outages.
    np.testing.assert_array_equal(outages.schedule("25:15:45:45", 0.0, 133.75), [[25, 40], [70, 85]])
    assert outages.schedule("200:5:50", 100.0, 300.0).shape == (0, 2)
    spec = outages.parse("25:15:45")
    assert spec == outages.OutageSpec(25.0, 15.0, 45.0, 0.0) and spec.text() == "25:15:45:0"


@pytest.mark.parametrize("text", ["1:2", "a:b:c", "0:10:5", "0:0:5", "1:2:3:4:5", "nan:1:2"])
def test_bad_outage_specs(text):
    with pytest.raises(outages.OutageError, match="--outages"):
        outages.parse(text)


def test_inside_is_start_inclusive_end_exclusive():
    sched = np.array([[10.0, 15.0], [20.0, 25.0]])
    t = np.array([9.999, 10.0, 14.999, 15.0, 19.0, 20.0, 24.9, 25.0, 30.0])
    np.testing.assert_array_equal(outages.inside(t, sched), [0, 1, 1, 0, 0, 1, 1, 0, 0])
    np.testing.assert_array_equal(outages.outage_index(t, sched), [-1, 0, 0, -1, -1, 1, 1, -1, -1])
    assert not outages.inside(t, np.zeros((0, 2))).any()


# --- outages: scoring -----------------------------------------------------------------------------------------

def _error_ned(t: float) -> np.ndarray:
    """The solution's error (NED, m) at time t, made up so that every figure can be computed by hand."""
    if 5.0 <= t < 8.0:
        s = t - 5.0
        return np.array([3 * s, 4 * s, -s])  # horizontal 5 s, vertical s
    if 12.0 <= t < 15.0:
        s = t - 12.0
        return np.array([0.0, 2 * s, 0.5 * s])  # horizontal 2 s, vertical s / 2
    return np.array([0.3, 0.4, 0.1])  # horizontal 0.5, vertical 0.1


def test_drift_scores_by_hand():
    llh = np.array([np.radians(40.0), np.radians(-105.0), 1600.0])
    t_ref = np.arange(0.0, 21.0)  # 1 Hz reference, standing still
    r_ref = np.repeat(_core.geodetic_to_ecef(llh)[None, :], len(t_ref), 0)
    t_sol = np.arange(0.0, 20.05, 0.1)
    r_sol = _core.ned_to_ecef(np.array([_error_ned(x) for x in t_sol]), llh)
    sched = np.array([[5.0, 8.0], [12.0, 15.0]])
    s = outages.score(t_sol, r_sol, t_ref, r_ref, sched)
    # Outage 1: epochs 5, 6, 7: horizontal 0, 5, 10, vertical 0, 1, 2. Outage 2: epochs 12, 13, 14: 0, 2, 4 and
    # 0, 0.5, 1.
    np.testing.assert_allclose(s.max_h_m, [10.0, 4.0], atol=1e-6)
    np.testing.assert_allclose(s.max_v_m, [2.0, 1.0], atol=1e-6)
    np.testing.assert_array_equal(s.n_ref, [3, 3])
    d = s.summary()
    assert d["horizontal_m"]["mean"] == pytest.approx(7.0, abs=1e-6)
    assert d["horizontal_m"]["worst"] == pytest.approx(10.0, abs=1e-6)
    assert d["horizontal_m"]["rms"] == pytest.approx(np.sqrt((100 + 16) / 2), abs=1e-6)
    assert d["vertical_m"]["rms"] == pytest.approx(np.sqrt((4 + 1) / 2), abs=1e-6)
    assert s.n_outside == 21 - 6
    assert s.outside_rms_h_m == pytest.approx(0.5, abs=1e-6) and s.outside_rms_v_m == pytest.approx(0.1, abs=1e-6)
    np.testing.assert_allclose(s.drift_t_s, [0, 1, 2, 0, 1, 2])
    np.testing.assert_allclose(s.drift_h_m, [0, 5, 10, 0, 2, 4], atol=1e-6)
    np.testing.assert_array_equal(s.drift_outage, [0, 0, 0, 1, 1, 1])
    # An outage without a reference epoch counts as not scored, not as zero drift.
    s2 = outages.score(t_sol, r_sol, t_ref, r_ref, np.array([[5.0, 8.0], [30.0, 35.0]]))
    assert np.isnan(s2.max_h_m[1]) and s2.summary()["n_scored"] == 1
    assert s2.summary()["horizontal_m"]["rms"] == pytest.approx(10.0, abs=1e-6)


def test_scoring_interpolates_a_moving_solution():
    # Moving north at 2 m/s; the solution at 100 Hz lags by 0.05 s (0.1 m behind) everywhere: the error at the
    # 4 Hz reference epochs between solution samples is exactly -0.1 m north.
    llh = np.array([np.radians(59.0), np.radians(18.0), 20.0])
    t_ref = np.arange(0.0, 10.0, 0.25) + 0.003
    t_sol = np.arange(0.0, 10.01, 0.01)
    north = lambda t: np.column_stack([2.0 * t, 0 * t, 0 * t])  # noqa: E731
    s = outages.score(t_sol, _core.ned_to_ecef(north(t_sol - 0.05), llh), t_ref,
                      _core.ned_to_ecef(north(t_ref), llh), np.array([[4.0, 6.0]]))
    assert s.outside_rms_h_m == pytest.approx(0.1, abs=1e-6)
    assert s.max_h_m[0] == pytest.approx(0.1, abs=1e-6) and s.n_ref[0] == 8


def test_scoring_never_interpolates_across_an_update():
    # Moving north at 2 m/s, sampled at 100 Hz; the solution is 1 m ahead until an update at t = 5.004 puts it
    # on the track. Reference epochs at 5.004 (the update's own instant), 5.002 (before it) and 5.0065 (after
    # it, between the same samples): the output there is the state after the updates up to that instant,
    # so 0, 1 and 0 m (linear interpolation across the step would give 0.6, 0.8 and 0.35 m).
    llh = np.array([np.radians(59.0), np.radians(18.0), 20.0])
    t_sol = np.round(np.arange(0.0, 10.001, 0.01), 9)
    north = lambda t: np.column_stack([2.0 * t, 0 * t, 0 * t])  # noqa: E731
    r_sol = _core.ned_to_ecef(north(t_sol) + np.where(t_sol < 5.004, 1.0, 0.0)[:, None] * [1, 0, 0], llh)
    v_sol = _core.ned_to_ecef(north(t_sol + 1.0), llh) - _core.ned_to_ecef(north(t_sol), llh)  # 2 m/s north
    t_ref = np.array([5.004, 5.002, 5.0065])
    r_ref = _core.ned_to_ecef(north(t_ref), llh)
    _, e = outages.errors_ned(t_sol, r_sol, t_ref, r_ref, v_sol, np.array([1.0, 5.004, 7.0]))
    np.testing.assert_allclose(e[:, 0], [0.0, 1.0, 0.0], atol=1e-6)
    _, lin = outages.errors_ned(t_sol, r_sol, t_ref, r_ref)
    np.testing.assert_allclose(lin[:, 0], [0.6, 0.8, 0.35], atol=1e-6)
    # An update closer after a reference epoch than the reference's time resolution is at that epoch.
    _, e = outages.errors_ned(t_sol, r_sol, t_ref[1:2], r_ref[1:2], v_sol, np.array([5.004]), same_instant_s=0.003)
    assert e[0, 0] == pytest.approx(0.0, abs=1e-6)


def _circling_fixes(velocity_at):
    """4 Hz RTK-fixed fixes of a walk round a 5 m circle at 1.5 m/s (north-east, fixed height), with the
    stated velocity from ``velocity_at(t, positions, times)``."""
    from gpsins.formats.common import Fixes
    llh = np.array([np.radians(40.0), np.radians(-105.0), 1600.0])
    t = np.arange(0.0, 30.0, 0.25)
    ned = lambda x: np.column_stack([5 * np.cos(0.3 * x), 5 * np.sin(0.3 * x), 0 * x])  # noqa: E731
    r = _core.ned_to_ecef(ned(t), llh)
    n = len(t)
    return Fixes(t + 1e9, r, np.full((n, 3), 0.01), np.ones(n, int), np.full(n, 20), velocity_at(t, ned),
                 np.full((n, 3), 0.05))


def test_velocity_lag_is_measured_from_the_fixes_positions():
    # Instantaneous velocities: no lag. Velocities that are the mean over the epoch just ended (what NAV-PVT
    # gives, per the walk): half an epoch. The true values are set by construction, not by the estimator.
    now = _circling_fixes(lambda t, ned: np.column_stack([-1.5 * np.sin(0.3 * t), 1.5 * np.cos(0.3 * t), 0 * t]))
    mean = _circling_fixes(lambda t, ned: (ned(t) - ned(t - 0.25)) / 0.25)
    a, b = dataset_fixes.velocity_lag(now), dataset_fixes.velocity_lag(mean)
    assert a["epochs"] == len(now) - 2 and a["interval_s"] == pytest.approx(0.25)  # all but the ends
    assert abs(a["lag_s"]) < 0.005 and b["lag_s"] == pytest.approx(0.125, abs=0.005)
    assert b["rms_mps"] < 0.01 < b["rms_mps_at_zero_lag"]
    # Standalone (Q 5) fixes cannot tell: no figure.
    mean.q[:] = 5
    assert dataset_fixes.velocity_lag(mean) is None


def test_the_walk_velocity_lag_is_half_its_epoch():
    from gpsins.formats import rtklib_pos
    m = dataset_fixes.velocity_lag(rtklib_pos.read(WALK / "gnss_1730_sf.pos"))
    assert m["lag_s"] == pytest.approx(0.125, abs=0.01) and m["rms_mps"] < 0.5 * m["rms_mps_at_zero_lag"]


def test_a_damaged_ubx_stream_is_one_note_and_the_rest_is_kept(tmp_path):
    data = bytearray((WALK / "gnss_1730.ubx").read_bytes())
    at = data.index(b"\xb5\x62\x02\x15", 200_000)  # an RXM-RAWX frame
    data[at + 40] ^= 0xFF
    (tmp_path / "damaged.ubx").write_bytes(bytes(data))
    text = (WALK / "walk_0827_ubx.toml").read_text()
    rel = Path(os.path.relpath(WALK, tmp_path)).as_posix()
    text = text.replace('file = "imu_1730_sf.csv"', f'file = "{rel}/imu_1730_sf.csv"')
    text = text.replace('file = "gnss_1730.ubx"', 'file = "damaged.ubx"')
    text = text.replace('reference = "gnss_1730_sf.pos"', f'reference = "{rel}/gnss_1730_sf.pos"')
    ds = load.load(_write(tmp_path, "d.toml", text))
    assert ds.skipped["ubx: damaged stretches"] == 1
    frame_len = 8 + data[at + 4] + 256 * data[at + 5]  # the damaged frame, nothing more
    assert [n for n in ds.notes if "skipped" in n] == [
        f"damaged.ubx: skipped 1 damaged stretch(es), {frame_len} bytes; "
        f"first at offset {at} (bad checksum of class 0x02 id 0x15)"]
    assert len(ds.fixes) == 536 and len(np.unique(ds.pseudoranges.t_abs)) == 535


# --- fix noise keys -------------------------------------------------------------------------------------------

def _kfgins_set(tmp_path, extra: str = "") -> Path:
    _write(tmp_path, "imu.csv", "0,0,0,0,0,0,0\n0.01,0,0,0,0,0,0\n")
    _write(tmp_path, "gnss.txt", "1000.0 59.3 18.1 30.0 0 0 0\n1001.0 59.3 18.1 30.0 0.5 0.5 1.0\n")
    return _write(tmp_path, "set.toml", f"""
[imu]
file = "imu.csv"
columns = ["t", "ax", "ay", "az", "gx", "gy", "gz"]
time = "gps_abs"
[gnss]
file = "gnss.txt"
format = "kf-gins"
week = 1653
{extra}
""")


def test_sigma_floor_table_reaches_the_fix_table(tmp_path):
    ds = load.load(_kfgins_set(tmp_path, "[gnss.sigma_floor_m]\nunknown = [0.1, 0.2]\n"))
    assert ds.sigma_floor_m == {"unknown": (0.1, 0.2)}
    h, v = dataset_fixes.fix_sigmas(ds.fixes, ds.sigma_floor_m, ds.sigma_default_m)
    np.testing.assert_allclose(h, [0.1, 0.5])  # a stated zero takes the floor; 0.5 is above it
    np.testing.assert_allclose(v, [0.2, 1.0])
    assert dataset_fixes.velocity_sigma(ds.fixes) is None  # kf-gins fixes have no velocity


def test_antenna_sigma_reaches_the_filter_configuration(tmp_path):
    from gpsins.replay import inputs

    assert (load.load(_kfgins_set(tmp_path, "")).antenna_sigma_m == 0).all()  # exact unless stated
    ds = load.load(_kfgins_set(tmp_path, "antenna_sigma_m = 0.05\n"))
    np.testing.assert_array_equal(ds.antenna_sigma_m, [0.05, 0.05, 0.05])
    ds = load.load(_kfgins_set(tmp_path, "antenna_sigma_m = [0.1, 0.0, 0.02]\n"))
    np.testing.assert_array_equal(ds.antenna_sigma_m, [0.1, 0.0, 0.02])
    # (two IMU samples: the doctor would refuse them, so --force)
    assert inputs.load_inputs(ds.path, force=True).data_config["lever_arm_sigma_m"] == [0.1, 0.0, 0.02]


@pytest.mark.parametrize("extra, match", [
    ("[gnss.sigma_floor_m]\nrtk = [0.1, 0.2]\n", "unknown quality 'rtk'"),
    ("[gnss.sigma_floor_m]\nfix = [0.1]\n", r"sigma_floor_m\] fix: must be two positive numbers"),
    ("[gnss.sigma_default_m]\nfix = [0.1, -1]\n", r"sigma_default_m\] fix: must be two positive"),
    ("velocity_sigma_floor_mps = 0\n", "velocity_sigma_floor_mps: must be positive"),
    ("antenna_sigma_m = -0.1\n", r"\[gnss\] antenna_sigma_m: 1-sigma metres per axis"),
    ("antenna_sigma_m = [0.1, 0.1]\n", r"\[gnss\] antenna_sigma_m: must be three numbers"),
    ('antenna_sigma_m = "5 cm"\n', r"\[gnss\] antenna_sigma_m: must be three numbers"),
])
def test_bad_sigma_keys_name_the_field(tmp_path, extra, match):
    with pytest.raises(DatasetError, match=match):
        load.load(_kfgins_set(tmp_path, extra))


def test_what_the_gnss_readers_leave_out_is_counted_with_the_imus(tmp_path):
    """One .pos row with a nan: the reader drops it and counts it; the data set (and so run.json's
    skipped) must say so, not only the reader's own result."""
    for f in ("walk_0827.toml", "imu_1730_sf.csv"):
        shutil.copy(WALK / f, tmp_path / f)
    lines = (WALK / "gnss_1730_sf.pos").read_text().splitlines(keepends=True)
    k = next(i for i, x in enumerate(lines) if not x.startswith("%")) + 10
    cols = lines[k].split()
    cols[2] = "nan"  # the latitude
    lines[k] = "  ".join(cols) + "\n"
    (tmp_path / "gnss_1730_sf.pos").write_text("".join(lines))
    ds = load.load(tmp_path / "walk_0827.toml")
    assert len(ds.fixes) == 535
    assert sum(v for k, v in ds.skipped.items() if k.startswith("GNSS")) == 1, ds.skipped

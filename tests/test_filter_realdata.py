"""What real data needs from the core: the heading of a handheld device found from its first seconds
of fixes, per-fix measurement noise (16-column fixes), the land-vehicle constraint, and the walk
(real u-blox + MEMS data) replayed loosely against its RTK reference with outages."""

import functools
import re
import tomllib
from importlib import resources
from pathlib import Path

import numpy as np
import pytest

from gpsins import _core, sim
from gpsins.nav import runs as flt
from gpsins.replay import run
from gpsins.replay import inputs as replay_inputs
from gpsins.nav import config as nav_config
from gpsins.replay import results as results_mod
from gpsins.sim import dataset_writer as dw, scenario

WALK = Path(__file__).parent / "data" / "walk_0827" / "walk_0827.toml"
WALK_BASELINE_DRIFT_M = 96.4  # RMS of per-outage max drift before the heading search (course taken as heading)


def _cut(name: str, seconds: float, stand_s: float, rate_hz: int | None = None) -> scenario.Scenario:
    data = tomllib.loads((resources.files("gpsins.sim") / "scenarios" / f"{name}.toml").read_text())
    keep, total = [], 0.0
    for seg in data["segment"]:
        seg = dict(seg)
        if seg.get("speed_mps", None) == 0 and not keep:
            seg["duration_s"] = stand_s
        keep.append(seg)
        total += seg["duration_s"]
        if total > seconds:
            break
    labels = {s["label"] for s in keep}
    data["segment"] = keep
    data.pop("repeat", None)
    data["obstruction"] = [o for o in data.get("obstruction", []) if o.get("segment", keep[0]["label"]) in labels]
    if rate_hz:
        data.setdefault("imu", {})["rate_hz"] = rate_hz
    return scenario.parse(data, name)


def _yaw_deg(q_eb: np.ndarray, r_ecef: np.ndarray) -> float:
    llh = _core.ecef_to_geodetic(r_ecef)
    return float(np.degrees(_core.euler_from_body_to_ecef(q_eb, llh)[0]))


def _true_yaw_deg(s, t_run: np.ndarray) -> np.ndarray:
    """The simulated vehicle's yaw at run times (nearest truth sample)."""
    k = np.clip(np.searchsorted(s.truth.t, t_run), 0, len(s.truth.t) - 1)
    return np.array([_yaw_deg(s.truth.q_eb[i], s.truth.r_ecef[i]) for i in k])


def _wrap(a):
    return (np.asarray(a) + 180.0) % 360.0 - 180.0


# --- per-fix noise -------------------------------------------------------------------------------

@pytest.fixture(scope="module")
def short_drive():
    s = sim.simulate(_cut("default", 60, 10), seed=2)
    cfg = nav_config.load_config(None, sim.imu_noise_truth(s.scenario.imu))
    return s, cfg, sim.imu_table(s), sim.fix_table(s)


def _states(sol):
    return np.column_stack([sol.t, sol.r_ecef, sol.v_ecef, sol.q_eb, sol.sigma])


def test_sixteen_column_fixes_with_nan_sigmas_equal_ten_columns(short_drive):
    s, cfg, imu, fixes = short_drive
    ten = flt.run(imu, fixes, cfg)
    sixteen = flt.run(imu, np.column_stack([fixes, np.full((len(fixes), 6), np.nan)]), cfg)
    np.testing.assert_array_equal(_states(ten), _states(sixteen))


def test_stated_sigmas_replace_the_dop_model(short_drive):
    s, cfg, imu, fixes = short_drive
    uere = cfg["fix_uere_m"]
    # The sigmas the DOP model gives, stated per fix: the same run (to rounding).
    sh, sv = uere * fixes[:, 7] / np.sqrt(2.0), uere * fixes[:, 8]
    same = np.column_stack([fixes, sh, sh, sv, np.full((len(fixes), 3), np.nan)])
    ref = flt.run(imu, fixes, cfg)
    np.testing.assert_allclose(_states(flt.run(imu, same, cfg)), _states(ref), rtol=0, atol=1e-6)
    # Ten times smaller stated sigmas: the fixes' innovation sigmas shrink accordingly (without the
    # preset's correlated parts, which the stated sigmas do not replace and which stay as they were).
    white = nav_config.load_config(None, {**sim.imu_noise_truth(s.scenario.imu), "fix_error_gm_sigma_m": 0.0})
    tight = same.copy()
    tight[:, 10:13] /= 10.0
    u_ref, u_tight = flt.run(imu, same, white).updates, flt.run(imu, tight, white).updates
    k_ref, k_tight = u_ref["kind"] == 1, u_tight["kind"] == 1
    assert np.median(u_tight["innovation_sigma"][k_tight][:, 0]) < 0.5 * np.median(
        u_ref["innovation_sigma"][k_ref][:, 0])


def test_zero_or_negative_sigmas_fall_back_and_a_stated_sigma_replaces_a_missing_dop(short_drive):
    s, cfg, imu, fixes = short_drive
    ref = flt.run(imu, fixes, cfg)
    zeros = np.column_stack([fixes, np.zeros((len(fixes), 3)), np.full((len(fixes), 3), -1.0)])
    np.testing.assert_array_equal(_states(flt.run(imu, zeros, cfg)), _states(ref))
    no_dop = np.column_stack([fixes, np.full((len(fixes), 3), 2.0), np.full((len(fixes), 3), np.nan)])
    no_dop[:, 7:9] = np.nan
    sol = flt.run(imu, no_dop, cfg)
    assert sol.counters["fixes_accepted"] > 0.9 * len(fixes) and np.all(np.isfinite(sol.r_ecef))
    with pytest.raises(ValueError, match=r"fixes: expected shape \(n, 10\) or \(n, 16\)"):
        flt.run(imu, fixes[:, :9], cfg)


# --- heading of a handheld device ----------------------------------------------------------------

HANDHELD_OFFSET_DEG = 115.0  # the device points this far to the right of where it goes


@pytest.fixture(scope="module")
def handheld_walk(tmp_path_factory):
    """A simulated walk whose device points away from the course: written with the IMU turned by the
    offset, the data set then declares no mounting, so the filter's body axes are the device's."""
    s = sim.simulate(_cut("walk", 100, 8), seed=5)
    d = tmp_path_factory.mktemp("handheld")
    path = dw.write_dataset(s, d, imu_to_body_ypr_deg=(HANDHELD_OFFSET_DEG, 0.0, 0.0), antenna_m=(0.0, 0.0, 0.0),
                            vehicle_kind="none", imu_time_offset_s=0.0)
    text = re.sub(r"imu_to_body_ypr_deg = .*", "imu_to_body_ypr_deg = [0.0, 0.0, 0.0]", path.read_text())
    # The device's calibration in its own axes (the data set states the unit's, in body axes).
    m = dw.ypr_matrix(HANDHELD_OFFSET_DEG, 0.0, 0.0)
    preset = nav_config.load_config(None)
    for k in ("gyro_bias_cal_rad_per_s", "accel_bias_cal_mps2"):
        text = re.sub(rf"{k} = .*", f"{k} = {(m.T @ np.asarray(preset[k], float)).tolist()}", text)
    path.write_text(text)
    return s, path


def test_heading_search_finds_a_handheld_devices_heading(handheld_walk):
    s, path = handheld_walk
    inp = replay_inputs._dataset_inputs(path, None, {})
    # The simulated walk has no gait: its heading shows only while it speeds up (the first corner comes
    # 38 s after it sets off), yet the default 20 s window decides it.
    cfg = nav_config.load_config(inp.base_config, inp.data_config)
    assert cfg["platform"] == "handheld"  # kind = "none"
    sol = flt.run(inp.imu, inp.fixes, cfg, output_every=10)
    found = sol.extra["heading_search"]
    # Truth: the vehicle's yaw at the filter's start plus the device's offset (C_e,device = C_eb Rz(offset)).
    t_run = sol.t - (inp.imu[0, 0] - s.imu_t[0])
    true_start = _true_yaw_deg(s, t_run[:1])[0] + HANDHELD_OFFSET_DEG
    print(f"\nhandheld: search {found['yaw_deg']:.1f} deg, truth {_wrap(true_start):.1f} deg, "
          f"dominance {found['dominance']:.0f}")
    # Well inside the sigma it starts with (15 deg), and the filter takes it from there.
    assert abs(_wrap(found["yaw_deg"] - true_start)) <= 10.0
    # After the window the filter's heading is within a few degrees of the truth all along.
    late = t_run > t_run[0] + found["window_s"] + 10.0
    true_yaw = _true_yaw_deg(s, t_run[late]) + HANDHELD_OFFSET_DEG
    est = np.array([_yaw_deg(q, r) for q, r in zip(sol.q_eb[late], sol.r_ecef[late])])
    err = _wrap(est - true_yaw)
    print(f"handheld: yaw error after the window RMS {np.sqrt(np.mean(err ** 2)):.2f} deg, max {np.abs(err).max():.2f}")
    assert np.sqrt(np.mean(err ** 2)) < 3.0


@pytest.mark.parametrize("seed", [0, 3])
def test_heading_search_decides_on_weak_motion(tmp_path, seed):
    """Walks without gait whose heading shows only in the first seconds of speeding up: with each
    hypothesis run from its own yaw sigma (15 deg coarse, 5 deg fine) the search decides within 10 deg
    of the truth. Before, the hypotheses started at the preset's 180 deg yaw sigma: these two seeds were
    undecided (dominance 14.5 and 12.0, best coarse 80 and 50 deg off) and the filter took the course,
    115 deg off (yaw RMS 33 and 27 deg after 40 s)."""
    s = sim.simulate(_cut("walk", 40, 8), seed=seed)
    path = dw.write_dataset(s, tmp_path, imu_to_body_ypr_deg=(HANDHELD_OFFSET_DEG, 0.0, 0.0),
                            antenna_m=(0.0, 0.0, 0.0), vehicle_kind="none", imu_time_offset_s=0.0)
    path.write_text(re.sub(r"imu_to_body_ypr_deg = .*", "imu_to_body_ypr_deg = [0.0, 0.0, 0.0]", path.read_text()))
    inp = replay_inputs._dataset_inputs(path, None, {})
    found = flt.search_heading(inp.imu.table(), inp.fixes, nav_config.load_config(inp.base_config, inp.data_config))
    true_start = _true_yaw_deg(s, s.imu_t[:1])[0] + HANDHELD_OFFSET_DEG
    assert found["yaw_deg"] is not None and found["dominance"] >= flt.DOMINANCE
    assert abs(_wrap(found["yaw_deg"] - true_start)) <= 10.0, (found["yaw_deg"], true_start)


def test_no_search_without_motion_or_for_a_vehicle(short_drive):
    s, cfg, imu, fixes = short_drive
    standing = fixes[fixes[:, 0] < 9.0]  # the drive's first seconds stand still
    found = flt.search_heading(imu[imu[:, 0] < 9.0], standing, cfg)
    assert found["yaw_deg"] is None
    assert not flt.needs_heading_search(cfg)  # the default platform is a vehicle
    assert "heading_search" not in flt.run(imu, fixes, cfg).extra
    with pytest.raises(nav_config.ConfigError, match="platform"):
        nav_config.load_config(None, {"platform": "bicycle"})


# --- land-vehicle constraint ---------------------------------------------------------------------

@pytest.fixture(scope="module")
def car_set(tmp_path_factory):
    s = sim.simulate(_cut("default", 150, 10, rate_hz=100), seed=3)
    d = tmp_path_factory.mktemp("car")
    path = dw.write_dataset(s, d, imu_format="rates")
    assert 'kind = "car"' in path.read_text()  # the simulated vehicle is one
    return s, path


def test_nonholonomic_constraint_reduces_outage_drift_on_a_simulated_car(car_set, tmp_path):
    s, path = car_set
    on = run.replay(path, tmp_path / "nhc", outages="30:15:30").summary
    off = run.replay(path, tmp_path / "free", outages="30:15:30",
                     overrides={"nonholonomic_constraint": False}).summary
    d_on, d_off = on["scoring"]["horizontal_m"]["rms"], off["scoring"]["horizontal_m"]["rms"]
    print(f"\ncar: drift RMS with NHC {d_on:.2f} m, without {d_off:.2f} m; "
          f"{on['counters']['nonholonomic_updates']} NHC updates")
    assert on["counters"]["nonholonomic_updates"] > 100 and off["counters"]["nonholonomic_updates"] == 0
    assert d_on < 0.8 * d_off
    assert not any("non-holonomic" in w for w in on["warnings"])


# --- the real walk -------------------------------------------------------------------------------

def _rot(axis: int, deg: float) -> np.ndarray:
    c, s_ = np.cos(np.radians(deg)), np.sin(np.radians(deg))
    i, j = [(1, 2), (2, 0), (0, 1)][axis]
    m = np.eye(3)
    m[i, i] = m[j, j] = c
    m[i, j], m[j, i] = -s_, s_
    return m


@functools.cache
def _walk_yaw_from_rtk():
    """The device's yaw on the walk found without the filter, in numpy: the IMU (the publisher's rotation,
    roll 180, yaw -90, from the data README) levelled and its gyro bias taken over the standstill before the
    walk, its attitude integrated from there with yaw 0; the initial yaw is then the rotation that best
    turns its horizontal velocity increments over 1 s into the RTK fixed positions' (central differences),
    a 2-D Procrustes fit. Returns GPS seconds of week, the integrated yaw (deg) at the IMU samples, the
    initial yaw and its standard error from six consecutive blocks of the fit."""
    imu = np.loadtxt(WALK.parent / "imu_1730_sf.csv", delimiter=",")
    tow_imu = (imu[:, 0] - 315964800.0) % 604800.0  # GPST counted as Unix seconds
    m = _rot(2, -90.0) @ _rot(0, 180.0)  # v_body = Rz(yaw) Rx(roll) v_imu
    f_b, w_b = (imu[:, 1:4] * 9.80665) @ m.T, imu[:, 4:7] @ m.T
    rows = [ln.split() for ln in (WALK.parent / "gnss_1730_sf.pos").read_text().splitlines() if not ln.startswith("%")]
    gps0 = np.datetime64("1980-01-06T00:00:00", "ms")
    tow_pos = np.array([(np.datetime64(r[0].replace("/", "-") + "T" + r[1], "ms") - gps0) / np.timedelta64(1, "s")
                        for r in rows]) % 604800.0
    lat, lon, q = (np.array([float(r[k]) for r in rows]) for k in (2, 3, 5))
    north = np.radians(lat - lat[0]) * 6378137.0
    east = np.radians(lon - lon[0]) * 6378137.0 * np.cos(np.radians(lat[0]))
    v_ne = np.column_stack([np.gradient(north, tow_pos), np.gradient(east, tow_pos)])
    t_move = tow_pos[np.argmax(np.hypot(*v_ne.T) > 0.3)]
    rest = (tow_imu > tow_imu[0] + 0.5) & (tow_imu < t_move - 1.0)
    f0, bias = f_b[rest].mean(0), w_b[rest].mean(0)
    c = _rot(1, np.degrees(np.arctan2(f0[0], np.hypot(f0[1], f0[2])))) @ _rot(0, np.degrees(np.arctan2(-f0[1], -f0[2])))
    k0 = int(np.flatnonzero(rest)[-1])
    f_l, yaw = np.zeros((len(imu), 3)), np.zeros(len(imu))
    f_l[k0] = c @ f_b[k0]
    for k in range(k0 + 1, len(imu)):
        phi = (0.5 * (w_b[k] + w_b[k - 1]) - bias) * (tow_imu[k] - tow_imu[k - 1])
        a = np.linalg.norm(phi)
        sk = np.array([[0, -phi[2], phi[1]], [phi[2], 0, -phi[0]], [-phi[1], phi[0], 0]]) / max(a, 1e-15)
        c = c @ (np.eye(3) + np.sin(a) * sk + (1 - np.cos(a)) * sk @ sk)
        f_l[k], yaw[k] = c @ f_b[k], np.arctan2(c[1, 0], c[0, 0])
    steps = np.concatenate([[[0.0, 0.0]], np.cumsum(0.5 * (f_l[1:, :2] + f_l[:-1, :2]) * np.diff(tow_imu)[:, None], 0)])
    i0 = np.arange(1, len(tow_pos) - 5)
    i1 = i0 + 4  # 1 s at 4 Hz
    ok = (q[i0 - 1] == 1) & (q[i0] == 1) & (q[i1] == 1) & (q[i1 + 1] == 1) & (tow_pos[i0] > tow_imu[k0])
    ok &= np.abs(tow_pos[i1] - tow_pos[i0] - 1.0) < 1e-3
    dv_rtk = (v_ne[i1] - v_ne[i0])[ok]
    dv_imu = np.column_stack([np.interp(tow_pos[i1], tow_imu, steps[:, j])
                              - np.interp(tow_pos[i0], tow_imu, steps[:, j])
                              for j in range(2)])[ok]
    cross = dv_imu[:, 0] * dv_rtk[:, 1] - dv_imu[:, 1] * dv_rtk[:, 0]
    dot = np.sum(dv_imu * dv_rtk, axis=1)
    psi0 = np.degrees(np.arctan2(cross.sum(), dot.sum()))
    blocks = [np.degrees(np.arctan2(cross[b].sum(), dot[b].sum())) for b in np.array_split(np.arange(len(dot)), 6)]
    se = float(np.std(_wrap(np.array(blocks) - psi0), ddof=1) / np.sqrt(len(blocks)))
    return tow_imu, np.degrees(yaw) + psi0, float(psi0), se


@pytest.mark.parametrize("name", ["walk_0827.toml", "walk_0827_ubx.toml", "walk_0827_raw.toml"])
def test_walk_replays_loose_with_the_heading_searched(tmp_path, name):
    """Measured: .pos 2.29 m drift RMS, 0.046 m outside; NAV-PVT 2.33 m, 0.046 m; the IMU as logged (RTKLIB
    time tags, the IMU's delay a state: -29.9 +- 1.4 ms) 2.28 m, 0.042 m; with the RTK solution's
    cm-level correlated fix errors and NAV-PVT's velocity taken as the mean over the epoch just ended (lag
    measured 0.134 s), and the searched heading (165 deg) started at its 15 deg sigma (2.81, 2.82 and
    2.56 m while it started at the preset's 180 deg). This schedule's two outages are luck either way: over
    seven schedules shifted by -10..+10 s (benchmarks/bench_walk.py) the pooled RMS is 2.60 m (.pos),
    2.58 m (NAV-PVT), 2.80 m (as logged). Asserted: 0.7 x the peer's 4.6 m, and the goal outside the
    outages, 0.05 m (the peer: 0.036 m)."""
    res = run.replay(WALK.parent / name, tmp_path / "walk").summary
    h = res["scoring"]["horizontal_m"]
    outside = res["scoring"]["outside"]["rms_h_m"]
    found = res["heading_search"]
    # The heading against the numpy estimate from the RTK positions (_walk_yaw_from_rtk), each within 95 % of
    # its stated sigma and that estimate's: the search's start (15 deg sigma), and the run's yaw where the
    # search's window ends (the filter's own sigma, by then a fraction of a degree).
    tow, yaw_np, psi0, se = _walk_yaw_from_rtk()
    z = results_mod.load(tmp_path / "walk")
    k = min(int(np.searchsorted(z["t"], found["t_end"])), len(z["t"]) - 1)
    d_start = float(_wrap(found["yaw_deg"] - psi0))
    d_run = float(_wrap(z["ypr_deg"][k, 0] - np.interp(z["t"][k], tow, yaw_np)))
    sigma_run = float(z["sigma_ypr_deg"][k, 2])  # about the down axis
    print(f"\n{name}: drift RMS {h['rms']:.2f} m (worst {h['worst']:.2f} m), outside RMS {outside:.3f} m, "
          f"heading {found['yaw_deg']} deg (dominance {found['dominance']:.0f}); from the RTK positions "
          f"{psi0:.1f} +- {se:.1f} deg; the run's yaw minus that at the window's end {d_run:.1f} deg "
          f"(sigma {sigma_run:.2f})")
    # Measured: RTK 151.5 +- 1.3 deg (the device points far from its course, about -90 deg); searched 165 deg on
    # every copy, the fine grid's edge (the best coarse hypothesis was 180 deg); the run 0.7-0.9 deg below.
    assert abs(d_start) <= 1.96 * np.hypot(found["sigma_deg"], se)
    assert abs(d_run) <= 1.96 * np.hypot(sigma_run, se)
    assert h["rms"] < 0.7 * 4.6 < 0.1 * WALK_BASELINE_DRIFT_M
    assert outside < 0.05
    assert res["counters"]["gnss_resets"] == 0 and res["counters"]["imu_gaps_bridged"] == 0


@pytest.mark.xfail(strict=True, reason="issue 16's goal is 2.3 m drift RMS; pooled over the issue's schedule "
                   "25:15:45:45 shifted by -10..+10 s (14 outages) the .pos copy drifts 2.60 m (2.29 m on the "
                   "unshifted schedule, on which this copy's keys were tuned)")
def test_walk_forward_drift_meets_the_goal_over_shifted_schedules(tmp_path):
    """Issue 16's walk goal, 2.3 m. Its schedule puts two outages into the walk, and this copy's keys were
    chosen on it (2.29 m); two outages' RMS moves by a metre when they start a few seconds earlier or later.
    So the goal is held against the RMS over every outage of the schedule shifted as benchmarks/bench_walk.py
    does (-10..+10 s): per schedule 4.58, 3.08, 0.62, 2.29, 2.46, 0.97, 2.03 m."""
    per_outage_m = []
    for shift_s in (-10, -6, -2, 0, 2, 6, 10):
        res = run.replay(WALK, tmp_path / f"walk_{shift_s}", outages=f"{25 + shift_s}:15:45:45").summary
        per_outage_m += [o["max_h_m"] for o in res["scoring"]["per_outage"] if np.isfinite(o["max_h_m"])]
    pooled_m = float(np.sqrt(np.mean(np.square(per_outage_m))))
    print(f"\nwalk drift RMS over {len(per_outage_m)} outages of shifted schedules: {pooled_m:.2f} m")
    assert len(per_outage_m) == 14
    assert pooled_m <= 2.3


# --- the walk from its publisher's facts alone (walk_0827_facts.toml: no key tuned on the walk) ----------

@pytest.fixture(scope="module")
def facts_walk(tmp_path_factory):
    return run.replay(WALK.parent / "walk_0827_facts.toml", tmp_path_factory.mktemp("facts"))


def test_walk_from_its_publishers_facts_meets_the_goal(facts_walk):
    """Issue 35's goal for a data set of facts only, 2.3 m on 25:15:45:45. The publisher puts the antenna
    "about 0.05 m" from the IMU without a direction, so the data set says antenna_sigma_m = 0.05 and replay
    fits the lever arm (nav.lever_arm); without the fit 2.36 m."""
    fit = facts_walk.summary["lever_arm_fit"]
    drift_m = facts_walk.summary["scoring"]["horizontal_m"]["rms"]
    print(f"\nlever arm {np.round(fit['lever_arm_body_m'], 3)} m, drift {drift_m:.2f} m")
    assert drift_m <= 2.3
    # The publisher's "about 0.05 m": a fit that had taken up some other misfit would be free to wander.
    assert 0.025 <= np.linalg.norm(fit["lever_arm_body_m"]) <= 0.1


def test_walk_from_its_publishers_facts_is_near_the_tuned_copy(facts_walk, tmp_path):
    """What the data set leaves out, replay takes from the data: no calibration of a consumer unit, no
    standalone receiver's correlated metres for RTK fixes, the velocity lag measured. Within 10 % of the
    hand-tuned copy's drift on the same schedule."""
    tuned = run.replay(WALK, tmp_path / "tuned").summary["scoring"]["horizontal_m"]["rms"]
    facts = facts_walk.summary["scoring"]["horizontal_m"]["rms"]
    print(f"\nfacts {facts:.2f} m, tuned {tuned:.2f} m")
    assert facts <= 1.1 * tuned
    assert facts_walk.summary["counters"]["gnss_resets"] == 0


@pytest.mark.xfail(strict=True, reason="issue 35 asks NIS/dof in [0.5, 2] for every source on real data; on the "
                   "walk from facts the RTK fixes' NIS/dof mean is 5.4 (median 2.4, lag-one autocorrelation "
                   "0.90; 5.8, 2.3, 0.88 before the lever arm was fitted): the hand's gait is motion the error "
                   "model has no term for, and fitting white IMU noise to it (fit_noise) brought the mean to 0.8 "
                   "but the drift to 4.7 m")
def test_walk_from_its_publishers_facts_is_consistent(facts_walk):
    import pyarrow.parquet as pq

    t = pq.read_table(facts_walk.out / "updates.parquet").to_pydict()
    kind, nis, dof = (np.asarray(t[k]) for k in ("kind", "nis", "dof"))
    for k in (1, 3):  # fix position, fix velocity
        per_dof = nis[kind == k] / dof[kind == k]
        assert 0.5 <= per_dof.mean() <= 2.0, (k, per_dof.mean())

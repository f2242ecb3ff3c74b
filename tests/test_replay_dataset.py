"""Replay of data sets (issue 16): the walk loose (.pos, NAV-PVT) and tight (UBX) end to end with its
outage scoring recomputed independently; the simulator's own data set with a known mounting rotation,
lever arm and IMU time offset, each checked against truth and each visibly worse when wrong; per-fix
sigmas (zeros included) and INS-only mode."""

import json
import re
import tomllib
from importlib import resources
from pathlib import Path

import numpy as np
import pytest

from gpsins import cli
from gpsins.dataset import fixes as dataset_fixes
from gpsins.replay import run as replay
from gpsins.gnss import spp
from gpsins.replay import results as results_mod
from gpsins.formats import rtklib_pos
from gpsins.sim import earth, scenario, simulate
from gpsins.sim import dataset_writer as dw

WALK = Path(__file__).parent / "data" / "walk_0827"


# --- helpers computed independently of the code under test ------------------------------------------------------

def _ned_errors(t_sol, r_sol, t_ref, r_ref, v_sol=None, upd_t=None, same_instant_s=0.001):
    """Solution minus reference in NED at the reference epochs inside the solution (the simulator's own
    geodetic model, not the core's). With velocities and update times, the solution at an epoch whose two
    neighbouring samples straddle an update is the sample on the epoch's side of it, carried with its velocity
    (an update less than a millisecond after the epoch counts as before it: the .pos tags' resolution)."""
    use = (t_ref >= t_sol[0]) & (t_ref <= t_sol[-1])
    est = np.column_stack([np.interp(t_ref[use], t_sol, r_sol[:, j]) for j in range(3)])
    if upd_t is not None:
        for n, te in enumerate(t_ref[use]):
            k = min(int(np.searchsorted(t_sol, te, side="right")) - 1, len(t_sol) - 2)
            if t_sol[k] == te:
                continue
            ups = upd_t[(upd_t > t_sol[k]) & (upd_t <= t_sol[k + 1])]
            if len(ups):
                j = k + 1 if ups.min() <= te + same_instant_s else k
                est[n] = r_sol[j] + v_sol[j] * (te - t_sol[j])
    out = []
    for x, r in zip(est, r_ref[use]):
        lat, lon, _ = earth.ecef_to_geodetic(r)
        out.append(earth.ecef_to_ned_matrix(lat, lon).T @ (x - r))
    return use, np.array(out).reshape(-1, 3)


def _score_by_hand(t_sol, r_sol, t_ref, r_ref, t0, first, length, period, end, t_last, v_sol=None, upd_t=None):
    starts = []
    k = 0
    while t0 + first + k * period < t_last - end:
        starts.append(t0 + first + k * period)
        k += 1
    use, e = _ned_errors(t_sol, r_sol, t_ref, r_ref, v_sol, upd_t)
    tr = t_ref[use]
    h, v = np.hypot(e[:, 0], e[:, 1]), np.abs(e[:, 2])
    inside = np.zeros(len(tr), bool)
    max_h, max_v = [], []
    for s in starts:
        m = (tr >= s) & (tr < s + length)
        inside |= m
        max_h.append(h[m].max())
        max_v.append(v[m].max())
    return np.array(starts), np.array(max_h), np.array(max_v), np.sqrt(np.mean(h[~inside] ** 2))


# --- the walk -------------------------------------------------------------------------------------------------

WALK_RUNS = [("walk_0827.toml", "loose"), ("walk_0827_ubx.toml", "loose"), ("walk_0827_ubx.toml", "tight")]


@pytest.fixture(scope="module")
def walk_runs(tmp_path_factory):
    out = {}
    for name, mode in WALK_RUNS:
        d = tmp_path_factory.mktemp(f"{Path(name).stem}_{mode}")
        out[(name, mode)] = (replay.replay(WALK / name, d, mode=mode), d)
    return out


@pytest.mark.parametrize("name, mode", WALK_RUNS)
def test_walk_replays_and_its_outage_scoring_is_recomputed_independently(walk_runs, name, mode):
    res, d = walk_runs[(name, mode)]
    s = json.loads((d / "run.json").read_text())
    z = results_mod.load(d)
    assert s["kind"] == "dataset" and s["mode"] == mode and len(z["t"]) > 15000
    # The data set's schedule: two 15 s outages from the first GNSS epoch; no GNSS update inside them.
    sched = np.array(s["outages"]["schedule"])
    t0 = s["outages"]["gnss_first_t"]
    np.testing.assert_allclose(sched - t0, [[25, 40], [70, 85]])
    gnss = np.isin(z["upd_kind"], (1, 2, 3, 6))
    tu = z["upd_t"][gnss]
    assert gnss.sum() > 10
    assert not np.any((tu[:, None] >= sched[:, 0]) & (tu[:, None] < sched[:, 1]))
    assert s["outages"]["fixes_removed"] == 120  # 4 Hz fixes, 2 x 15 s
    if mode == "tight":
        assert s["outages"]["pseudoranges_removed"] > 0 and s["counters"]["pseudoranges_used"] > 0
    # Scoring recomputed from the written arrays and the reference file (Q = 1 epochs, geoid height added).
    ref = rtklib_pos.read(WALK / "gnss_1730_sf.pos", -21.387)
    ref = ref.select(ref.q == 1)
    t_ref = ref.t_abs - int(z["week"]) * 604800.0
    starts, max_h, max_v, outside = _score_by_hand(z["t"], z["r_point_ecef"], t_ref, ref.r_ecef, t0, 25, 15, 45, 45,
                                                   s["outages"]["gnss_last_t"], z["v_ecef"], z["upd_t"])
    np.testing.assert_allclose(starts, sched[:, 0])
    sc = s["scoring"]
    np.testing.assert_allclose([o["max_h_m"] for o in sc["per_outage"]], max_h, rtol=1e-6, atol=1e-6)
    np.testing.assert_allclose([o["max_v_m"] for o in sc["per_outage"]], max_v, rtol=1e-6, atol=1e-6)
    assert sc["horizontal_m"]["rms"] == pytest.approx(np.sqrt(np.mean(max_h ** 2)), rel=1e-6)
    assert sc["horizontal_m"]["worst"] == pytest.approx(max_h.max(), rel=1e-6)
    assert sc["outside"]["rms_h_m"] == pytest.approx(outside, rel=1e-6, abs=1e-6)
    # The figures, reported (not asserted: the filter's start-up and gate recovery are another issue's).
    print(f"\n{name} {mode}: RMS of per-outage max horizontal drift {sc['horizontal_m']['rms']:.2f} m, "
          f"outside outages {sc['outside']['rms_h_m']:.3f} m; fixes accepted {s['counters']['fixes_accepted']}, "
          f"rejected {s['counters']['fixes_rejected']}")


def test_walk_data_set_noise_and_rates_reach_the_filter(walk_runs):
    _, d = walk_runs[("walk_0827.toml", "loose")]
    cfg = tomllib.loads((d / "config.toml").read_text())
    s = json.loads((d / "run.json").read_text())
    assert cfg["imu_rate_hz"] == pytest.approx(1 / 0.006, rel=0.01)  # from the data, not 64 Hz
    assert cfg["imu_noise"]["gyro_arw_rad_per_sqrt_s"] == 6.63e-5 and cfg["gyro_bias_cal_rad_per_s"] == [0, 0, 0]
    assert cfg["use_fix_velocity"] is True and 0.02 <= cfg["fix_velocity_sigma_mps"] < 0.1
    assert s["dataset"]["fix_quality"] == {"fix": 349, "float": 187}
    # NAV-PVT's velocity is the mean over the epoch just ended ([gnss] velocity_lag_s = "measured"): moved to
    # the fix's time, its updates agree with the filter as their sigmas say far better than taken as instantaneous
    # (fix velocity NIS per axis, mean: measured 2.4 with the lag, 4.1 without).
    assert cfg["fix_velocity_lag_s"] == pytest.approx(s["dataset"]["velocity_lag_measured"]["lag_s"])
    assert 0.1 < cfg["fix_velocity_lag_s"] < 0.15
    z = results_mod.load(d)
    nis = z["upd_nis"][z["upd_kind"] == 3].mean() / 3
    no_lag = replay.replay(WALK / "walk_0827.toml", d.parent / "no_lag", overrides={"fix_velocity_lag_s": 0.0})
    z0 = results_mod.load(no_lag.out)
    assert nis < 0.75 * z0["upd_nis"][z0["upd_kind"] == 3].mean() / 3
    _, d = walk_runs[("walk_0827_ubx.toml", "tight")]
    cfg = tomllib.loads((d / "config.toml").read_text())
    assert cfg["pseudorange_decimation"] == 4  # RAWX at 4 Hz: about one epoch a second
    # The fixes written: hdop/vdop carry the per-fix sigma (floors 0.02 / 0.03 m for RTK fixed).
    z = results_mod.load(d)
    h = z["fixes"][:, 7] * cfg["fix_uere_m"] / np.sqrt(2)
    assert h.min() == pytest.approx(0.02) and (h > 0.1).any()


def _replay_edited_walk(tmp_path, old: str, new: str) -> tuple[dict, Path]:
    """The walk's UBX data set with one edit of its text, replayed tight: its run.json and results directory."""
    toml = tmp_path / "walk_0827_ubx.toml"
    toml.write_text((WALK / "walk_0827_ubx.toml").read_text().replace(old, new))
    for f in ("gnss_1730.ubx", "imu_1730_sf.csv", "gnss_1730_sf.pos"):
        (tmp_path / f).symlink_to((WALK / f).resolve())
    out = tmp_path / "edited"
    replay.replay(toml, out, mode="tight")
    return json.loads((out / "run.json").read_text()), out


def test_tight_walk_with_galileo_beats_gps_alone_and_ignores_the_galileo_clock(walk_runs, tmp_path, monkeypatch):
    """The walk's UBX stream has complete ephemerides for four GPS and seven Galileo satellites in its 134 s.
    Galileo's pseudoranges enter as differences within each epoch, so the receiver's Galileo time offset
    drops out: a kilometre added to all of them changes nothing, and they must sharpen the tight solution."""
    from gpsins.formats import ubx

    res_both, d_both = walk_runs[("walk_0827_ubx.toml", "tight")]
    s_both = json.loads((d_both / "run.json").read_text())
    assert s_both["counters"]["pseudoranges_used"] > 0
    z_both = results_mod.load(d_both)
    used = np.unique(z_both["upd_id"][(z_both["upd_kind"] == 6) & (z_both["upd_accepted"] == 1)])
    assert (used > 32).sum() >= 5 and (used <= 32).sum() == 4
    s_gps, _ = _replay_edited_walk(tmp_path, 'format = "ubx"', 'format = "ubx"\nsystems = ["gps"]')
    out_both, out_gps = s_both["scoring"]["outside"]["rms_h_m"], s_gps["scoring"]["outside"]["rms_h_m"]
    v_both = s_both["scoring"]["outside"].get("rms_v_m"), s_gps["scoring"]["outside"].get("rms_v_m")
    print(f"\ntight walk outside outages, H RMS: GPS + Galileo {out_both:.2f} m, GPS alone {out_gps:.2f} m; "
          f"V RMS {v_both}")
    # Measured (with Doppler): 8.98 against 9.44 m horizontally, 2.91 against 4.62 m vertically (before Doppler
    # 10.97 / 11.81 and 3.40 / 3.88: the error was the heading's then). What is left is the single-frequency
    # ranges' ionosphere, which no Klobuchar page in 134 s models.
    assert out_both < out_gps and v_both[0] < v_both[1]

    real_read = ubx.read

    def shifted(path):
        u = real_read(path)
        gal = u.pseudoranges.prn > 32
        u.pseudoranges.pr_m = np.where(gal, u.pseudoranges.pr_m + 1000.0, u.pseudoranges.pr_m)
        return u

    monkeypatch.setattr(ubx, "read", shifted)
    replay.replay(WALK / "walk_0827_ubx.toml", tmp_path / "shifted", mode="tight")
    z_shift = results_mod.load(tmp_path / "shifted")
    # Not to rounding: 1 km later in light time the satellites' positions differ by about a centimetre
    # (3.3 us at 3.9 km/s); 2.4 mm measured.
    np.testing.assert_allclose(z_shift["r_point_ecef"], z_both["r_point_ecef"], rtol=0, atol=0.01)


def _yaw_difference_deg(a, b) -> np.ndarray:
    """a's yaw minus b's (results tables) at a's epochs where both know their heading, wrapped to +-180 deg."""
    both = _both_know_heading(a, b)
    yb = np.interp(a["t"], b["t"], np.unwrap(np.radians(b["ypr_deg"][:, 0])))
    return np.degrees(np.angle(np.exp(1j * (np.radians(a["ypr_deg"][both, 0]) - yb[both]))))


def _both_know_heading(a, b) -> np.ndarray:
    k = np.searchsorted(b["t"], a["t"]).clip(0, len(b["t"]) - 1)
    return a["heading_known"].astype(bool) & b["heading_known"][k].astype(bool)


def test_tight_walk_doppler_gives_the_heading_pseudoranges_cannot(walk_runs, tmp_path):
    """At walking speed pseudoranges' metres hardly show the heading; RAWX's Doppler (0.1-0.2 m/s) does. With it
    the tight run's yaw follows the loose run's (RTK fixes) closer and its drift and error shrink; without it
    (doppler_sigma_mps = 0) the yaw wanders from where the heading search set it. "Closer" is a one-sided sign
    test at 95 % over 15 s blocks of the walk (the yaw difference's autocorrelation first reaches zero after
    12.5 s, so the blocks are about independent): the block medians of |yaw - loose yaw|, with against without;
    the drift in each of the schedule's two outages, and the error outside them."""
    from scipy.stats import binomtest

    res, d = walk_runs[("walk_0827_ubx.toml", "tight")]
    s = json.loads((d / "run.json").read_text())
    assert s["counters"]["range_rates_used"] > 3000 and s["counters"]["range_rates_rejected"] == 0
    s_nod, d_nod = _replay_edited_walk(tmp_path, "[filter.imu_noise]", "doppler_sigma_mps = 0.0\n\n[filter.imu_noise]")
    assert s_nod["counters"]["range_rates_used"] == 0
    loose = results_mod.load(walk_runs[("walk_0827_ubx.toml", "loose")][1])
    blocks = {}
    for name, z in (("with", results_mod.load(d)), ("without", results_mod.load(d_nod))):
        dy = np.abs(_yaw_difference_deg(z, loose))
        t = z["t"][_both_know_heading(z, loose)]
        k = ((t - t[0]) // 15.0).astype(int)
        blocks[name] = np.array([np.median(dy[k == j]) for j in range(k.max() + 1)])
    closer = int(np.sum(blocks["with"] < blocks["without"]))
    p = binomtest(closer, len(blocks["with"]), 0.5, alternative="greater").pvalue
    drift = [o["max_h_m"] for o in s["scoring"]["per_outage"]]
    drift_nod = [o["max_h_m"] for o in s_nod["scoring"]["per_outage"]]
    out, out_nod = s["scoring"]["outside"]["rms_h_m"], s_nod["scoring"]["outside"]["rms_h_m"]
    print(f"\ntight walk, median |yaw - loose yaw| per 15 s: with Doppler {np.round(blocks['with'], 1)}, without "
          f"{np.round(blocks['without'], 1)} deg: closer in {closer} of {len(blocks['with'])} (p {p:.4f}); drift per "
          f"outage {np.round(drift, 2)} / {np.round(drift_nod, 2)} m; outside H RMS {out:.2f} / {out_nod:.2f} m")
    # Measured: closer in 9 of 9 blocks (median 1.2 against 4.8 deg over the walk); drift 8.70 / 17.3 against
    # 9.11 / 36.0 m (most of what is left is the standing error of single-frequency ranges without an
    # ionosphere model: about 8 m before the first outage begins); outside 9.05 against 10.56 m.
    assert p < 0.05
    assert len(drift) == len(drift_nod) == 2 and np.all(np.array(drift) < np.array(drift_nod)) and out < out_nod


@pytest.mark.xfail(strict=True, reason="tight walk with Doppler: median |yaw - loose yaw| 1.24 deg against "
                   "0.6745 x the runs' stated sigmas, 0.31 deg (tight 0.44, loose 0.14 deg): the yaw is "
                   "about 4x over-confident")
def test_tight_walk_yaw_follows_the_loose_run_within_their_sigmas(walk_runs):
    """The tight run's yaw (with Doppler) and the loose run's (RTK fixes) estimate the same heading: if each
    is Gaussian with its stated sigma, |difference| has the median 0.6745 sqrt(sigma_t^2 + sigma_l^2) or less
    (their errors share the IMU, which only makes the difference smaller)."""
    z = results_mod.load(walk_runs[("walk_0827_ubx.toml", "tight")][1])
    loose = results_mod.load(walk_runs[("walk_0827_ubx.toml", "loose")][1])
    dy = np.abs(_yaw_difference_deg(z, loose))
    both = _both_know_heading(z, loose)
    sigma = np.hypot(z["sigma_ypr_deg"][both, 2], np.interp(z["t"][both], loose["t"], loose["sigma_ypr_deg"][:, 2]))
    print(f"\nmedian |yaw - loose yaw| {np.median(dy):.2f} deg, 0.6745 x stated {0.6745 * np.median(sigma):.2f} deg")
    assert np.median(dy) <= 0.6745 * np.median(sigma)


def test_fix_sigmas_floors_defaults_and_zeros():
    from gpsins.formats.common import Fixes

    n = 6
    f = Fixes(np.arange(n, dtype=float), np.zeros((n, 3)),
              np.array([[0.0, 0.0, 0.0], [0.03, 0.04, 0.05], [np.nan] * 3, [0.0, 0.0, 0.0], [0.2, 0.2, 0.3],
                        [np.nan] * 3]), np.array([1, 1, 1, 2, 5, 5]), np.zeros(n, int))
    h, v = dataset_fixes.fix_sigmas(f)
    np.testing.assert_allclose(h, [0.02, np.sqrt((0.03 ** 2 + 0.04 ** 2) / 2), 0.05, 0.15, 1.5, 3.0])
    np.testing.assert_allclose(v, [0.03, 0.05, 0.1, 0.3, 3.0, 6.0])
    h2, _ = dataset_fixes.fix_sigmas(f, {"fix": (0.005, 0.01)})
    assert h2[0] == 0.005
    tab = dataset_fixes.fix_table(f, 0.0, 3.0)
    assert np.all(tab[:, 7] > 0) and np.all(tab[:, 8] > 0) and np.all(tab[:, 9] == 2)
    np.testing.assert_allclose(3.0 * tab[:, 7] / np.sqrt(2), h)


def test_replay_cli_on_a_data_set_prints_the_outage_table(tmp_path, capsys):
    assert cli.main(["replay", str(WALK / "walk_0827.toml"), "--out", str(tmp_path / "r"),
                     "--outages", "20:10:40", "--point", "imu"]) == 0
    text = capsys.readouterr().out
    assert "drift against gnss_1730_sf.pos" in text and "outside RMS" in text
    s = json.loads((tmp_path / "r" / "run.json").read_text())
    assert s["outages"]["spec"] == "20:10:40:0"
    np.testing.assert_allclose(np.array(s["outages"]["schedule"]) - s["outages"]["gnss_first_t"],
                               [[20, 30], [60, 70], [100, 110]])  # 140 is past the last epoch (133.75 s)
    assert s["solution_point"] == "imu"
    assert cli.main(["replay", str(WALK / "walk_0827.toml"), "--out", str(tmp_path / "x"), "--outages", "5:10"]) == 2
    assert "--outages '5:10'" in capsys.readouterr().err


def test_outages_none_sets_the_data_sets_schedule_aside(tmp_path):
    """walk_0827.toml schedules outages in its [scoring]; --outages none replays with every fix."""
    assert cli.main(["replay", str(WALK / "walk_0827.toml"), "--out", str(tmp_path / "r"), "--outages", "none"]) == 0
    s = json.loads((tmp_path / "r" / "run.json").read_text())
    assert s["outages"]["schedule"] == [] and s["outages"]["fixes_removed"] == 0
    assert cli.main(["replay", str(WALK / "walk_0827.toml"), "--out", str(tmp_path / "d")]) == 0
    assert json.loads((tmp_path / "d" / "run.json").read_text())["outages"]["fixes_removed"] > 0


# --- the simulator's data set: mounting rotation, lever arm, time offset against truth -----------------------

MOUNT = (-90.0, 3.0, 180.0)
LEVER = (0.6, -0.3, -1.1)
OFFSET_S = 0.05


@pytest.fixture(scope="module")
def sim_set(tmp_path_factory):
    """The default drive cut to its first 2 minutes, with a 100 Hz IMU, written as a data set (IMU rates)."""
    data = tomllib.loads((resources.files("gpsins.sim") / "scenarios" / "default.toml").read_text())
    keep, total = [], 0.0
    for seg in data["segment"]:
        keep.append(seg)
        total += seg["duration_s"]
        if total > 110:
            break
    keep.append({"label": "stop", "duration_s": 10, "speed_mps": 0})
    labels = {s["label"] for s in keep}
    data["segment"] = keep
    data["obstruction"] = [o for o in data.get("obstruction", []) if o.get("segment", keep[0]["label"]) in labels]
    data.setdefault("imu", {})["rate_hz"] = 100
    sim = simulate(scenario.parse(data, "short"), 3)
    d = tmp_path_factory.mktemp("simset")
    # Without the land-vehicle constraint: with it, a 50 ms IMU offset left out costs only 5 % of IMU-point
    # RMS (0.51 vs 0.49 m) and 4 % of 3-sigma coverage, since the constraint holds the velocity the
    # offset would bend; these tests are about what the mounting, lever and offset alone do.
    path = dw.write_dataset(sim, d, imu_to_body_ypr_deg=MOUNT, antenna_m=LEVER, imu_time_offset_s=OFFSET_S,
                            imu_format="rates", vehicle_kind="none")
    return sim, path


@pytest.fixture(scope="module")
def right_dir(sim_set, tmp_path_factory):
    """The right run's results directory and what _run_variant gives."""
    d = tmp_path_factory.mktemp("right")
    return d / "right", _run_variant(sim_set, d, "right")


@pytest.fixture(scope="module")
def right_run(right_dir):
    return right_dir[1]


def _run_variant(sim_set, tmp_path, name, edit=lambda s: s, **kw):
    sim, path = sim_set
    p = path.parent / f"{name}.toml"
    p.write_text(edit(path.read_text()))
    res = replay.replay(p, tmp_path / name, outages="40:10:25", **kw)
    z = results_mod.load(tmp_path / name)
    sc = sim.scenario
    t_run = z["t"] + int(z["week"]) * 604800.0 - (sc.start.gps_week * 604800.0 + sc.start.gps_tow_s)
    # IMU-point errors against the simulator's truth, NED, after the heading is known (plus 5 s).
    e = np.array([earth.ecef_to_ned_matrix(*earth.ecef_to_geodetic(r)[:2]).T @ (x - r)
                  for x, r in zip(z["r_ecef"][::20], sim.truth.position_at(t_run[::20]))])
    hk = np.flatnonzero(z["heading_known"])
    ok = t_run[::20] > t_run[hk[0]] + 5.0
    inside3 = np.mean(np.abs(e[ok]) <= 3 * z["sigma_ned_m"][::20][ok], axis=0)
    rms_h = float(np.sqrt(np.mean(e[ok, 0] ** 2 + e[ok, 1] ** 2)))
    return res.summary, inside3, rms_h


def test_sim_data_set_with_the_right_mounting_lever_and_offset_is_inside_3_sigma(sim_set, tmp_path):
    s, inside3, rms_h = _run_variant(sim_set, tmp_path, "right")  # (its own directory: the files are read here)
    print(f"\nright: IMU-point H RMS {rms_h:.3f} m, inside 3 sigma {inside3}, drift RMS "
          f"{s['scoring']['horizontal_m']['rms']:.2f} m")
    assert np.all(inside3 >= 0.97)
    assert rms_h < 1.5
    assert s["dataset"]["imu_time_offset_s"] == OFFSET_S
    np.testing.assert_allclose(s["dataset"]["imu_to_body"], dw.ypr_matrix(*MOUNT), atol=1e-12)
    cfg = tomllib.loads((tmp_path / "right" / "config.toml").read_text())
    assert cfg["lever_arm_body_m"] == list(LEVER) and cfg["imu_rate_hz"] == pytest.approx(100, rel=1e-3)
    # The antenna point written: IMU point + C_eb lever arm.
    z = results_mod.load(tmp_path / "right")
    from gpsins import _core
    np.testing.assert_allclose(z["r_point_ecef"][-1], z["r_ecef"][-1] + _core.dcm_from_quat(z["q_eb"][-1]) @ LEVER,
                               atol=1e-9)


def test_a_lagged_fix_velocity_is_measured_and_moved_to_its_fix(sim_set, tmp_path):
    # The simulator's receiver states the antenna's mean velocity over the 0.2 s fix interval just ended (its
    # own truth, not the filter's model): the lag measured from its fixes is half the interval, and with it
    # the filter's velocity is closer to the truth and its fix-velocity updates agree with their sigmas.
    sim, _ = sim_set
    path = dw.write_dataset(sim, tmp_path / "set", imu_to_body_ypr_deg=MOUNT, antenna_m=LEVER,
                            imu_time_offset_s=OFFSET_S, imu_format="rates", vehicle_kind="none",
                            velocity_mean_over_epoch=True)
    sc = sim.scenario
    out = {}
    for lag in ('"measured"', "0.0"):
        p = path.parent / f"lag_{lag.strip(chr(34))}.toml"
        p.write_text(path.read_text().replace('format = "rtklib-pos"\n',
                                              f'format = "rtklib-pos"\nvelocity_lag_s = {lag}\n'))
        res = replay.replay(p, tmp_path / p.stem)
        z = results_mod.load(tmp_path / p.stem)
        t_run = z["t"] + int(z["week"]) * 604800.0 - (sc.start.gps_week * 604800.0 + sc.start.gps_tow_s)
        ok = t_run > t_run[np.flatnonzero(z["heading_known"])[0]] + 5.0
        dv = z["v_ecef"][ok] - sim.truth.velocity_at(t_run[ok])
        nis = z["upd_nis"][z["upd_kind"] == 3].mean() / 3
        out[lag] = (res.summary, float(np.sqrt(np.mean(np.sum(dv ** 2, 1)))), nis)
    (s_lag, v_lag, nis_lag), (_, v_none, nis_none) = out['"measured"'], out["0.0"]
    print(f"\nlagged fix velocity: measured lag {s_lag['dataset']['velocity_lag_measured']['lag_s']:.3f} s; velocity "
          f"error RMS {v_lag:.3f} m/s (taken as instantaneous {v_none:.3f}); fix-velocity NIS/axis {nis_lag:.2f} "
          f"({nis_none:.2f})")
    # (measured 0.092 s: the fixes' 1-4 cm position noise leaves it about 0.01 s uncertain; velocity error
    # 0.023 vs 0.069 m/s, NIS 1.03 vs 1.47)
    assert s_lag["dataset"]["velocity_lag_measured"]["lag_s"] == pytest.approx(0.1, abs=0.02)
    assert v_lag < 0.5 * v_none and nis_lag < 0.8 * nis_none and nis_lag < 1.2


def _h_rms_between_outages(sim, out: Path, summary: dict) -> np.ndarray:
    """IMU-point horizontal error RMS against the simulator's truth (as _run_variant) over each stretch
    with GNSS between the run's outages (from 5 s after the heading is known)."""
    z = results_mod.load(out)
    sc = sim.scenario
    t_run = (z["t"] + int(z["week"]) * 604800.0 - (sc.start.gps_week * 604800.0 + sc.start.gps_tow_s))[::20]
    e = np.array([earth.ecef_to_ned_matrix(*earth.ecef_to_geodetic(r)[:2]).T @ (x - r)
                  for x, r in zip(z["r_ecef"][::20], sim.truth.position_at(t_run))])
    h2 = e[:, 0] ** 2 + e[:, 1] ** 2
    t_first = t_run[np.flatnonzero(z["heading_known"][::20])[0]] + 5.0
    outages = np.array(summary["outages"]["schedule"]) - sc.start.gps_tow_s
    starts, ends = np.concatenate([[t_first], outages[:, 1]]), np.concatenate([outages[:, 0], [np.inf]])
    rms = [np.sqrt(h2[(t_run >= a) & (t_run < b)].mean()) for a, b in zip(starts, ends)
           if ((t_run >= a) & (t_run < b)).sum() >= 10]
    return np.array(rms)


@pytest.mark.parametrize("name, edit", [
    ("no_lever", lambda s: re.sub(r"antenna_m = .*", "antenna_m = [0.0, 0.0, 0.0]", s)),
    ("mount_yaw_10", lambda s: re.sub(r"imu_to_body_ypr_deg = .*", "imu_to_body_ypr_deg = [-80.0, 3.0, 180.0]", s)),
    ("no_offset", lambda s: re.sub(r"time_offset_s = .*", "time_offset_s = 0.0", s)),
])
def test_a_wrong_lever_mounting_or_offset_is_visibly_worse(sim_set, right_dir, tmp_path, name, edit):
    """One criterion for every case: where GNSS holds the position (between outages: the right run is at
    the fixes' centimetres there, while in the outages the drift's own scatter hides a systematic error) the
    wrong run's IMU-point horizontal RMS is worse than the right run's in a one-sided paired t-test at 95 %
    over the stretches between the four outages. The closed forms say by how much for two of them: a lever
    left out puts the IMU point at the antenna, |L_h| = 0.671 m off; a mounting 10 deg off in yaw turns that
    lever by 10 deg, 2 sin(5 deg) |L_h| = 0.117 m."""
    from scipy.stats import t as student_t

    sim, _ = sim_set
    right_out, (right, _, rms_right) = right_dir
    wrong, _, rms_wrong = _run_variant(sim_set, tmp_path, name, edit)
    per_right = _h_rms_between_outages(sim, right_out, right)
    per_wrong = _h_rms_between_outages(sim, tmp_path / name, wrong)
    diff = per_wrong - per_right
    t_stat = diff.mean() / (diff.std(ddof=1) / np.sqrt(len(diff)))
    t_crit = student_t.ppf(0.95, len(diff) - 1)
    print(f"\n{name}: IMU-point H RMS between outages {np.round(per_wrong, 3)} m (right {np.round(per_right, 3)}), "
          f"paired t {t_stat:.1f} (95 %: {t_crit:.2f}); over the whole run {rms_wrong:.3f} m (right {rms_right:.3f})")
    # Measured: right 0.013-0.015 m; no lever 0.67-0.70 m; mounting 0.12-0.13 m; offset left out 0.016-0.031 m
    # (t 3.0). Over the whole run, outages included: 1.30x, 1.01x and 1.29x the right run's 0.71 m.
    assert len(diff) == 4
    assert t_stat > t_crit, (per_wrong, per_right)


def test_rates_with_every_fifth_row_missing_are_integrated_once(sim_set, right_run, tmp_path):
    """IMU rates cover each step by the trapezoid, a double one too: such a step is no lost frame
    to bridge. Bridging it as one (the core's way for frame increments) counted its motion twice."""
    sim, path = sim_set
    lines = (path.parent / "imu.csv").read_text().splitlines(keepends=True)
    (path.parent / "imu_sparse.csv").write_text(lines[0] + "".join(x for i, x in enumerate(lines[1:]) if i % 5 != 4))
    sparse = lambda s: s.replace('file = "imu.csv"', 'file = "imu_sparse.csv"')  # noqa: E731
    right, _, rms_right = right_run
    once, _, rms_once = _run_variant(sim_set, tmp_path, "sparse", sparse)
    twice, _, rms_twice = _run_variant(sim_set, tmp_path, "sparse_bridged", sparse,
                                       overrides={"imu_increments_cover_gaps": False})
    print(f"\nevery fifth IMU row missing: IMU-point H RMS {rms_once:.3f} m (all rows {rms_right:.3f}, the double "
          f"steps bridged {rms_twice:.3f}); drift RMS {once['scoring']['horizontal_m']['rms']:.2f} m (all rows "
          f"{right['scoring']['horizontal_m']['rms']:.2f}, bridged {twice['scoring']['horizontal_m']['rms']:.2f})")
    assert once["counters"]["imu_gaps_bridged"] == 0 < twice["counters"]["imu_gaps_bridged"]
    assert rms_once < 1.2 * rms_right
    assert once["scoring"]["horizontal_m"]["rms"] < 1.2 * right["scoring"]["horizontal_m"]["rms"]
    assert rms_twice > 2 * rms_once


def test_zero_standard_deviations_do_not_break_anything(sim_set, tmp_path):
    def zero(text):
        return text.replace('file = "receiver.pos"', 'file = "receiver_zero.pos"')
    sim, path = sim_set
    rows = []
    for line in (path.parent / "receiver.pos").read_text().splitlines():
        if not line.startswith("%"):
            tok = line.split()
            tok[7:13] = ["0.0000"] * 6  # sdn sde sdu sdne sdeu sdun
            tok[19:25] = ["0.00000"] * 6  # velocity sigmas
            line = " ".join(tok)
        rows.append(line)
    (path.parent / "receiver_zero.pos").write_text("\n".join(rows) + "\n")
    s, inside3, rms_h = _run_variant(sim_set, tmp_path, "zero", zero)
    cfg = tomllib.loads((tmp_path / "zero" / "config.toml").read_text())
    assert cfg["fix_velocity_sigma_mps"] == dataset_fixes.VELOCITY_SIGMA_FLOOR_MPS
    assert np.isfinite(s["scoring"]["horizontal_m"]["rms"]) and rms_h < 2.0
    assert s["counters"]["fixes_accepted"] > 0.9 * s["counters"]["fixes"]


def test_ins_mode_navigates_freely_after_the_initialisation(sim_set, right_run, tmp_path):
    s, _, _ = _run_variant(sim_set, tmp_path, "ins", mode="ins")
    t_free = s["ins"]["aiding_until_t"]
    z = results_mod.load(tmp_path / "ins")
    fixes_used = z["upd_t"][np.isin(z["upd_kind"], (1, 2, 3))]
    assert fixes_used.max() <= t_free and not np.isin(z["upd_kind"], (4, 5)).any()
    assert s["scoring"]["n_outages"] == 1 and s["scoring"]["per_outage"][0]["start"] == t_free
    loose = right_run[0]
    assert s["scoring"]["horizontal_m"]["worst"] > 10 * loose["scoring"]["horizontal_m"]["worst"]
    print(f"\nins: free from {t_free:.1f}, worst horizontal drift {s['scoring']['horizontal_m']['worst']:.1f} m")


def test_a_session_with_truth_is_scored_against_the_truth_at_the_imu(sim_set, tmp_path):
    from gpsins.sim.session import write_session

    sim, _ = sim_set
    write_session(sim, tmp_path / "session")
    res = replay.replay(tmp_path / "session", tmp_path / "out", outages="40:10:25")
    sc = res.summary["scoring"]
    assert sc["reference"] == "truth.npz" and sc["point"] == "imu" and sc["n_outages"] == 4
    z = results_mod.load(tmp_path / "out")
    sched = np.array(res.summary["outages"]["schedule"])
    gnss = np.isin(z["upd_kind"], (1, 2, 3))
    assert not np.any((z["upd_t"][gnss][:, None] >= sched[:, 0]) & (z["upd_t"][gnss][:, None] < sched[:, 1]))
    # Recomputed from the truth file (IMU point) and the written solution, every 10th truth epoch.
    t_week = sim.scenario.start.gps_week * 604800.0
    with np.load(tmp_path / "session" / "truth.npz") as tz:
        t_ref, r_ref = tz["tow_s"][::10], tz["r_ecef"][::10]
    np.testing.assert_allclose(z["r_point_ecef"], z["r_ecef"])
    use, e = _ned_errors(z["t"], z["r_ecef"], t_ref + t_week - int(z["week"]) * 604800.0, r_ref)
    tr = (t_ref + t_week - int(z["week"]) * 604800.0)[use]
    for (a, b), o in zip(sched, sc["per_outage"]):
        m = (tr >= a) & (tr < b)
        assert o["max_h_m"] == pytest.approx(np.hypot(e[m, 0], e[m, 1]).max(), rel=0.02)


def test_a_rinex_data_set_replays_loose_from_single_point_fixes_and_tight(shared_data, tmp_path):
    """GEONET 0759 (observations every 30 s) with a synthetic IMU standing level and facing north at the
    station for the first 20 minutes: both modes stay near the station's surveyed position."""
    import os

    r0 = np.array([-3976219.5082, 3382372.5671, 3652512.9849])  # the file's APPROX POSITION XYZ
    lat, lon, _ = earth.ecef_to_geodetic(r0)
    c_en = earth.ecef_to_ned_matrix(lat, lon)
    g_ned = c_en.T @ earth.gravity_ecef(r0)  # gravity incl. centrifugal, NED
    w_ned = c_en.T @ np.array([0.0, 0.0, 7.292115e-5])
    t0 = 1316 * 604800.0 + 6 * 86400.0  # 2005-04-02 00:00 GPST: Saturday of week 1316
    t = t0 - 5.0 + np.arange(0.0, 1200.0, 0.05)  # 20 Hz, starting 5 s before the first epoch
    rows = np.column_stack([t, np.tile(-g_ned, (len(t), 1)), np.tile(w_ned, (len(t), 1))])
    np.savetxt(tmp_path / "imu.csv", rows, delimiter=",", fmt="%.3f,%.9f,%.9f,%.9f,%.12e,%.12e,%.12e")
    rel = Path(os.path.relpath(shared_data, tmp_path)).as_posix()
    (tmp_path / "set.toml").write_text(f"""
[imu]
file = "imu.csv"
columns = ["t", "ax", "ay", "az", "gx", "gy", "gz"]
time = "gps_abs"
[gnss]
file = "{rel}/07590920.05o"
format = "rinex"
nav = "{rel}/07590920.05n"
[filter]
preset = "default"
initial_yaw_deg = 0.0
gyro_bias_cal_rad_per_s = [0.0, 0.0, 0.0]
accel_bias_cal_mps2 = [0.0, 0.0, 0.0]
gyro_scale_factor_cal = [0.0, 0.0, 0.0]
accel_scale_factor_cal = [0.0, 0.0, 0.0]
""")
    for mode in ("loose", "tight"):
        res = replay.replay(tmp_path / "set.toml", tmp_path / mode, mode=mode)
        z = results_mod.load(tmp_path / mode)
        e = np.array([c_en.T @ (x - r0) for x in z["r_ecef"][::200]])
        h = np.hypot(e[:, 0], e[:, 1])
        print(f"\nRINEX {mode}: horizontal RMS {np.sqrt(np.mean(h ** 2)):.2f} m, max {h.max():.2f} m, "
              f"vertical RMS {np.sqrt(np.mean(e[:, 2] ** 2)):.2f} m; {res.summary['counters']}")
        assert np.sqrt(np.mean(h ** 2)) < 5.0 and np.abs(e[:, 2]).max() < 20.0
    c = res.summary["counters"]
    # Unknown C/N0 (no S1 in the file) is not masked as weak: only the elevation mask removes some.
    assert c["pseudorange_epochs"] == 40 and c["pseudoranges_masked"] < 0.2 * (
        c["pseudoranges_used"] + c["pseudoranges_rejected"] + c["pseudoranges_masked"])
    # The receiver's clock drifts about 1.4 us/s (12.5 km between the 30 s epochs, 4 times the drift state's
    # prior sigma): its pseudoranges are used, not gated out, and the filter's drift agrees with the slope of
    # the clock that single-point positioning (matched to RTKLIB in test_gnss) solves for epoch by epoch.
    assert c["clock_reseeds"] <= 1 and c["pseudoranges_rejected"] < 0.1 * c["pseudoranges_used"]
    run = spp.solve(spp.from_rinex(shared_data / "07590920.05o", shared_data / "07590920.05n"))
    slope_mps = np.polyfit(run.t_abs[run.ok] - run.t_abs[0], run.clock_m[run.ok], 1)[0]
    z = results_mod.load(tmp_path / "tight")
    assert abs(slope_mps) > 300.0 and z["clock"][-1, 1] == pytest.approx(slope_mps, abs=1.0)


def test_report_of_a_data_set_has_the_drift_figure_and_table(walk_runs, tmp_path):
    import matplotlib.pyplot as plt

    from gpsins.report import page as report_page
    from gpsins.report import figures as report_figures

    (_, d_loose), (_, d_tight) = walk_runs[("walk_0827_ubx.toml", "loose")], walk_runs[("walk_0827_ubx.toml", "tight")]
    page = report_page.make_report([d_loose, d_tight], tmp_path / "rep")
    assert (tmp_path / "rep" / "outage_drift.png").exists()
    text = page.read_text()
    assert "## Drift per outage against gnss_1730_sf.pos (antenna point)" in text
    s = json.loads((d_loose / "run.json").read_text())["scoring"]
    row = next(x for x in text.splitlines() if x.startswith("| rms |"))
    assert f"| {s['horizontal_m']['rms']:.2f} |" in row
    figs = report_figures.build_figures([d_loose, d_tight])
    fig = figs["outage_drift.png"]
    ax = fig.axes[0]
    z = results_mod.load(d_loose)
    shown = np.concatenate([ln.get_ydata() for ln in ax.get_lines() if ln.get_color() == "tab:blue"
                            and ln.get_linestyle() == "-"])
    np.testing.assert_allclose(np.sort(shown), np.sort(z["drift_h_m"]))  # every drift epoch of the loose run
    # The tight run's range rates: each satellite's accepted innovations over their sigma, as recorded.
    zt = results_mod.load(d_tight)
    ax = figs["range_rate.png"].axes[0]
    drawn = {ln.get_label(): ln.get_ydata() for ln in ax.get_lines() if ln.get_label().startswith("PRN ")}
    k = (zt["upd_kind"] == 9) & (zt["upd_accepted"] > 0)
    assert len(drawn) == len(np.unique(zt["upd_id"][k])) >= 8
    m = k & (zt["upd_id"] == 10)
    np.testing.assert_allclose(drawn["PRN 10"], zt["upd_innovation"][m, 0] / zt["upd_innovation_sigma"][m, 0])
    assert (tmp_path / "rep" / "range_rate.png").exists()
    for f in figs.values():
        plt.close(f)


def test_outage_table_puts_the_smoothed_drift_beside_the_forward(tmp_path):
    import io

    from gpsins.report import terminal as report_terminal

    def scoring(h, v):
        return {"reference": "ref.pos", "point": "antenna",
                "per_outage": [{"start": 10.0, "end": 25.0, "n_ref": 60, "max_h_m": h, "max_v_m": v}],
                "horizontal_m": {"mean": h, "worst": h, "rms": h}, "vertical_m": {"mean": v, "worst": v, "rms": v},
                "outside": {"n": 9, "rms_h_m": h / 100, "rms_v_m": v / 100}}

    summary = {"mode": "loose", "outages": {"gnss_first_t": 0.0}, "scoring": scoring(1.75, 4.25),
               "smoothed": {"scoring": scoring(0.14, 0.66)}}
    buf = io.StringIO()
    report_terminal.print_outage_table(summary, buf)
    rows = [ln for ln in buf.getvalue().splitlines() if ln.startswith("│ rms") or ln.startswith("│ 1 ")]
    assert len(rows) == 2
    for row in rows:
        cells = [c.strip() for c in row.strip("│").split("│")]
        assert cells[-4:] == ["1.75", "4.25", "0.14", "0.66"]
    summary.pop("smoothed")
    buf = io.StringIO()
    report_terminal.print_outage_table(summary, buf)
    assert "smooth" not in buf.getvalue()


# --- the IMU time offset as a state (estimate_time_offset) -----------------------------------------------------

def test_a_missing_imu_offset_is_estimated_and_the_solution_recovers(sim_set, right_run, tmp_path):
    """The sim's IMU stamps are OFFSET_S early; declared 0, the state must find OFFSET_S (the simulator's
    truth, not anything the filter printed) and the IMU point's error must come back near the declared run's."""
    no_offset = lambda s: re.sub(r"time_offset_s = .*", "time_offset_s = 0.0", s)  # noqa: E731
    _, _, rms_right = right_run
    _, _, rms_off = _run_variant(sim_set, tmp_path, "undeclared", no_offset)
    on, _, rms_on = _run_variant(sim_set, tmp_path, "undeclared_estimated", no_offset,
                                 overrides={"estimate_time_offset": True}, smooth=True)
    to = on["time_offset"]
    z = results_mod.load(tmp_path / "undeclared_estimated")
    first = int(np.argmin(z["smooth_t"]))  # the smoothed solution's first epoch
    sm_offset, sm_sigma = z["smooth_time_offset_s"][first], z["smooth_sigma"][first, -1]
    print(f"\nundeclared {OFFSET_S} s IMU offset estimated: {to['estimate_s']:.4f} s (sigma {to['sigma_s']:.4f}); "
          f"IMU-point H RMS {rms_on:.3f} m (state off {rms_off:.3f}, declared right {rms_right:.3f}); smoothed "
          f"{sm_offset:.4f} s at the start (sigma {sm_sigma:.4f})")
    assert to["applied_s"] == 0.0
    assert abs(to["estimate_s"] - OFFSET_S) < 3 * to["sigma_s"]
    assert abs(to["estimate_s"] - OFFSET_S) < 0.01
    assert to["sigma_s"] < 0.01
    # (measured: 0.767 m against 0.941 off and 0.707 declared; most of what remains is the first 35 s, before the
    # estimate has settled. Its positions are at GNSS time: the nominal's moved back by v dt_imu.)
    assert rms_off > 1.2 * rms_right
    assert rms_on < rms_right + 0.4 * (rms_off - rms_right)
    # Per epoch: the column and its sigma (the last state), the sigma shrinking from its prior.
    assert z["time_offset_s"][-1] == to["estimate_s"] and z["sigma"][-1, -1] == to["sigma_s"]
    assert z["sigma"][0, -1] == pytest.approx(0.05, rel=0.05)
    # The smoother carries the offset back to the start.
    assert abs(sm_offset - OFFSET_S) < 3 * sm_sigma
    assert sm_sigma < 0.5 * z["sigma"][0, -1]


def test_a_declared_imu_offset_leaves_an_estimate_of_zero(sim_set, tmp_path):
    s, _, _ = _run_variant(sim_set, tmp_path, "declared_estimated", overrides={"estimate_time_offset": True})
    to = s["time_offset"]
    print(f"\ndeclared {OFFSET_S} s IMU offset: residual estimate {to['estimate_s']:.4f} s (sigma {to['sigma_s']:.4f})")
    assert to["applied_s"] == OFFSET_S
    assert abs(to["estimate_s"]) < 3 * to["sigma_s"]
    assert to["sigma_s"] < 0.01


def test_without_the_offset_state_nothing_reports_one(right_run):
    right, _, _ = right_run
    assert "time_offset" not in right


def test_an_imu_gap_restart_keeps_the_offset_estimate_and_its_sigma(sim_set, tmp_path):
    """The offset is a property of the sensors: a restart after an IMU gap (here 2 s cut out at 80 s, where the
    estimate has settled) resets the navigation but carries dt_imu and its variance over. The gap falls in a
    turn; a heading taken from a fix inside it, while the IMU was still missing, left the yaw 11 deg off and let the
    constant-velocity coast teach the offset (issue 36: -80 +- 4 ms at the end; now 45 +- 7 ms, 49 +- 7 without the
    gap)."""
    sim, path = sim_set
    lines = (path.parent / "imu.csv").read_text().splitlines(keepends=True)
    t = np.array([float(x.split(",", 1)[0]) for x in lines[1:]])
    cut = (t > t[0] + 80.0) & (t < t[0] + 82.0)
    (path.parent / "imu_gap.csv").write_text(lines[0] + "".join(x for x, c in zip(lines[1:], cut) if not c))
    gap = lambda s: re.sub(r"time_offset_s = .*", "time_offset_s = 0.0", s).replace(  # noqa: E731
        'file = "imu.csv"', 'file = "imu_gap.csv"')
    s, _, _ = _run_variant(sim_set, tmp_path, "gap_estimated", gap, overrides={"estimate_time_offset": True})
    restarts = [e["t"] for e in s["events"] if e["kind"] == "imu_gap_restart"]
    assert len(restarts) == 1
    z = results_mod.load(tmp_path / "gap_estimated")
    before, after = np.searchsorted(z["t"], restarts[0] - 2.0) - 1, np.searchsorted(z["t"], restarts[0], side="right")
    print(f"\nIMU gap restart: offset {z['time_offset_s'][before]:.4f} s (sigma {z['sigma'][before, -1]:.4f}) before, "
          f"{z['time_offset_s'][after]:.4f} s (sigma {z['sigma'][after, -1]:.4f}) after; final {s['time_offset']}")
    assert z["sigma"][after, -1] <= 1.05 * z["sigma"][before, -1] < 0.02  # not back at its 0.05 s prior
    assert abs(z["time_offset_s"][after] - z["time_offset_s"][before]) < 0.005
    assert abs(s["time_offset"]["estimate_s"] - OFFSET_S) < 3 * s["time_offset"]["sigma_s"]

"""The simulated reference system (dual-antenna RTK, seed 004 section 4.2) and its file:
accuracies against the report's Tables 4.3 and 4.4 measured on the truth, outages where the
satellites or the dynamics say there must be, and the reader's handling of damage."""

import numpy as np
import pytest

from gpsins.formats import reference
from gpsins import sim
from gpsins.sim import scenario
from gpsins.replay import results as results_mod
from gpsins.sim.session import write_session

G0 = 9.80665


@pytest.fixture(scope="module")
def session(tmp_path_factory):
    s = sim.simulate(scenario.load("default"), seed=0)
    d = write_session(s, tmp_path_factory.mktemp("ref") / "s")
    return s, d, reference.load(d)


def _truth_at(s, ref):
    tr = s.truth
    t = ref.gps_tow_s - s.scenario.start.gps_tow_s
    yaw = np.interp(t, tr.t, np.unwrap(tr.ypr[:, 0]))
    pitch = np.interp(t, tr.t, tr.ypr[:, 1])
    return t, tr.position_at(t), yaw, pitch


def test_reference_accuracy_matches_the_report(session):
    """RTK about 0.01 m 3D RMS (Table 4.3); heading 0.004/L rad and pitch 0.008/L rad RMS for
    L = 1.5 m, i.e. 0.15 and 0.31 deg (Table 4.4), and the file's sigmas say the same."""
    s, _, ref = session
    t, r, yaw, pitch = _truth_at(s, ref)
    ok, aok = ref.position_ok, ref.attitude_ok
    assert ok.sum() > 300 and aok.sum() > 300
    rms3d = np.sqrt(np.mean(np.sum((ref.r_ecef_m[ok] - r[ok]) ** 2, axis=1)))
    dh = np.degrees((ref.heading_rad[aok] - yaw[aok] + np.pi) % (2 * np.pi) - np.pi)
    dp = np.degrees(ref.pitch_rad[aok] - pitch[aok])
    assert 0.006 < rms3d < 0.014, rms3d
    assert 0.10 < np.sqrt(np.mean(dh ** 2)) < 0.20
    assert 0.21 < np.sqrt(np.mean(dp ** 2)) < 0.41
    assert np.allclose(np.degrees(ref.sigma_heading_rad[aok]), np.degrees(0.004 / 1.5), atol=1e-4)
    assert np.allclose(np.degrees(ref.sigma_pitch_rad[aok]), np.degrees(0.008 / 1.5), atol=1e-4)
    assert np.allclose(np.sqrt(np.sum(ref.sigma_ned_m[ok] ** 2, axis=1)), 0.01, atol=1e-4)
    # GPS-timed epochs on whole tenths of a second, one per 0.1 s over the run
    assert np.allclose(np.diff(ref.gps_seconds()), 0.1, atol=1e-6)
    assert np.allclose(np.round(ref.gps_tow_s * 10) / 10, ref.gps_tow_s, atol=1e-6)


def test_reference_drops_out_where_it_must(session):
    """No RTK with fewer than 5 tracked satellites (nor for 10 s after), no attitude with fewer
    than 4; none while shaken beyond 0.6 g or turning faster than 60 deg/s (the report's
    vibration-sensitive receiver); and standing still in open sky it is there."""
    s, _, ref = session
    t = ref.gps_tow_s - s.scenario.start.gps_tow_s
    g, tr = s.gnss, s.truth
    epoch = np.clip(np.searchsorted(g.t, t, side="right") - 1, 0, len(g.t) - 1)
    sats = g.tracked[epoch].sum(axis=1)
    assert not np.any(ref.position_ok & (sats < 5))
    assert not np.any(ref.attitude_ok & (sats < 4))
    k = np.clip(np.searchsorted(tr.t, t), 0, len(tr.t) - 1)
    shaken = (np.abs(np.linalg.norm(tr.f_body[k], axis=1) - G0) > 0.6 * G0) | (
        np.degrees(np.linalg.norm(tr.w_ib_body[k], axis=1)) > 60.0)
    assert not np.any((ref.position_ok | ref.attitude_ok) & shaken)
    low = np.flatnonzero(sats < 5)
    after = (low[:, None] + np.arange(1, 100)[None, :]).ravel()
    assert not np.any(ref.position_ok[after[after < len(t)]])
    standing = t < 30.0  # Start-A, 8 satellites
    assert ref.position_ok[(t > 11.0) & standing].all() and ref.attitude_ok[(t > 4.0) & standing].all()
    moving = np.linalg.norm(tr.velocity_at(t), axis=1) > 0.5
    assert ref.position_ok[moving].mean() < 0.6  # the report's "long outages"


def test_reference_sits_beside_the_session_and_is_named_in_the_sidecar(session):
    import json
    _, d, ref = session
    assert (d / "reference.csv").exists()
    assert json.loads((d / "session.json").read_text())["simulation"]["reference"] == "reference.csv"
    assert not ref.damaged_lines
    assert (d / "reference.csv").read_text().startswith(reference.MAGIC)


def test_round_trip_with_outages_and_damage(tmp_path):
    n = 5
    tow = 604799.8 + 0.1 * np.arange(n)  # crosses a week
    r = np.array([[3.1e6, 1.0e6, 5.4e6]]) + np.arange(n)[:, None]
    r[1] = np.nan
    head = np.radians([10.0, 20.0, np.nan, 40.0, 50.0])
    pitch = np.radians([1.0, 2.0, np.nan, 4.0, 5.0])
    p = tmp_path / "reference.csv"
    reference.write(p, 1590, tow, r, np.full((n, 3), 0.0058), head, pitch, 0.00267, 0.00533)
    ref = reference.read(p)
    assert list(ref.gps_week) == [1590, 1590, 1591, 1591, 1591]
    assert np.allclose(ref.gps_seconds(), 1590 * 604800.0 + tow, atol=1e-6)
    assert list(ref.position_ok) == [True, False, True, True, True]
    assert list(ref.attitude_ok) == [True, True, False, True, True]
    assert np.allclose(ref.r_ecef_m[ref.position_ok], r[[0, 2, 3, 4]], atol=1e-4)
    assert np.allclose(np.degrees(ref.heading_rad[ref.attitude_ok]), [10, 20, 40, 50], atol=1e-4)
    lines = p.read_text().splitlines()
    lines.insert(5, "1590,garbage,1,2")
    lines.insert(6, "1590,x,1,2,3,,,,,,,")
    p.write_text("\n".join(lines) + "\n")
    damaged = reference.read(p)
    assert [num for num, _ in damaged.damaged_lines] == [6, 7]  # named by line, the rest kept
    assert len(damaged.gps_tow_s) == n
    p.write_text("no header\n")
    with pytest.raises(reference.ReferenceError, match=r"reference\.csv: line 1: header"):
        reference.read(p)
    with pytest.raises(reference.ReferenceError, match="no reference file"):
        reference.load(tmp_path / "nowhere")


def test_reference_can_be_switched_off(tmp_path):
    from gpsins.sim.scenario import parse
    import tomllib
    sc = parse(tomllib.loads('[[segment]]\nlabel = "x"\nduration_s = 20\n[reference]\nenabled = false\n'), "t")
    d = write_session(sim.simulate(sc, seed=0), tmp_path / "s")
    assert not (d / "reference.csv").exists()


def test_compare_scores_an_estimate_against_the_reference(session):
    """The truth as the 'estimate' scores the reference's own errors; a 1 m north offset and a
    heading bias across +-180 deg show up as themselves."""
    s, _, ref = session
    tr = s.truth
    gps0 = s.scenario.start.gps_week * 604800.0 + s.scenario.start.gps_tow_s
    i = s.truth_at_imu
    yaw, pitch = tr.ypr[i, 0], tr.ypr[i, 1]
    e = reference.compare(ref, gps0 + tr.t[i], tr.r_ecef[i], yaw, pitch)
    summ = e.summary()
    assert 0.003 < summ["horizontal_rms_m"] < 0.012 and summ["position_epochs"] == ref.position_ok.sum()
    assert 0.10 < summ["heading_rms_deg"] < 0.20 and 0.21 < summ["pitch_rms_deg"] < 0.41
    north = np.stack([-np.sin(tr.lat[i]) * np.cos(tr.lon[i]), -np.sin(tr.lat[i]) * np.sin(tr.lon[i]),
                      np.cos(tr.lat[i])], -1)
    shifted = reference.compare(ref, gps0 + tr.t[i], tr.r_ecef[i] + north, yaw + np.radians(179.0), pitch)
    ok = np.all(np.isfinite(shifted.position_ned_m), axis=1)
    assert np.allclose(shifted.position_ned_m[ok] - e.position_ned_m[ok], [1.0, 0.0, 0.0], atol=1e-3)
    good = np.isfinite(shifted.heading_rad)
    wrapped = np.mod(shifted.heading_rad[good] - e.heading_rad[good] + np.pi, 2 * np.pi) - np.pi
    assert np.allclose(np.degrees(wrapped), 179.0, atol=1e-6)
    assert np.all(np.abs(shifted.heading_rad[good]) <= np.pi)


def test_summary_block_by_block_equals_the_whole_comparison(session, monkeypatch):
    """Replay scores its reference system block by block without the per-epoch arrays: the same figures
    as the whole comparison's, recomputed here from its arrays."""
    s, _, ref = session
    tr, i = s.truth, s.truth_at_imu
    gps0 = s.scenario.start.gps_week * 604800.0 + s.scenario.start.gps_tow_s
    args = (ref, gps0 + tr.t[i], tr.r_ecef[i] + 0.3, tr.ypr[i, 0] + 0.01, tr.ypr[i, 1])
    e = reference.compare(*args)
    pos = np.all(np.isfinite(e.position_ned_m), axis=1)
    att = np.isfinite(e.heading_rad)
    monkeypatch.setattr(reference, "COMPARE_BLOCK", 37)
    got = reference.compare_summary(*args)
    assert got["epochs"] == len(e.gps_s) and got["position_epochs"] == pos.sum() and got["attitude_epochs"] == att.sum()
    assert got["horizontal_rms_m"] == pytest.approx(np.sqrt(np.mean(np.sum(e.position_ned_m[pos, :2] ** 2, 1))),
                                                    rel=1e-12)
    assert got["vertical_rms_m"] == pytest.approx(np.sqrt(np.mean(e.position_ned_m[pos, 2] ** 2)), rel=1e-12)
    assert got["heading_rms_deg"] == pytest.approx(np.degrees(np.sqrt(np.mean(e.heading_rad[att] ** 2))), rel=1e-12)
    assert got["reference_horizontal_sigma_m"] == pytest.approx(
        np.sqrt(np.mean(np.hypot(*e.sigma_ned_m[pos, :2].T) ** 2)), rel=1e-12)
    assert got == pytest.approx(reference.compare(*args).summary(), rel=1e-12)


def test_replay_scores_a_session_against_its_reference_system(session, tmp_path):
    """run.json's reference scoring equals the truth-based errors at the reference's epochs,
    to within the reference's own centimetre-level error."""
    from gpsins.replay import run

    s, d, ref = session
    res = run.replay(d, tmp_path / "r")
    got = res.summary["reference_system"]
    z = results_mod.load(tmp_path / "r")
    t_sol = z["t"] + int(z["week"]) * 604800.0
    t_ref = ref.gps_seconds()[ref.position_ok]
    t_ref = t_ref[(t_ref >= t_sol[0]) & (t_ref <= t_sol[-1])]
    ok = np.all(np.isfinite(z["err_ned_m"]), axis=1)
    e = np.stack([np.interp(t_ref, t_sol[ok], z["err_ned_m"][ok, i]) for i in range(3)], axis=-1)
    h_truth = float(np.sqrt(np.mean(e[:, 0] ** 2 + e[:, 1] ** 2)))
    assert got["position_epochs"] == len(t_ref)
    assert abs(got["horizontal_rms_m"] - h_truth) < 0.05, (got, h_truth)
    assert np.isfinite(got["heading_rms_deg"]) and got["attitude_epochs"] > 0


def test_fast_reader_equals_the_line_parser(session, monkeypatch):
    """A clean file goes through pyarrow's CSV reader; the line-by-line parser (used for damaged
    files) reads the same numbers, outages' empty fields included."""
    _, d, fast = session
    assert (~fast.position_ok).any() and (~fast.attitude_ok).any()
    monkeypatch.setattr(reference, "_read_clean", lambda path: None)
    slow = reference.load(d)
    for name in ("gps_week", "gps_tow_s", "r_ecef_m", "sigma_ned_m", "heading_rad", "pitch_rad",
                 "sigma_heading_rad", "sigma_pitch_rad"):
        a, b = getattr(fast, name), getattr(slow, name)
        assert a.dtype == b.dtype and np.array_equal(a, b, equal_nan=True), name

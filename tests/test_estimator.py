"""Plug-in estimators (issue 40): the built-in filter wrapped as one gives exactly the native scores;
any other is scored the same way, checked here against errors computed without the scorer."""

import json
import sys
from pathlib import Path

import numpy as np
import pytest

from gpsins import cli, sim
from gpsins.nav import estimator
from gpsins.replay import run, results
from gpsins.sim.session import write_session

from drives import START, stand_and_drive


@pytest.fixture(scope="module")
def drive(tmp_path_factory):
    sc = stand_and_drive("plug", 20, 70)
    s = sim.simulate(sc, seed=2)
    d = tmp_path_factory.mktemp("plug") / "session"
    write_session(s, d)
    return s, d


def receiver_fixes(inputs):
    """An estimator that is no filter at all: the receiver's own fixes, no attitude."""
    f = inputs.fixes[np.isin(inputs.fixes[:, 9], (2, 3))]
    return {"t": f[:, 0], "r_ecef": f[:, 1:4], "v_ecef": f[:, 4:7], "q_eb": np.full((len(f), 4), np.nan)}


def _sections(out):
    doc = json.loads((out / "run.json").read_text())
    return {k: doc[k] for k in ("errors", "scoring", "imu_samples", "epochs")}


@pytest.mark.parametrize("mode", ["loose", "tight"])
def test_the_builtin_filter_as_a_plug_in_scores_exactly_as_native(drive, tmp_path, mode):
    _, d = drive
    native = run.replay(d, tmp_path / "native", mode=mode, outages="35:10:25")
    plugged = run.replay(d, tmp_path / "plugin", mode=mode, outages="35:10:25",
                            estimator="gpsins.nav.estimator:builtin")
    assert plugged.summary["estimator"] == "gpsins.nav.estimator:builtin"
    assert _sections(native.out) == _sections(plugged.out)
    a, b = results.load(native.out), results.load(plugged.out)
    for k in ("t", "r_ecef", "sigma_ned_m", "err_ned_m", "nees9"):
        assert np.array_equal(a[k], b[k], equal_nan=True), k


def test_any_estimator_is_scored_like_the_filter(drive, tmp_path, monkeypatch):
    """The receiver's fixes as a solution: run.json's horizontal and vertical RMS against the truth are
    the ones computed here from the simulator's truth with this test's own local-level rotation."""
    s, d = drive
    monkeypatch.setitem(sys.modules, "plugin_under_test", sys.modules[__name__])
    res = run.replay(d, tmp_path / "fixes", estimator="plugin_under_test:receiver_fixes")
    f = sim.fix_table(s)
    f = f[np.isin(f[:, 9], (2, 3))]
    t = f[:, 0] + START["gps_tow_s"]  # the replay's time base: seconds of the week
    inside = (f[:, 0] >= s.truth.t[0]) & (f[:, 0] <= s.truth.t[-1])
    d_ecef = f[inside, 1:4] - s.truth.position_at(f[inside, 0])
    lat, lon = np.radians(START["lat_deg"]), np.radians(START["lon_deg"])
    north = np.array([-np.sin(lat) * np.cos(lon), -np.sin(lat) * np.sin(lon), np.cos(lat)])
    east = np.array([-np.sin(lon), np.cos(lon), 0.0])
    down = -np.array([np.cos(lat) * np.cos(lon), np.cos(lat) * np.sin(lon), np.sin(lat)])
    h = np.hypot(d_ecef @ north, d_ecef @ east)
    e = res.summary["errors"]
    print(f"{inside.sum()} fixes from t = {t[inside][0]:.1f}: H RMS {np.sqrt(np.mean(h ** 2)):.3f} m here, "
          f"{e['horizontal_rms_m']:.3f} m by the scorer")
    assert e["horizontal_rms_m"] == pytest.approx(np.sqrt(np.mean(h ** 2)), rel=1e-3)
    assert e["vertical_rms_m"] == pytest.approx(np.sqrt(np.mean((d_ecef @ down) ** 2)), rel=1e-3)


@pytest.mark.parametrize("spec,says", [("nosuchmodule:f", "cannot import"), ("gpsins.nav.estimator:nosuch", "has no"),
                                       ("gpsins.nav.estimator", "package.module:name")])
def test_a_bad_estimator_is_one_line(drive, tmp_path, capsys, spec, says):
    _, d = drive
    assert cli.main(["replay", str(d), "--out", str(tmp_path / "o"), "--estimator", spec]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and says in err[0], err


def test_a_result_of_the_wrong_shape_is_refused_by_name():
    with pytest.raises(estimator.EstimatorError, match="r_ecef has shape"):
        estimator.as_solution({"t": [1.0, 2.0], "r_ecef": np.zeros((3, 3)), "v_ecef": np.zeros((2, 3)),
                               "q_eb": np.zeros((2, 4))}, "loose", 10, 2, "x:y")
    with pytest.raises(estimator.EstimatorError, match="increasing"):
        estimator.as_solution({"t": [2.0, 1.0]}, "loose", 10, 2, "x:y")


def test_score_of_a_replays_pos_gives_its_drift(tmp_path):
    """The walk replayed, then its solution.pos scored as an outside solution against the same data set:
    the drift of each outage as the replay's own (to the .pos's 0.1 mm). Outside the outages the file
    scores worse (0.087 against 0.046 m on the walk): a .pos has no update instants, so the solution is
    interpolated across the fixes' steps, which the replay's own scoring never does."""
    walk = Path(__file__).parent / "data" / "walk_0827" / "walk_0827.toml"
    own = run.replay(walk, tmp_path / "own")
    assert cli.main(["score", str(own.out / "solution.pos"), "--against", str(walk), "--out",
                     str(tmp_path / "scored")]) == 0
    a, b = (json.loads((p / "run.json").read_text())["scoring"] for p in (own.out, tmp_path / "scored"))
    assert a["n_scored"] == b["n_scored"] == 2
    for x, y in zip(a["per_outage"], b["per_outage"]):
        assert abs(x["max_h_m"] - y["max_h_m"]) < 1e-3 and abs(x["max_v_m"] - y["max_v_m"]) < 1e-3, (x, y)


def test_score_of_a_kf_gins_navigation_file(drive, tmp_path):
    """A replay's solution written here in KF-GINS's navigation layout (week, seconds of week, latitude,
    longitude, height, velocity NED, roll, pitch, yaw) and scored against the session: the errors
    against the truth are the replay's own, the attitude read back within the file's digits."""
    _, d = drive
    own = run.replay(d, tmp_path / "own")
    z = results.load(own.out)
    k = z["heading_known"]
    llh, ypr = z["llh"][k], z["ypr_deg"][k]
    c = np.stack([_ned_rows(lat, lon) for lat, lon in llh[:, :2]])  # rows north, east, down in ECEF
    v_ned = np.einsum("nij,nj->ni", c, z["v_ecef"][k])
    nav = np.column_stack([np.full(k.sum(), int(z["week"])), z["t"][k], np.degrees(llh[:, 0]),
                           np.degrees(llh[:, 1]), llh[:, 2], v_ned, ypr[:, 2], ypr[:, 1], ypr[:, 0]])
    f = tmp_path / "NavResult.nav"
    np.savetxt(f, nav, fmt=["%d", "%.6f"] + ["%.11f"] * 2 + ["%.5f"] * 4 + ["%.7f"] * 3)
    assert cli.main(["score", str(f), "--against", str(d), "--out", str(tmp_path / "scored")]) == 0
    a = json.loads((own.out / "run.json").read_text())["errors"]
    b = json.loads((tmp_path / "scored" / "run.json").read_text())["errors"]
    assert b["horizontal_rms_m"] == pytest.approx(a["horizontal_rms_m"], abs=1e-3)
    assert b["vertical_rms_m"] == pytest.approx(a["vertical_rms_m"], abs=1e-3)
    back = results.load(tmp_path / "scored")
    assert np.allclose(back["ypr_deg"][:, :2], ypr[:, :2], atol=1e-5)


def _ned_rows(lat: float, lon: float) -> np.ndarray:
    sl, cl, so, co = np.sin(lat), np.cos(lat), np.sin(lon), np.cos(lon)
    return np.array([[-sl * co, -sl * so, cl], [-so, co, 0.0], [-cl * co, -cl * so, -sl]])


def test_report_puts_any_number_of_named_results_side_by_side(drive, tmp_path, monkeypatch):
    """Built-in, plug-in and outside results on one page, each named by the user (five, past the
    palette's first four)."""
    _, d = drive
    monkeypatch.setitem(sys.modules, "plugin_under_test", sys.modules[__name__])
    outs = {"native-loose": run.replay(d, tmp_path / "l").out, "native-tight": run.replay(
        d, tmp_path / "t", mode="tight").out,
            "wrapped": run.replay(d, tmp_path / "w", estimator="gpsins.nav.estimator:builtin").out,
            "receiver": run.replay(d, tmp_path / "f", estimator="plugin_under_test:receiver_fixes").out}
    assert cli.main(["score", str(outs["native-loose"] / "solution.pos"), "--against", str(d), "--out",
                     str(tmp_path / "s")]) == 0
    outs["from-file"] = tmp_path / "s"
    assert cli.main(["report", *[f"{k}={v}" for k, v in outs.items()], "--out", str(tmp_path / "page")]) == 0
    page = (tmp_path / "page" / "report.md").read_text()
    for name in outs:
        assert f"## {name}" in page, name


def test_score_of_a_csv_with_declared_columns(drive, tmp_path, capsys):
    """The same solution as a CSV (seconds of week, latitude/longitude/height, NED velocity, a column to
    skip, quaternion) scores as the replay itself; a bad value is named by line and column."""
    _, d = drive
    own = run.replay(d, tmp_path / "own")
    z = results.load(own.out)
    k = z["heading_known"]
    llh = z["llh"][k]
    c = np.stack([_ned_rows(lat, lon) for lat, lon in llh[:, :2]])
    v_ned = np.einsum("nij,nj->ni", c, z["v_ecef"][k])
    table = np.column_stack([z["t"][k], np.degrees(llh[:, 0]), np.degrees(llh[:, 1]), llh[:, 2], v_ned,
                             np.zeros(k.sum()), z["q_eb"][k]])
    f = tmp_path / "mine.csv"
    np.savetxt(f, table, fmt="%.12f", delimiter=",", header="sow,lat,lon,h,vn,ve,vd,unused,qw,qx,qy,qz")
    cols = "t,lat_deg,lon_deg,h_m,vn,ve,vd,-,qw,qx,qy,qz"
    week = str(int(z["week"]))
    assert cli.main(["score", str(f), "--columns", cols, "--time", "gps_sow", "--week", week, "--against", str(d),
                     "--out", str(tmp_path / "scored")]) == 0
    a = json.loads((own.out / "run.json").read_text())["errors"]
    b = json.loads((tmp_path / "scored" / "run.json").read_text())["errors"]
    assert b["horizontal_rms_m"] == pytest.approx(a["horizontal_rms_m"], abs=1e-4)
    lines = f.read_text().splitlines()
    lines[5] = lines[5].replace(",", ",x", 1)
    f.write_text("\n".join(lines) + "\n")
    capsys.readouterr()
    assert cli.main(["score", str(f), "--columns", cols, "--time", "gps_sow", "--week", week, "--against", str(d),
                     "--out", str(tmp_path / "bad")]) == 2
    err = capsys.readouterr().err
    assert "mine.csv:6: column 2 (lat_deg)" in err, err

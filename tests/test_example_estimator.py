"""The example estimator (issue 40): examples/numpy_loose_ekf.py, a loosely coupled EKF in pure NumPy,
replayed as a plug-in. Its errors on a simulated drive are computed here from the simulator's truth
with this test's own local-level rotation, not the scorer's; the built-in filter's on the same data
are printed beside them."""

import tomllib
from pathlib import Path

import numpy as np
import pytest
from scipy.stats import chi2

from gpsins.replay import run, results
from gpsins import sim
from gpsins.sim.scenario import parse
from gpsins.sim.session import write_session

EXAMPLES = Path(__file__).resolve().parents[1] / "examples"
SPEC = "numpy_loose_ekf:estimate"
WALK = Path(__file__).parent / "data" / "walk_0827" / "walk_0827.toml"
WALK_OUTAGES = "25:15:45:45"  # 15 s outages from 25 s after the first fix, every 45 s
START = {"gps_week": 1590, "gps_tow_s": 419400.0, "lat_deg": 59.37, "lon_deg": 17.95, "height_m": 30.0,
         "heading_deg": 160.0}
SEED = 0  # the first seed, not a chosen one (seeds 0-7: the example's H RMS 1.46-2.09 m, NEES 17-49)

_lat, _lon = np.radians(START["lat_deg"]), np.radians(START["lon_deg"])
NORTH = np.array([-np.sin(_lat) * np.cos(_lon), -np.sin(_lat) * np.sin(_lon), np.cos(_lat)])
EAST = np.array([-np.sin(_lon), np.cos(_lon), 0.0])


@pytest.fixture(scope="module")
def examples_on_path():
    with pytest.MonkeyPatch.context() as mp:
        mp.syspath_prepend(str(EXAMPLES))
        yield


@pytest.fixture(scope="module")
def drive(tmp_path_factory, examples_on_path):
    """20 s standing, then 90 s of driving that turns left by 90 deg and right by 120 deg; the example
    and the built-in filter replayed on it."""
    sc = parse({"name": "example", "start": START,
                "segment": [{"label": "stand", "duration_s": 20, "speed_mps": 0},
                            {"label": "drive", "duration_s": 40, "speed_mps": 10, "turn_deg": 90},
                            {"label": "back", "duration_s": 50, "speed_mps": 12, "turn_deg": -120}]})
    s = sim.simulate(sc, seed=SEED)
    root = tmp_path_factory.mktemp("example_drive")
    write_session(s, root / "session")
    return (s, run.replay(root / "session", root / "example", estimator=SPEC),
            run.replay(root / "session", root / "native"))


def horizontal_errors(s, out, t_from):
    """Times and horizontal errors (m) of a replay's IMU-point positions against the truth, from t_from
    (seconds of the simulation) to the truth's end. The drive spans 1 km: one local level does."""
    z = results.load(out)
    t = z["t"] - START["gps_tow_s"]
    m = (t >= t_from) & (t <= s.truth.t[-1])
    d = z["r_ecef"][m] - s.truth.position_at(t[m])
    return t[m], np.hypot(d @ NORTH, d @ EAST)


def rms(x):
    return float(np.sqrt(np.mean(np.square(x))))


def test_the_example_tracks_a_drive_as_well_as_its_receiver(drive):
    """The bar, from the receiver alone: a loosely coupled filter of white-noise fixes cannot remove the
    fixes' own (correlated) errors, but it must not add much to them either: its horizontal RMS no worse
    than 1.5 x the receiver's over the same stretch, the margin for the IMU's bridging between 1 Hz
    fixes and the first seconds' heading error. The example's output starts once it knows its heading."""
    s, example, native = drive
    t, h = horizontal_errors(s, example.out, -np.inf)
    t0 = t[0]
    f = sim.fix_table(s)
    f = f[np.isin(f[:, 9], (2, 3)) & (f[:, 0] >= t0) & (f[:, 0] <= s.truth.t[-1])]
    d = f[:, 1:4] - s.truth.position_at(f[:, 0])
    h_fix = np.hypot(d @ NORTH, d @ EAST)
    _, h_native = horizontal_errors(s, native.out, t0)
    e, en = example.summary["errors"], native.summary["errors"]
    print(f"\ndrive from t = {t0:.1f} s: receiver H RMS {rms(h_fix):.2f} m ({len(f)} fixes); example H RMS "
          f"{rms(h):.2f} m (scorer {e['horizontal_rms_m']:.2f}), NEES {e['nees9_mean']:.1f}; built-in H RMS "
          f"{rms(h_native):.2f} m over the same stretch (scorer, all epochs with heading: "
          f"{en['horizontal_rms_m']:.2f}), NEES {en['nees9_mean']:.1f}")
    assert len(t) > 0.9 * 64 * (s.truth.t[-1] - t0)  # every IMU sample from the start on
    assert rms(h) <= 1.5 * rms(h_fix)
    assert e["horizontal_rms_m"] == pytest.approx(rms(h), rel=1e-3)  # the scorer agrees with this test


@pytest.mark.xfail(strict=True, reason="measured on this drive: NEES 44.6 against the 95 % band 2.70-19.02 "
                   "(the position's north and down errors 4 and 10 times their stated variance; seeds 0-7: 17-49; the "
                   "built-in filter 10.0): "
                   "the simulated receiver's errors are correlated over 12 s and this filter, by design, "
                   "takes each fix as white (UERE x DOP), so it averages them down and claims a smaller "
                   "position error than it has. Folding the configured correlated part into R as white "
                   "noise halves it (10-28) but does not cure it; that takes error states.")
def test_the_example_nees_lies_in_the_chi_square_band(drive):
    """Consistency: run.json's mean NEES of the 9 navigation states against the two-sided 95 % band of a
    single chi-square draw with 9 dof. The run's epochs are correlated over the fixes' correlation
    time, so their mean is no average of independent draws, and the band of independent ones would be
    too narrow; the mean of correlated draws varies no more than one draw does, so this band is loose."""
    _, example, _ = drive
    lo, hi = chi2.ppf([0.025, 0.975], 9)
    nees = example.summary["errors"]["nees9_mean"]
    print(f"\nexample NEES {nees:.1f}, band {lo:.2f}-{hi:.2f}")
    assert lo <= nees <= hi


@pytest.fixture(scope="module")
def walk(tmp_path_factory, examples_on_path):
    root = tmp_path_factory.mktemp("example_walk")
    return (run.replay(WALK, root / "example", estimator=SPEC, outages=WALK_OUTAGES),
            run.replay(WALK, root / "native", outages=WALK_OUTAGES))


def free_inertial_bound_m(fixes: np.ndarray, outage_s: float = 15.0) -> float:
    """How far an IMU drifts over an outage if the filter learnt nothing of it before: the start's
    velocity error as the fixes state it (sigma_v T), the accelerometer's turn-on bias (b_a T^2 / 2; the
    tilt levelling leaves with it cancels it at first, so it is counted once) and the gyro's, which tilts
    the platform by b_g t and so accelerates it by g b_g t (g b_g T^3 / 6), the biases at the 1-sigma
    priors the data set gives both filters (MEMS turn-on figures: 2e-3 rad/s, 0.03 m/s^2), summed as if
    aligned. Over 15 s: 0.7 + 3.4 + 11.0 = 15.2 m; the gyro's share grows as T^3."""
    cfg = tomllib.loads(WALK.read_text(encoding="utf-8"))["filter"]
    sigma_v = float(np.median(fixes[:, 13:15]))
    T = outage_s
    b_a, b_g = cfg["accel_bias_residual_mps2"], cfg["gyro_bias_residual_rad_per_s"]
    return sigma_v * T + b_a * T ** 2 / 2 + 9.81 * b_g * T ** 3 / 6


def _drift(res):
    sc = res.summary["scoring"]
    return [o["max_h_m"] for o in sc["per_outage"]], sc["horizontal_m"]["rms"], sc["outside"]["rms_h_m"]


def test_the_example_bridges_the_walk_outages_within_the_free_inertial_bound(walk):
    """The walk (a real hand-held MEMS unit, RTK fixes) with its two 15 s outages: each outage's worst
    horizontal drift is finite and below the free-inertial bound, the honest bar for a filter of
    position fixes alone; the built-in filter's (velocity and zero-velocity updates, correlated
    fix-error states) are printed beside."""
    example, native = walk
    per, drift_rms, outside = _drift(example)
    n_per, n_rms, n_outside = _drift(native)
    bound = free_inertial_bound_m(results.load(example.out)["fixes"])
    print(f"\nwalk outages {WALK_OUTAGES}: example drift {', '.join(f'{x:.2f}' for x in per)} m (RMS {drift_rms:.2f}), "
          f"outside RMS {outside:.3f} m, fix NIS/dof {example.summary['sources']['fix_3d']['nis_per_dof_mean']:.1f}; "
          f"built-in {', '.join(f'{x:.2f}' for x in n_per)} m (RMS {n_rms:.2f}), outside {n_outside:.3f} m; "
          f"free-inertial bound {bound:.1f} m")
    assert len(per) == 2 and np.all(np.isfinite(per))
    assert max(per) < bound


@pytest.mark.xfail(strict=True, reason="measured: outage 1 drifts 3.97 m, 5.4 x the 0.73 m horizontal sigma "
                   "the example states at its end (outage 2: 1.30 m, 3.0 x 0.43 m); the walk's gait is motion "
                   "its IMU's datasheet noise does not cover (fix NIS/dof 6 outside the outages). The "
                   "built-in filter is as overconfident there: 5.6 x and 4.0 x.")
def test_the_example_walk_drift_lies_within_its_own_sigma(walk):
    """Consistency in the outages: each outage's worst drift within 3 times the horizontal sigma (root
    sum of the north and east variances) the example states at the outage's end, its largest."""
    example, _ = walk
    z = results.load(example.out)
    for o in example.summary["scoring"]["per_outage"]:
        k = int(np.searchsorted(z["t"], o["end"])) - 1
        sigma_h = float(np.hypot(*z["sigma_ned_m"][k, :2]))
        print(f"\noutage from {o['start']:.1f}: drift {o['max_h_m']:.2f} m, sigma_h {sigma_h:.2f} m")
        assert o["max_h_m"] <= 3 * sigma_h

"""The ``report2005`` preset (the report's hand tuning) run on the simulated default drive, against the
magnitudes seed 004 states in chapter 7 for its car run, in its units (ENU metres, degrees):

- loose, segments L-O: the filter differs from the reference by about 20 m east, 10 m north, 22 m up
  (7.1.2.1); at the stop at the end pitch and yaw errors are about 0.5 deg and 5 deg (7.1.2.2);
- tight, segments L-O: about 18 m east, 22 m north, 15 m up (7.2.2.1); at the end 0.3 deg and 7 deg (7.2.2.2).

The report shows one run; here each figure is the median over five simulated runs (seeds 0-4), so that
a match or a miss is not one noise draw's luck (seed 0 alone once matched the pitch, at 0.42 deg, which the
median does not). The L-O peaks, which scatter most, are compared with one run's 95 % prediction interval
from the five instead. What matches is asserted; what does not is a strict xfail that says by how much, and the
preset's description says the same.
"""

import numpy as np
import pytest

from gpsins.replay import run, results
from gpsins.replay import inputs as replay_inputs
from gpsins import sim
from gpsins.sim import scenario
from gpsins.sim.session import write_session

REPORT = {"loose": {"enu_m": (20.0, 10.0, 22.0), "pitch_deg": 0.5, "yaw_deg": 5.0},
          "tight": {"enu_m": (18.0, 22.0, 15.0), "pitch_deg": 0.3, "yaw_deg": 7.0}}
L_TO_O = ("L-M", "M-N", "N-O")
SEEDS = range(5)


@pytest.fixture(scope="module")
def runs(tmp_path_factory):
    """Per mode, one results dict per seed."""
    out = {"loose": [], "tight": []}
    for seed in SEEDS:
        root = tmp_path_factory.mktemp(f"report2005_{seed}")
        write_session(sim.simulate(scenario.load("default"), seed=seed), root / "session")
        inp = replay_inputs.load_inputs(root / "session", modes=("loose", "tight"), config="report2005")
        for mode in out:
            run.run_mode(inp, root / mode, mode=mode)
            out[mode].append(results.load(root / mode))
    return out


def _median(f, zs) -> np.ndarray:
    return np.median([f(z) for z in zs], axis=0)


def _l_to_o_peaks(z) -> np.ndarray:
    """Largest |east|, |north|, |up| error over segments L-M to N-O."""
    m = np.zeros(len(z["t"]), bool)
    for label, (a, b) in zip(z["seg_labels"], z["seg_t"]):
        if str(label) in L_TO_O:
            m |= (z["t"] >= a) & (z["t"] < b)
    e = z["err_ned_m"][m]
    return np.nanmax(np.abs(np.column_stack([e[:, 1], e[:, 0], e[:, 2]])), axis=0)


def _end_errors(z) -> np.ndarray:
    """Mean |yaw| and |pitch| error over the last 10 s (the car stands still at the end)."""
    end = z["t"] > z["t"][-1] - 10.0
    return np.nanmean(np.abs(z["err_ypr_deg"][end, :2]), axis=0)


@pytest.mark.xfail(strict=True, reason="median over seeds 0-4 of the pitch error at the stop: 3.7 deg (loose) and "
                                       "3.9 deg (tight), 1.2-9.6 deg per seed, against the report's 0.5 and 0.3 deg")
@pytest.mark.parametrize("mode", ["loose", "tight"])
def test_pitch_at_the_stop_is_the_reports(runs, mode):
    _, pitch = _median(_end_errors, runs[mode])
    assert pitch <= 2 * REPORT[mode]["pitch_deg"]


def _one_run_interval(peaks: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """The report's figure is one run's peak; ours scatter by a factor of 2-4 from seed to seed. So the bar is
    the 95 % prediction interval of one more run from the seeds' log peaks (Student t; the log spread pooled over
    east, north and up, 3 x (seeds - 1) degrees of freedom): its low and high end per axis."""
    from scipy.stats import t as student_t

    logs = np.log(peaks)  # (seeds, 3)
    n = len(logs)
    s = np.sqrt(logs.var(axis=0, ddof=1).mean())
    half = student_t.ppf(0.975, 3 * (n - 1)) * s * np.sqrt(1.0 + 1.0 / n)
    centre = logs.mean(axis=0)
    return np.exp(centre - half), np.exp(centre + half)


def test_tight_l_to_o_errors_are_the_reports_magnitude(runs):
    peaks = np.array([_l_to_o_peaks(z) for z in runs["tight"]])
    want = np.array(REPORT["tight"]["enu_m"])
    lo, hi = _one_run_interval(peaks)
    print(f"\ntight L-O peaks per seed (E, N, U m) {np.round(peaks, 1).tolist()}; one run's 95 % interval "
          f"{np.round(lo, 1)}..{np.round(hi, 1)}; the report {want}")
    # Measured (seeds 0-4): E 7.7-29.2, N 21.4-62.3, U 3.0-11.0 m; interval E 4.5-58, N 11.5-148, U 1.8-23 m:
    # that wide because a single run's peak is that uncertain, the report's as much as ours.
    assert np.all(want >= lo) and np.all(want <= hi), (lo, hi)


@pytest.mark.xfail(strict=True, reason="seeds 0-4: loose L-O north error peaks at 42-172 m (median 69 m) where "
                                       "the simulated receiver's fixes are 100 m off and the report's tuning has "
                                       "no gate; the report's about 10 m is below one run's 95 % interval, 20-347 m")
def test_loose_l_to_o_errors_are_the_reports_magnitude(runs):
    peaks = np.array([_l_to_o_peaks(z) for z in runs["loose"]])
    want = np.array(REPORT["loose"]["enu_m"])
    lo, hi = _one_run_interval(peaks)
    print(f"\nloose L-O peaks per seed (E, N, U m) {np.round(peaks, 1).tolist()}; one run's 95 % interval "
          f"{np.round(lo, 1)}..{np.round(hi, 1)}; the report {want}")
    assert np.all(want >= lo) and np.all(want <= hi), (lo, hi)


@pytest.mark.xfail(strict=True, reason="median over seeds 0-4 of the yaw error at the stop: 12.9 deg (loose) and "
                                       "11.6 deg (tight) against the report's 5 and 7 deg")
@pytest.mark.parametrize("mode", ["loose", "tight"])
def test_yaw_at_the_stop_is_the_reports(runs, mode):
    yaw, _ = _median(_end_errors, runs[mode])
    assert yaw <= 1.5 * REPORT[mode]["yaw_deg"]

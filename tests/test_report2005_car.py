"""The report's car run reproduced where it has numbers: the ``report2005_car`` scenario (Table 6.1's
satellite geometry, a unit whose gyros hold their calibrated bias as the report's filter assumes) replayed with
the ``report2005`` preset (the report's hand tuning), against the FOI report's figures (docs/report2005.md):

- Table 6.1: satellites used per segment (the range, its dips included) and HDOP and VDOP per segment within a
  factor of 2 (the segment's lowest and highest value each against the table's), from the receiver's 3-D fixes
  as the replay reads them from the session;
- 7.1.2.1 / 7.2.2.1: the filters' largest east, north and up errors over L-O, about 20 / 10 / 22 m loose and
  18 / 22 / 15 m tight, within a factor of 1.5 per axis;
- 7.1.2.2 / 7.2.2.2: pitch and yaw errors at the final stop, about 0.5 / 5 deg loose and 0.3 / 7 deg tight,
  within a factor of 2;
- Table 7.4 and 7.2.2.1: the segments where an innovation leaves its 3-sigma band, loose Start-A, O-P, P-Q and
  T-U, tight once, just before P (in O-P).

The report shows one run; the filter figures here are the median over seeds 0-4, so that a match or a miss is
not one noise draw's luck. The geometry is the same for every seed (the scenario's obstructions do not
flicker). Every comparison whose bar is not met is a strict xfail whose reason gives the measured figure;
docs/report2005.md explains why each is missed.
"""

import numpy as np
import pytest

from gpsins.replay import run
from gpsins.replay import inputs as replay_inputs
from gpsins.report import data as report_data
from gpsins import sim
from gpsins.sim import scenario
from gpsins.sim.session import write_session

SEEDS = range(5)
SCENARIO = "report2005_car"

# Table 6.1: segment -> (satellites used, VDOP, HDOP), each as (low, high).
TABLE_6_1 = {
    "Start-A": ((8, 8), (1.2, 1.2), (1, 1)), "A-B": ((4, 4), (12.2, 12.2), (20, 20)),
    "B-C": ((4, 6), (2, 4), (1.5, 4)), "C-D": ((4, 6), (2, 4), (1.5, 2)), "D-E": ((5, 5), (2, 2), (2, 2)),
    "E-F": ((2, 5), (2, 4.2), (2, 4)), "F-G": ((4, 6), (2, 4.2), (1.5, 4)), "G-H": ((5, 6), (2, 2.7), (1.5, 2)),
    "H-I": ((5, 6), (2, 2), (1.5, 1.5)), "I-J": ((2, 5), (2, 9.5), (2, 14)), "J-K": ((4, 7), (1.7, 4), (1.5, 4)),
    "K-L": ((5, 7), (1.7, 1.7), (1.5, 2)), "L-M": ((3, 5), (2, 5), (2.5, 5)), "M-N": ((5, 5), (2, 2), (2.5, 2.5)),
    "N-O": ((4, 5), (2, 2), (2.5, 2.5)), "O-P": ((5, 7), (2, 2), (1.5, 2.5)), "P-Q": ((3, 7), (2, 5), (2, 17)),
    "Q-R": ((4, 5), (2, 9), (2, 5)), "R-S": ((4, 7), (2, 5), (2, 5)), "S-T": ((5, 7), (2, 4.5), (2, 9)),
    "T-U": ((2, 6), (2, 9), (2, 6)), "U-V": ((4, 7), (2, 7), (2, 21)), "V-W": ((4, 6), (2.5, 7), (2, 21)),
    "W-X": ((5, 7), (1.5, 2), (1.5, 1.5)), "X-Stop": ((6, 9), (1.5, 1.5), (1, 1)),
}
DOP_FACTOR = 2.0  # the issue's bar for Table 6.1's DOPs and the final-stop angles
L_O_FACTOR = 1.5  # the bar for the L-O errors
REPORT = {"loose": {"enu_m": (20.0, 10.0, 22.0), "pitch_deg": 0.5, "yaw_deg": 5.0,
                    "intervals": {"Start-A", "O-P", "P-Q", "T-U"}},
          "tight": {"enu_m": (18.0, 22.0, 15.0), "pitch_deg": 0.3, "yaw_deg": 7.0, "intervals": {"O-P"}}}
L_TO_O = ("L-M", "M-N", "N-O")
AXES = ("east", "north", "up")


@pytest.fixture(scope="module")
def runs(tmp_path_factory):
    """Per mode, one report.Result per seed."""
    out = {"loose": [], "tight": []}
    for seed in SEEDS:
        root = tmp_path_factory.mktemp(f"{SCENARIO}_{seed}")
        write_session(sim.simulate(scenario.load(SCENARIO), seed=seed), root / "session")
        inp = replay_inputs.load_inputs(root / "session", modes=("loose", "tight"), config="report2005")
        for mode in out:
            run.run_mode(inp, root / mode, mode=mode)
            out[mode].append(report_data.load(root / mode))
    return out


def _segments(r):
    return [(str(label), float(a), float(b)) for label, (a, b) in zip(r.a["seg_labels"], r.a["seg_t"])]


def _fix_table(r) -> dict:
    """Per segment: (sats low, high) from the report's segment table, and the (low, high) VDOP and HDOP of
    the segment's 3-D fixes as the replay read them (each fix in the segment it was measured in, as the table
    counts it)."""
    f, f_t = r.a["fixes"], report_data.fix_true_times(r)
    sats = {row["segment"]: (row["sats_min"], row["sats_max"]) for row in report_data.segment_table(r)}
    out = {}
    for label, a, b in _segments(r):
        m = (f_t >= a) & (f_t < b) & (f[:, 9] == 2)
        out[label] = (sats[label], (f[m, 8].min(), f[m, 8].max()), (f[m, 7].min(), f[m, 7].max()))
    return out


def test_the_geometry_is_the_same_for_every_seed(runs):
    first = _fix_table(runs["loose"][0])
    for r in runs["loose"][1:]:
        assert _fix_table(r) == first


def test_table_6_1_satellite_counts(runs):
    """Each segment's count stays within the table's range and reaches its low end where the table has a dip
    (2 or 3 satellites: E-F, I-J, T-U, L-M, P-Q), as the report's segment table (``gpsins report``) shows it."""
    table = _fix_table(runs["loose"][0])
    assert list(table) == list(TABLE_6_1)
    for label, ((lo, hi), _, _) in TABLE_6_1.items():
        n_lo, n_hi = table[label][0]
        assert lo <= n_lo and n_hi <= hi, (label, n_lo, n_hi, lo, hi)
        if lo <= 3:
            assert n_lo == lo, (label, n_lo, lo)


def test_the_segment_table_counts_each_fix_where_it_was_measured(tmp_path):
    """The default drive: a fix tagged on a segment's first second was measured the receiver clock's bias
    (tens of ns) before it, with the satellites of the segment before. The table counted it in the segment that
    starts there (A-B "4-8" where the fixes measured in A-B have 4); each segment's range must be that of the
    simulator's own fixes whose true time falls in it."""
    s = sim.simulate(scenario.load("default"), seed=0)
    write_session(s, tmp_path / "session")
    inp = replay_inputs.load_inputs(tmp_path / "session", modes=("loose",))
    run.run_mode(inp, tmp_path / "loose", mode="loose")
    rows = {row["segment"]: (row["sats_min"], row["sats_max"]) for row in report_data.segment_table(
        report_data.load(tmp_path / "loose"))}
    t = np.array([f.t for f in s.gnss.fixes])
    n = np.array([f.sats for f in s.gnss.fixes])
    for label, a, b in s.scenario.segment_times():
        m = (t >= a) & (t < b)
        assert rows[label] == (n[m].min(), n[m].max()), (label, rows[label])
    assert rows["A-B"] == (4, 4)


@pytest.mark.parametrize("which", ["VDOP", "HDOP"])
def test_table_6_1_dops_within_a_factor_of_2(runs, which):
    """The lowest and the highest DOP of each segment's 3-D fixes each within a factor of 2 of the table's."""
    table = _fix_table(runs["loose"][0])
    k = 1 if which == "VDOP" else 2
    misses = []
    for label, row in TABLE_6_1.items():
        for got, want in zip(table[label][k], row[k]):
            if not want / DOP_FACTOR <= got <= want * DOP_FACTOR:
                misses.append((label, round(float(got), 1), want))
    assert not misses, misses


def _l_to_o_peaks(r) -> np.ndarray:
    """Largest |east|, |north|, |up| error over segments L-M to N-O."""
    z = r.a
    m = np.zeros(len(z["t"]), bool)
    for label, a, b in _segments(r):
        if label in L_TO_O:
            m |= (z["t"] >= a) & (z["t"] < b)
    e = z["err_ned_m"][m]
    return np.nanmax(np.abs(np.column_stack([e[:, 1], e[:, 0], e[:, 2]])), axis=0)


def _end_errors(r) -> np.ndarray:
    """Mean |yaw| and |pitch| error over the last 10 s (the car stands still at the end)."""
    z = r.a
    end = z["t"] > z["t"][-1] - 10.0
    return np.nanmean(np.abs(z["err_ypr_deg"][end, :2]), axis=0)


# Medians over seeds 0-4 as measured; each miss is explained in docs/report2005.md.
L_O_MISSES = {
    ("loose", "east"): "median loose L-O east peak 6.9 m (seeds 6.1-15.0 m) against the report's 20 m",
    ("loose", "north"): "median loose L-O north peak 17.6 m (seeds 11.6-27.7 m) against the report's 10 m",
    ("loose", "up"): "median loose L-O up peak 9.3 m (seeds 6.7-13.9 m) against the report's 22 m",
    ("tight", "east"): "median tight L-O east peak 2.5 m (seeds 2.0-2.7 m) against the report's 18 m",
    ("tight", "north"): "median tight L-O north peak 4.7 m (seeds 2.7-6.3 m) against the report's 22 m",
    ("tight", "up"): "median tight L-O up peak 2.7 m (seeds 1.1-6.0 m) against the report's 15 m",
}


def _cases(misses: dict, modes=("loose", "tight"), names=AXES):
    return [pytest.param(mode, name, marks=pytest.mark.xfail(strict=True, reason=misses[(mode, name)]))
            if (mode, name) in misses else (mode, name) for mode in modes for name in names]


@pytest.mark.parametrize("mode,axis", _cases(L_O_MISSES))
def test_l_to_o_errors_within_a_factor_of_1_5(runs, mode, axis):
    i = AXES.index(axis)
    peaks = np.array([_l_to_o_peaks(r) for r in runs[mode]])
    got, want = float(np.median(peaks[:, i])), REPORT[mode]["enu_m"][i]
    print(f"\n{mode} L-O {axis} peaks per seed {np.round(peaks[:, i], 1).tolist()} m, median {got:.1f}, "
          f"report {want}")
    assert want / L_O_FACTOR <= got <= want * L_O_FACTOR


END_MISSES = {
    ("loose", "pitch"): "median loose pitch error at the stop 0.21 deg (seeds 0.14-0.58 deg) against the report's "
                        "0.5 deg",
    ("tight", "yaw"): "median tight yaw error at the stop 1.1 deg (seeds 0.3-1.8 deg) against the report's 7 deg",
}


@pytest.mark.parametrize("mode,angle", _cases(END_MISSES, names=("yaw", "pitch")))
def test_final_stop_attitude_within_a_factor_of_2(runs, mode, angle):
    i = ("yaw", "pitch").index(angle)
    errs = np.array([_end_errors(r) for r in runs[mode]])
    got, want = float(np.median(errs[:, i])), REPORT[mode][f"{angle}_deg"]
    print(f"\n{mode} {angle} at the stop per seed {np.round(errs[:, i], 2).tolist()} deg, median {got:.2f}, "
          f"report {want}")
    assert want / DOP_FACTOR <= got <= want * DOP_FACTOR


def _interval_segments(r) -> set:
    segs = _segments(r)
    out = set()
    for row in report_data.innovation_intervals(r):
        out |= {label for label, a, b in segs if a <= row["t_start"] < b}
    return out


@pytest.mark.xfail(strict=True, reason="loose: 21-29 intervals per seed in 11-18 segments (B-C in every seed, P-Q "
                                       "in four, T-U and O-P in two), never Start-A; the report's are Start-A, O-P, "
                                       "P-Q, T-U")
def test_loose_innovation_intervals_are_table_7_4s(runs):
    got = [_interval_segments(r) for r in runs["loose"]]
    print(f"\nloose interval segments per seed {[sorted(s) for s in got]}")
    assert all(s == REPORT["loose"]["intervals"] for s in got)


@pytest.mark.xfail(strict=True, reason="tight: no interval in seeds 0, 1, 3 and one in A-B (the start of the drive) "
                                       "in seeds 2 and 4; the report's one is just before P")
def test_tight_innovation_intervals_are_the_reports(runs):
    got = [_interval_segments(r) for r in runs["tight"]]
    print(f"\ntight interval segments per seed {[sorted(s) for s in got]}")
    assert all(s == REPORT["tight"]["intervals"] for s in got)

"""A replay's solution scored against a reference (an RTKLIB .pos, a data set's reference, a simulated
truth) with the drift through each outage, and against a session's own reference system (``reference.csv``),
whose dual-antenna heading can also aid the filter.
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

import numpy as np

from .. import evaluate
from ..formats import gpstime
from ..evaluate import outages as outages_mod
from ..formats import reference as reference_mod
from ..dataset import load as dataset_load
from ..session import layouts


TRUTH_SCORING_HZ = 10.0  # a simulated truth scored as the reference is taken at about this rate
POS_TIME_RESOLUTION_S = 0.001  # an RTKLIB .pos reference's epochs are printed to the millisecond


def score_reference_system(ref, week: int, rows: dict) -> dict:
    """Errors against the session's own reference system (RTK position and dual-antenna heading
    and pitch, ``reference.csv`` beside the session), as a real campaign scores without truth;
    ``rows``: the solution rows that bracket its epochs (``solution.Brackets``)."""
    if ref is None or len(rows.get("t", ())) < 2:
        return {}
    summary = reference_mod.compare_summary(ref, week * gpstime.SECONDS_PER_WEEK + rows["t"], rows["r_imu"],
                                            rows["yaw"], rows["pitch"])
    return {"file": reference_mod.FILE_NAME, "damaged_lines": len(ref.damaged_lines), **summary}


HEADING_AIDING_INTERVAL_S = 1.0  # the reference's heading errors are partly slow (multipath): not at its full rate


def heading_aiding(ref, week: int, interval_s: float = HEADING_AIDING_INTERVAL_S) -> np.ndarray:
    """A reference system's dual-antenna heading and pitch as the filter's attitude input
    [t, yaw, pitch, sigma yaw, sigma pitch], at most one epoch per ``interval_s``."""
    ok = np.isfinite(ref.heading_rad) & np.isfinite(ref.sigma_heading_rad)
    t = ref.gps_seconds()[ok] - week * gpstime.SECONDS_PER_WEEK
    keep = np.ones(len(t), bool)
    last = -np.inf
    for i, x in enumerate(t):  # thin to the interval without drifting off it
        keep[i] = x - last >= interval_s - 1e-6
        last = x if keep[i] else last
    pitch_ok = np.isfinite(ref.pitch_rad[ok]) & np.isfinite(ref.sigma_pitch_rad[ok])
    return np.column_stack([t, ref.heading_rad[ok], np.where(pitch_ok, ref.pitch_rad[ok], np.nan),
                            ref.sigma_heading_rad[ok], np.where(pitch_ok, ref.sigma_pitch_rad[ok], np.nan)])[keep]


def _truth_reference(truth: evaluate.Truth, system_epochs: np.ndarray) -> tuple:
    """The simulated truth as the reference (t, r_ecef, name): at the reference system's epochs when the
    session has one (so both are scored from one set of bracketing rows: a day's brackets then take
    150 MB less), else every sample at about TRUTH_SCORING_HZ; either is enough for drift and outage
    maxima. Read block by block from a memory-mapped truth, whose pages are given back."""
    tt = truth.t
    if len(system_epochs):
        te = system_epochs[(system_epochs >= tt[0]) & (system_epochs <= tt[-1])]
        r, block = np.empty((len(te), 3)), outages_mod.ERRORS_BLOCK
        for a in range(0, len(te), block):
            r[a:a + block] = truth.at(te[a:a + block]).r_ecef
            truth.release()
        return te, r, "truth.npz"
    step = max(1, int(round(1.0 / (TRUTH_SCORING_HZ * float(np.median(np.diff(tt))))))) if len(tt) > 1 else 1
    out = (tt[::step], np.array(truth.r_ecef[::step]), "truth.npz")
    truth.release()
    return out


_REFERENCE_SYSTEM: dict = {}  # the last reference system read, under its file's (path, mtime, size)


def reference_system(source: Path):
    """A session's reference system (``reference.csv``), if it has one; read once for the modes of one
    replay (--mode both read and parsed it twice: 0.03-0.06 s each for the default drive's)."""
    path = source / reference_mod.FILE_NAME
    if not (source.is_dir() and path.exists()):
        return None
    st = path.stat()
    key = (str(path.resolve()), st.st_mtime_ns, st.st_size)
    if _REFERENCE_SYSTEM.get("key") != key:
        _REFERENCE_SYSTEM.clear()
        _REFERENCE_SYSTEM.update(key=key, reference=reference_mod.load(source))
    return _REFERENCE_SYSTEM["reference"]


def reference_scores(t: np.ndarray, r_score: np.ndarray, ref: tuple, schedule: np.ndarray,
                     v: np.ndarray | None = None, update_t: np.ndarray | None = None, same_instant_s: float = 0.0
                     ) -> tuple[dict, dict, np.ndarray]:
    """Errors against a reference (t, r_ecef, name) and the per-outage drift: arrays, the scoring
    summary, and which reference epochs were used. With the solution's velocities and update times the
    solution is never interpolated across an update (``outages.solution_at``)."""
    use, e = outages_mod.errors_ned(t, r_score, ref[0], ref[1], v, update_t, same_instant_s)
    sc = outages_mod.score_errors(np.asarray(ref[0], float)[use], e, schedule)
    h = np.hypot(e[:, 0], e[:, 1])
    scoring = {"all": {"rms_h_m": float(np.sqrt(np.mean(h ** 2))) if len(h) else float("nan"),
                       "rms_v_m": float(np.sqrt(np.mean(e[:, 2] ** 2))) if len(h) else float("nan"),
                       "max_h_m": float(h.max()) if len(h) else float("nan")},
               **sc.summary()}
    arrays = dict(ref_err_ned_m=e, drift_t_s=sc.drift_t_s, drift_h_m=sc.drift_h_m, drift_v_m=sc.drift_v_m,
                  drift_outage=sc.drift_outage)
    return arrays, scoring, use


@dataclass
class Scored:
    """What a solution stream's brackets give against a reference."""

    arrays: dict
    summary: dict


def score_stream(stream, ref, schedule, prefix: str = "") -> Scored:
    rows = stream.brackets.rows()
    if ref is None or not len(ref[0]) or len(rows.get("t", ())) < 1:
        return Scored({}, {})
    same_instant = 0.0 if stream.truth is not None and ref[2] == "truth.npz" else POS_TIME_RESOLUTION_S
    arrays, scoring, use = reference_scores(rows["t"], rows["r_score"], ref, schedule, rows.get("v"),
                                            stream.update_times(), same_instant)
    arrays.update(ref_t=ref[0][use], ref_r_ecef=ref[1][use], ref_outage=outages_mod.outage_index(ref[0][use], schedule))
    return Scored({prefix + k: v for k, v in arrays.items()}, scoring)


@dataclass
class Target:
    """What a run is scored against: a reference (t, r_ecef, name) and the point it is at, a session's
    simulated truth, and the epochs whose bracketing solution rows are kept for the scoring."""

    truth: tuple | None  # (evaluate.Truth, extra arrays) of a simulated session
    ref: tuple | None
    point: str  # the point the reference is at: antenna, or imu for a simulated truth
    system_epochs: np.ndarray  # the reference system's epochs (reference.csv), if any
    bracket_epochs: np.ndarray

    @property
    def has_ref(self) -> bool:
        return self.ref is not None and len(self.ref[0]) > 0


def scoring_target(inp, ref_system, reference: str | Path | None, reference_q) -> Target:
    """Scoring against a reference: a .pos at the antenna point (``reference``, its ``reference_q`` epochs,
    or the data set's), else a session's truth at the IMU."""
    found = inp.truth
    ref = inp.reference
    if reference is not None:
        f = dataset_load.load_reference(reference, reference_q)
        ref = (f.t_abs - inp.week * gpstime.SECONDS_PER_WEEK, f.r_ecef, f.source)
        t_imu = (float(inp.imu[0, 0]), float(inp.imu[len(inp.imu) - 1, 0]))
        if not np.any((ref[0] >= t_imu[0]) & (ref[0] <= t_imu[1])):
            raise layouts.LogError(f"{reference}: none of its {len(ref[0])} epochs (Q {list(reference_q)}) falls "
                                   f"inside the IMU's span (GPS week {inp.week}, {t_imu[0]:.1f} to {t_imu[1]:.1f} s "
                                   "of week)")
    scored_point = "antenna"
    sys_epochs = (ref_system.gps_seconds() - inp.week * gpstime.SECONDS_PER_WEEK) if ref_system else np.zeros(0)
    if ref is None and found:
        ref, scored_point = _truth_reference(found[0], sys_epochs), "imu"
    has_ref = ref is not None and len(ref[0]) > 0
    bracket_epochs = np.concatenate([ref[0] if has_ref else np.zeros(0), sys_epochs])
    return Target(found, ref, scored_point, sys_epochs, bracket_epochs)

"""Simulated GNSS outages and their scoring against a reference trajectory (pure functions).

Schedule (``--outages FIRST:LENGTH:PERIOD[:END]``, seconds): outage k covers
[t0 + FIRST + k PERIOD, t0 + FIRST + k PERIOD + LENGTH), t0 being the first GNSS
epoch's time, for every k whose start is earlier than END seconds before the last
GNSS epoch (END defaults to 0).

Scoring, the field's way (KF-GINS paper): at every reference epoch the solution is
taken at the reference time (interpolated, but never across a measurement update's step:
``solution_at``) and the error is taken in the local north-east-down
frame of the reference point; per outage the maximum horizontal and vertical error
("drift"), then the mean, the worst and the RMS of those per-outage maxima; outside
the outages the RMS of the horizontal and vertical errors.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from .. import _core
from . import c_en


class OutageError(ValueError):
    pass


@dataclass(frozen=True)
class OutageSpec:
    first_s: float
    length_s: float
    period_s: float
    end_s: float = 0.0

    def text(self) -> str:
        return ":".join(f"{x:g}" for x in (self.first_s, self.length_s, self.period_s, self.end_s))


NONE = "none"  # --outages none: no outage, also where a data set's [scoring] schedules some


def is_none(text) -> bool:
    return isinstance(text, str) and text.strip().lower() == NONE


def parse(text: str) -> OutageSpec:
    """``FIRST:LENGTH:PERIOD[:END]`` in seconds."""
    parts = str(text).split(":")
    if len(parts) not in (3, 4):
        raise OutageError(f"--outages {text!r}: expected FIRST:LENGTH:PERIOD[:END] (seconds)")
    try:
        values = [float(x) for x in parts]
    except ValueError:
        raise OutageError(f"--outages {text!r}: not numbers") from None
    spec = OutageSpec(*values)
    if not all(np.isfinite(values)):
        raise OutageError(f"--outages {text!r}: not finite")
    if spec.length_s <= 0:
        raise OutageError(f"--outages {text!r}: LENGTH must be positive")
    if spec.period_s < spec.length_s:
        raise OutageError(f"--outages {text!r}: PERIOD must be at least LENGTH (outages would overlap)")
    return spec


def schedule(spec: OutageSpec | str, t_first: float, t_last: float) -> np.ndarray:
    """(k, 2) [start, end) of every outage, for GNSS epochs from t_first to t_last."""
    if not isinstance(spec, OutageSpec):
        spec = parse(spec)
    limit = t_last - spec.end_s
    starts = []
    k = 0
    while True:
        s = t_first + spec.first_s + k * spec.period_s
        if not s < limit:
            break
        starts.append(s)
        k += 1
    starts = np.array(starts, float)
    return np.column_stack([starts, starts + spec.length_s]).reshape(-1, 2)


def inside(t: np.ndarray, outages: np.ndarray) -> np.ndarray:
    """Which times fall in an outage (start included, end excluded)."""
    t = np.asarray(t, float)
    if not len(outages):
        return np.zeros(t.shape, bool)
    k = np.searchsorted(outages[:, 0], t, side="right") - 1
    ok = k >= 0
    out = np.zeros(t.shape, bool)
    out[ok] = t[ok] < outages[k[ok], 1]
    return out


def outage_index(t: np.ndarray, outages: np.ndarray) -> np.ndarray:
    """Index of the outage each time falls in, -1 outside."""
    t = np.asarray(t, float)
    if not len(outages):
        return np.full(t.shape, -1)
    k = np.searchsorted(outages[:, 0], t, side="right") - 1
    k = np.where(k >= 0, k, -1)
    hit = (k >= 0) & (t < outages[np.maximum(k, 0), 1])
    return np.where(hit, k, -1)


ERRORS_BLOCK = 1 << 16  # reference epochs per block


def solution_at(t_sol: np.ndarray, r_sol: np.ndarray, te: np.ndarray, v_sol: np.ndarray | None = None,
                update_t: np.ndarray | None = None, same_instant_s: float = 0.0) -> np.ndarray:
    """The solution's positions at epochs ``te`` inside its span: linear interpolation between the rows
    around each epoch, unless a measurement update falls between them (``update_t``, with the rows'
    velocities ``v_sol``). A row holds the state after every update up to its time, so the output at
    ``te`` is then the row on ``te``'s side of the update, carried to ``te`` with its velocity:
    interpolating across the update's step would blend the prior and the posterior (at the first fix
    after an outage, about half the outage's drift: 0.55 and 0.47 m on the walk). An update less than
    ``same_instant_s`` after ``te`` counts as at ``te``: a reference whose time tags are printed to the
    millisecond (RTKLIB's .pos) cannot be ordered against an update closer than that (the walk's
    .pos tags are the receiver's epochs truncated to the millisecond, 0.54 ms early)."""
    t_sol, te = np.asarray(t_sol, float), np.asarray(te, float)
    est = np.column_stack([np.interp(te, t_sol, r_sol[:, j]) for j in range(3)]) if len(te) else np.zeros((0, 3))
    if v_sol is None or update_t is None or len(t_sol) < 2 or not len(te):
        return est
    u = np.asarray(update_t, float)
    if len(u) > 1 and np.any(u[1:] < u[:-1]):
        u = np.sort(u)
    k = np.clip(np.searchsorted(t_sol, te, side="right") - 1, 0, len(t_sol) - 2)
    between = t_sol[k] < te
    n_after_row = np.searchsorted(u, t_sol[k], side="right")
    upto = np.minimum(te + same_instant_s, t_sol[k + 1])
    post = between & (np.searchsorted(u, upto, side="right") > n_after_row)  # an update in (t_k, te + tol]
    pre = between & ~post & (np.searchsorted(u, t_sol[k + 1], side="right") > n_after_row)  # in (te, t_k+1]
    j = np.where(post, k + 1, k)
    carried = r_sol[j] + v_sol[j] * (te - t_sol[j])[:, None]
    return np.where((post | pre)[:, None], carried, est)


def errors_ned(t_sol: np.ndarray, r_sol: np.ndarray, t_ref: np.ndarray, r_ref: np.ndarray,
               v_sol: np.ndarray | None = None, update_t: np.ndarray | None = None, same_instant_s: float = 0.0):
    """Solution minus reference in NED at the reference epochs inside the solution's span (the solution
    there as ``solution_at`` gives it).

    Returns (mask of the reference epochs used, (m, 3) errors)."""
    t_sol = np.asarray(t_sol, float)
    use = (t_ref >= t_sol[0]) & (t_ref <= t_sol[-1]) if len(t_sol) else np.zeros(len(t_ref), bool)
    idx = np.flatnonzero(use)
    out = np.empty((len(idx), 3))
    for a in range(0, len(idx), ERRORS_BLOCK):  # a day's epochs would need 3x3 matrices of 140 MB at once
        k = idx[a:a + ERRORS_BLOCK]
        est = solution_at(t_sol, r_sol, t_ref[k], v_sol, update_t, same_instant_s)
        llh = _core.ecef_to_geodetic(r_ref[k])
        out[a:a + len(k)] = np.einsum("nji,nj->ni", c_en(llh[:, 0], llh[:, 1]), est - r_ref[k])
    return use, out


@dataclass
class Score:
    outages: np.ndarray  # (k, 2) the schedule
    max_h_m: np.ndarray  # (k,) per-outage maximum horizontal error (NaN: no reference epoch inside)
    max_v_m: np.ndarray  # (k,) per-outage maximum vertical error
    n_ref: np.ndarray  # (k,) reference epochs inside each outage
    outside_rms_h_m: float
    outside_rms_v_m: float
    n_outside: int
    # Drift vs time in outage (for the report's figure): one row per reference epoch inside an outage.
    drift_t_s: np.ndarray  # time since the outage began
    drift_h_m: np.ndarray
    drift_v_m: np.ndarray
    drift_outage: np.ndarray  # outage index

    def _stat(self, x: np.ndarray) -> dict:
        x = x[np.isfinite(x)]
        if not len(x):
            return {"mean": float("nan"), "worst": float("nan"), "rms": float("nan")}
        return {"mean": float(np.mean(x)), "worst": float(np.max(x)), "rms": float(np.sqrt(np.mean(x ** 2)))}

    def summary(self) -> dict:
        """Plain numbers for run.json."""
        return {"n_outages": int(len(self.outages)), "n_scored": int(np.isfinite(self.max_h_m).sum()),
                "horizontal_m": self._stat(self.max_h_m), "vertical_m": self._stat(self.max_v_m),
                "per_outage": [{"start": float(a), "end": float(b), "max_h_m": float(h), "max_v_m": float(v),
                                "n_ref": int(n)}
                               for (a, b), h, v, n in zip(self.outages, self.max_h_m, self.max_v_m, self.n_ref)],
                "outside": {"rms_h_m": self.outside_rms_h_m, "rms_v_m": self.outside_rms_v_m,
                            "n": self.n_outside}}


def score(t_sol: np.ndarray, r_sol: np.ndarray, t_ref: np.ndarray, r_ref: np.ndarray, outages: np.ndarray,
          v_sol: np.ndarray | None = None, update_t: np.ndarray | None = None, same_instant_s: float = 0.0) -> Score:
    """Score a solution (times, ECEF positions of the point the reference measures; with its velocities
    and update times, ``solution_at``'s steps) against a reference."""
    use, e = errors_ned(t_sol, r_sol, np.asarray(t_ref, float), np.asarray(r_ref, float), v_sol, update_t,
                        same_instant_s)
    return score_errors(np.asarray(t_ref, float)[use], e, outages)


def score_errors(tr: np.ndarray, e: np.ndarray, outages: np.ndarray) -> Score:
    """``score`` from the NED errors ``e`` at the reference epochs ``tr`` (``errors_ned``'s)."""
    outages = np.asarray(outages, float).reshape(-1, 2)
    h = np.hypot(e[:, 0], e[:, 1])
    v = np.abs(e[:, 2])
    k = outage_index(tr, outages)
    n = len(outages)
    max_h, max_v, n_ref = np.full(n, np.nan), np.full(n, np.nan), np.zeros(n, int)
    for j in range(n):
        m = k == j
        n_ref[j] = int(m.sum())
        if n_ref[j]:
            max_h[j], max_v[j] = h[m].max(), v[m].max()
    out = k < 0
    rms = (lambda x: float(np.sqrt(np.mean(x ** 2))) if len(x) else float("nan"))
    ins = k >= 0
    return Score(outages, max_h, max_v, n_ref, rms(h[out]), rms(v[out]), int(out.sum()),
                 tr[ins] - outages[k[ins], 0] if ins.any() else np.zeros(0), h[ins], v[ins], k[ins])

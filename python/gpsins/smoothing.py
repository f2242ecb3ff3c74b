"""Replay's side of the fixed-interval smoother (the C++ core's rts.hpp).

``flt.run(..., smooth=True)`` gives the smoothed solution at the same epochs as the
forward one (``sol.extra["smoothed"]``). Here it is scored the way replay scores the
forward solution: errors against truth (with NEES and the share inside 3 sigma),
errors and per-outage drift against a reference; the arrays go to results.npz with
the prefix ``smooth_``.
"""
from __future__ import annotations

import numpy as np

from . import filter as flt

PREFIX = "smooth_"


def results(sol: flt.Solution, truth, ref, scored_point: str, lever: np.ndarray, score_sched: np.ndarray
            ) -> tuple[dict, dict, flt.Solution, np.ndarray, np.ndarray]:
    """(arrays without prefix, summary, smoothed solution, its antenna positions, its NED position sigmas)."""
    from .replay import antenna_positions, reference_scores, solution_arrays, truth_errors
    sm = sol.extra["smoothed"]
    r_ant = antenna_positions(sm, lever)
    a = solution_arrays(sm)
    summary: dict = {"info": dict(sol.extra.get("smooth_info", {}))}
    if truth:
        err_arrays, stats = truth_errors(sm, truth[0])
        a.update(err_arrays)
        if stats:
            summary["errors"] = stats
    if ref is not None and len(ref[0]):
        r_score = r_ant if scored_point == "antenna" else sm.r_ecef
        ref_arrays, summary["scoring"], _ = reference_scores(sm.t, r_score, ref, score_sched)
        a.update(ref_arrays, r_point_ecef=r_score)
    return a, summary, sm, r_ant, a["sigma_ned_m"]


def prefixed(arrays: dict) -> dict:
    return {PREFIX + k: v for k, v in arrays.items()}

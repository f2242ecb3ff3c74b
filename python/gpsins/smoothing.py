"""Replay's side of the fixed-interval smoother (the C++ core's rts.hpp).

``flt.run(..., smooth=True)`` gives the smoothed solution at the same epochs as the
forward one (``sol.extra["smoothed"]``). Here it is scored the way replay scores the
forward solution: errors against truth (with NEES and the share inside 3 sigma),
errors and per-outage drift against a reference; the arrays go to results.npz with
the prefix ``smooth_``.
"""
from __future__ import annotations

import numpy as np

from . import evaluate, filter as flt, outages as outages_mod

PREFIX = "smooth_"


def results(sol: flt.Solution, truth, ref, scored_point: str, lever: np.ndarray, score_sched: np.ndarray
            ) -> tuple[dict, dict, flt.Solution, np.ndarray, np.ndarray]:
    """(arrays without prefix, summary, smoothed solution, its antenna positions, its NED position sigmas)."""
    from .replay import _fill, _nav_sigmas, _subset, antenna_positions
    sm = sol.extra["smoothed"]
    sigma_ned, sigma_ypr = _nav_sigmas(sm)
    r_ant = antenna_positions(sm, lever)
    llh = sm.llh()
    c_en_sol = evaluate.c_en(llh[:, 0], llh[:, 1])
    p_v = np.swapaxes(c_en_sol, -1, -2) @ sm.covariance[:, 3:6, 3:6] @ c_en_sol
    a = dict(r_ecef=sm.r_ecef, v_ecef=sm.v_ecef, q_eb=sm.q_eb, llh=llh, ypr_deg=np.degrees(sm.ypr()),
             gyro_bias=sm.gyro_bias, accel_bias=sm.accel_bias, sigma=sm.sigma, sigma_ned_m=sigma_ned,
             sigma_ypr_deg=sigma_ypr, sigma_v_ned_mps=np.sqrt(np.diagonal(p_v, axis1=1, axis2=2)))
    if sm.clock is not None:
        a["clock"] = sm.clock
    summary: dict = {"info": dict(sol.extra.get("smooth_info", {}))}
    if truth:
        tr = truth[0]
        inside = (sm.t >= tr.t[0]) & (sm.t <= tr.t[-1])
        err = evaluate.nav_errors(_subset(sm, inside), tr)
        ref_tr = tr.at(sm.t[inside])
        llh_ref = flt._core.ecef_to_geodetic(ref_tr.r_ecef)
        c_en = evaluate.c_en(llh_ref[:, 0], llh_ref[:, 1])
        dv_ned = np.einsum("nji,nj->ni", c_en, sm.v_ecef[inside] - ref_tr.v_ecef)
        nees = evaluate.nees(err.e9, sm.covariance[inside][:, :9, :9])
        a.update(err_ned_m=_fill(inside, err.r_ned), err_ypr_deg=_fill(inside, err.ypr_deg),
                 err_v_ned_mps=_fill(inside, dv_ned), nees9=_fill(inside, nees))
        hk = sm.heading_known[inside]
        if hk.any():
            h = np.hypot(err.r_ned[hk, 0], err.r_ned[hk, 1])
            summary["errors"] = {
                "horizontal_rms_m": float(np.sqrt(np.mean(h ** 2))), "horizontal_max_m": float(h.max()),
                "vertical_rms_m": float(np.sqrt(np.mean(err.r_ned[hk, 2] ** 2))),
                "vertical_max_m": float(np.abs(err.r_ned[hk, 2]).max()), "nees9_mean": float(nees[hk].mean()),
                "inside_3_sigma": float(np.mean(np.abs(err.e9[hk]) <= 3 * sm.sigma[inside][hk, :9]))}
    if ref is not None and len(ref[0]):
        r_score = r_ant if scored_point == "antenna" else sm.r_ecef
        sc = outages_mod.score(sm.t, r_score, ref[0], ref[1], score_sched)
        use, e = outages_mod.errors_ned(sm.t, r_score, ref[0], ref[1])
        a.update(ref_err_ned_m=e, drift_t_s=sc.drift_t_s, drift_h_m=sc.drift_h_m, drift_v_m=sc.drift_v_m,
                 drift_outage=sc.drift_outage, r_point_ecef=r_score)
        h = np.hypot(e[:, 0], e[:, 1])
        summary["scoring"] = {"all": {"rms_h_m": float(np.sqrt(np.mean(h ** 2))) if len(h) else float("nan"),
                                      "rms_v_m": float(np.sqrt(np.mean(e[:, 2] ** 2))) if len(h) else float("nan"),
                                      "max_h_m": float(h.max()) if len(h) else float("nan")},
                              **sc.summary()}
    return a, summary, sm, r_ant, sigma_ned


def prefixed(arrays: dict) -> dict:
    return {PREFIX + k: v for k, v in arrays.items()}

"""Replay a logger session through the filter.

session directory -> decoded measurements -> time alignment -> filter -> results directory:

- ``results.npz``: the solution (see ``RESULT_ARRAYS``), the receiver's fixes,
  every update, and, when the session has a truth file, the errors;
- ``solution.pos``: RTKLIB-style positions (GPST, latitude, longitude, height,
  standard deviations), for RTKLIB's plot tools and comparisons;
- ``config.toml``: the exact filter configuration used;
- ``run.json``: counters, what was skipped and why, the alignment's summary,
  timings and summary statistics.
"""

from __future__ import annotations

import json
import time
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from . import evaluate, filter as flt, measurements, measurements_ubx, timing
from .readers import rinex

DEFAULT_GPS_LATENCY_S = 0.0205  # receiver's epoch-to-first-byte delay (assumed 20 ms) + the logger's
DEFAULT_IMU_LATENCY_S = 0.0005

RESULT_ARRAYS = {
    "t": "GPS time, s since the start of `week`", "week": "GPS week of t = 0",
    "r_ecef": "position, m", "v_ecef": "velocity, m/s", "q_eb": "attitude body->ECEF (w, x, y, z)",
    "llh": "latitude, longitude (rad), height (m)", "ypr_deg": "yaw, pitch, roll relative to NED, deg",
    "gyro_bias": "rad/s", "accel_bias": "m/s^2", "sigma": "error-state standard deviations",
    "sigma_ned_m": "position sigma north, east, down", "sigma_ypr_deg": "attitude sigma about N, E, D axes",
    "standstill": "standstill detected", "heading_known": "heading initialised",
    "fixes": "receiver fixes [t, r xyz, v xyz, hdop, vdop, mode]", "fix_sats": "satellites used per fix",
    "upd_*": "updates: t, kind, id, dof, nis, gate, accepted, innovation (3), innovation_sigma (3)",
    "err_ned_m": "position error (estimate - truth) NED", "err_ypr_deg": "attitude error",
    "err_v_ned_mps": "velocity error NED", "nees9": "NEES of the 9 navigation states",
    "seg_labels": "truth segment labels", "seg_t": "truth segments' start and end times",
    "sigma_v_ned_mps": "velocity sigma north, east, down",
    "clock": "tight mode: receiver clock bias (m) and drift (m/s); their sigmas are the last two of `sigma`",
}


@dataclass
class ReplayResult:
    out: Path
    mode: str
    summary: dict


def _nav_sigmas(sol: flt.Solution) -> tuple[np.ndarray, np.ndarray]:
    llh = sol.llh()
    c_en = evaluate.c_en(llh[:, 0], llh[:, 1])
    p = sol.covariance
    pos = np.swapaxes(c_en, -1, -2) @ p[:, 6:9, 6:9] @ c_en
    # Body-side attitude error dtheta -> NED axes: C_nb dtheta.
    c_eb = flt._core.dcm_from_quat(sol.q_eb)
    c_nb = np.swapaxes(c_en, -1, -2) @ c_eb
    att = c_nb @ p[:, 0:3, 0:3] @ np.swapaxes(c_nb, -1, -2)
    return (np.sqrt(np.diagonal(pos, axis1=1, axis2=2)), np.degrees(np.sqrt(np.diagonal(att, axis1=1, axis2=2))))


def write_pos(path: Path, week: int, sol: flt.Solution, sigma_ned: np.ndarray, sats: np.ndarray, every: int = 1,
              note: str = "") -> None:
    """RTKLIB-style .pos (lat/lon/height, GPST epochs); Q = 5 (single) for an INS solution."""
    llh = sol.llh()
    idx = np.arange(0, len(sol.t), every)
    lines = ["% program   : gpsins replay", f"% {note}" if note else "%",
             "% (lat/lon/height=WGS84/ellipsoidal,Q=1:fix,2:float,3:sbas,4:dgps,5:single,6:ppp,ns=# of satellites)",
             "%  GPST                   latitude(deg) longitude(deg)  height(m)   Q  ns   sdn(m)   sde(m)   sdu(m)"
             "  sdne(m)  sdeu(m)  sdun(m) age(s)  ratio"]
    times = rinex.gpst_text(week * measurements.SECONDS_PER_WEEK + sol.t[idx])
    for k, ts in zip(idx, times):
        lat, lon = np.degrees(llh[k, :2])
        sn, se, sd = sigma_ned[k]
        lines.append(f"{ts} {lat:14.9f} {lon:14.9f} {llh[k, 2]:10.4f} {5:3d} {int(sats[k]):3d} {sn:8.4f} {se:8.4f} "
                     f"{sd:8.4f} {0.0:8.4f} {0.0:8.4f} {0.0:8.4f} {0.0:6.2f} {0.0:6.1f}")
    path.write_text("\n".join(lines) + "\n", encoding="ascii")


def load_session_truth(directory: Path, t_offset: float) -> tuple[evaluate.Truth, dict] | None:
    """The simulated truth next to a session (session dir or its parent), on the replay's time base."""
    for p in (directory / "truth.npz", directory.parent / "truth.npz"):
        if p.exists():
            z = np.load(p)
            tow = z["tow_s"] + (int(z["gps_week"]) * 604800.0) - t_offset
            extra = {"seg_labels": z["segment_labels"], "seg_t": z["segment_t"] + float(z["t0_tow_s"]) +
                     int(z["gps_week"]) * 604800.0 - t_offset}
            return evaluate.Truth(tow, z["r_ecef"], z["v_ecef"], z["q_eb"]), extra
    return None


def replay(session: str | Path, out: str | Path, *, mode: str = "loose", config=None, overrides: dict | None = None,
           timing_method: str = "robust", gps_latency_s: float = DEFAULT_GPS_LATENCY_S,
           imu_latency_s: float = DEFAULT_IMU_LATENCY_S, truth: bool = True,
           nav: str | Path | None = None) -> ReplayResult:
    session, out = Path(session), Path(out)
    clock = {"start": time.perf_counter()}
    dec = measurements_ubx.decode_session(session, flt.load_config(config, overrides or {})["fix_uere_m"]) \
        if measurements_ubx.is_ublox(session) else measurements.decode_session(session)  # u-blox: issue 19
    clock["decode_s"] = time.perf_counter() - clock.pop("start")
    t1 = time.perf_counter()
    al = timing.align(dec.gps.tow, dec.gps.stamps, dec.gps.week, dec.imu.stamps, dec.imu.counter, dec.imu.rate_hz,
                      method=timing_method, gps_latency_s=gps_latency_s, imu_latency_s=imu_latency_s)
    clock["align_s"] = time.perf_counter() - t1
    imu = np.column_stack([al.imu_t, dec.imu.dtheta_rad, dec.imu.dv_mps])
    cfg = flt.load_config(config, {**(overrides or {}), "mode": mode})
    tight = {}
    if mode == "tight":
        klob = None
        if dec.gps.iono is not None:
            klob = (dec.gps.iono.alpha, dec.gps.iono.beta)
        elif nav is not None:
            n = rinex.read_nav(nav)
            klob = (n.alpha, n.beta) if n.alpha else None
        ephs = dec.gps.decoded_ephemerides(dec.skipped)
        if nav is not None:
            ephs += rinex.read_nav(nav).ephemerides
        tight = dict(pseudoranges=dec.gps.pseudorange_table(), ephemerides=ephs, klobuchar=klob,
                     gps_time_offset_s=dec.gps.week * measurements.SECONDS_PER_WEEK)
    t2 = time.perf_counter()
    max_gap = float(cfg.get("max_gap_s", 0.5))
    try:
        sol = flt.run(imu, dec.gps.fixes, cfg, mode=mode, covariance=True, **tight)
        split = []
    except ValueError as e:
        # Interim until the core re-initialises after long IMU gaps itself: run the filter
        # on each stretch between them, each starting afresh.
        if "gap longer than max_gap_s" not in str(e):
            raise
        sol, split = _run_stretches(imu, dec.gps.fixes, cfg, mode, tight, max_gap)
    clock["filter_s"] = time.perf_counter() - t2
    if len(sol.t) == 0:
        raise measurements.logs.LogError(f"{session}: the filter never initialised (no usable fix after levelling)")

    sigma_ned, sigma_ypr = _nav_sigmas(sol)
    fix_t = dec.gps.fixes[:, 0]
    k = np.clip(np.searchsorted(fix_t, sol.t, side="right") - 1, 0, max(len(fix_t) - 1, 0))
    sats = dec.gps.fix_sats[k] if len(fix_t) else np.zeros(len(sol.t), int)
    arrays = dict(t=sol.t, week=np.int64(dec.gps.week), r_ecef=sol.r_ecef, v_ecef=sol.v_ecef, q_eb=sol.q_eb,
                  llh=sol.llh(), ypr_deg=np.degrees(sol.ypr()), gyro_bias=sol.gyro_bias, accel_bias=sol.accel_bias,
                  sigma=sol.sigma, sigma_ned_m=sigma_ned, sigma_ypr_deg=sigma_ypr, standstill=sol.standstill,
                  heading_known=sol.heading_known, fixes=dec.gps.fixes, fix_sats=dec.gps.fix_sats)
    arrays.update({f"upd_{k}": v for k, v in sol.updates.items()})
    c_en_sol = evaluate.c_en(arrays["llh"][:, 0], arrays["llh"][:, 1])
    p_v_ned = np.swapaxes(c_en_sol, -1, -2) @ sol.covariance[:, 3:6, 3:6] @ c_en_sol
    arrays["sigma_v_ned_mps"] = np.sqrt(np.diagonal(p_v_ned, axis1=1, axis2=2))
    if sol.clock is not None:
        arrays["clock"] = sol.clock
    stats = {}
    found = load_session_truth(session, dec.gps.week * measurements.SECONDS_PER_WEEK) if truth else None
    if found:
        tr, extra = found
        inside = (sol.t >= tr.t[0]) & (sol.t <= tr.t[-1])
        err = evaluate.nav_errors(_subset(sol, inside), tr)
        ref = tr.at(sol.t[inside])
        llh_ref = flt._core.ecef_to_geodetic(ref.r_ecef)
        c_en = evaluate.c_en(llh_ref[:, 0], llh_ref[:, 1])
        dv_ned = np.einsum("nji,nj->ni", c_en, sol.v_ecef[inside] - ref.v_ecef)
        e9 = err.e9
        nees = evaluate.nees(e9, sol.covariance[inside][:, :9, :9])
        full = lambda a: _fill(inside, a)  # noqa: E731
        arrays.update(err_ned_m=full(err.r_ned), err_ypr_deg=full(err.ypr_deg), err_v_ned_mps=full(dv_ned),
                      nees9=full(nees), **extra)
        hk = sol.heading_known[inside]
        h = np.hypot(err.r_ned[hk, 0], err.r_ned[hk, 1])
        # Errors count from the first known heading; a short or standing run may never get there.
        stats = {} if not hk.any() else {"horizontal_rms_m": float(np.sqrt(np.mean(h ** 2))), "horizontal_max_m": float(h.max()),
                 "vertical_rms_m": float(np.sqrt(np.mean(err.r_ned[hk, 2] ** 2))),
                 "vertical_max_m": float(np.abs(err.r_ned[hk, 2]).max()),
                 "nees9_mean": float(nees[hk].mean()),
                 "inside_3_sigma": float(np.mean(np.abs(e9[hk]) <= 3 * sol.sigma[inside][hk, :9]))}
    out.mkdir(parents=True, exist_ok=True)
    np.savez_compressed(out / "results.npz", **arrays)
    write_pos(out / "solution.pos", dec.gps.week, sol, sigma_ned, sats, note=f"mode {mode}, session {session.name}")
    (out / "config.toml").write_text(flt.to_toml(cfg), encoding="utf-8")
    clock["total_s"] = sum(v for v in clock.values())
    gaps = al.gap_list(min_s=max_gap) if timing_method == "robust" else []
    summary = {"session": str(session), "mode": mode, "alignment": al.summary(), "counters": sol.counters,
               "imu_gaps_longer_than_max_gap": gaps,
               "reinitialisations": {"count": len(split), "at_t": split,
                                     "how": "interim: the filter restarted on each stretch between IMU gaps"
                                     if split else ""},
               "warnings": al.warnings if timing_method == "robust" else [],
               "skipped": dict(dec.skipped), "fixes_after_end": sol.extra["fixes_after_end"],
               "wall_time_s": clock, "imu_samples": int(len(imu)), "errors": stats,
               "update_kinds": {flt.UPDATE_KINDS[int(k)]: int(np.sum(sol.updates["kind"] == k))
                                for k in np.unique(sol.updates["kind"])}}
    (out / "run.json").write_text(json.dumps(summary, indent=2) + "\n", encoding="utf-8")
    return ReplayResult(out, mode, summary)


def _run_stretches(imu: np.ndarray, fixes: np.ndarray, cfg: dict, mode: str, tight: dict, max_gap: float
                   ) -> tuple[flt.Solution, list[float]]:
    """The filter run afresh on each stretch of IMU samples between gaps longer than max_gap;
    the solutions concatenated. Returns it and the times at which the filter restarted."""
    cut = np.flatnonzero(np.diff(imu[:, 0]) > max_gap) + 1
    bounds = list(zip(np.concatenate([[0], cut]), np.concatenate([cut, [len(imu)]])))
    parts = []
    for j, (a, b) in enumerate(bounds):
        t_lo = imu[a, 0] if j else -np.inf
        t_hi = imu[b, 0] if b < len(imu) else np.inf
        sel = (fixes[:, 0] > t_lo) & (fixes[:, 0] <= t_hi) if j else fixes[:, 0] <= t_hi
        kw = dict(tight)
        if "pseudoranges" in kw:
            pr = kw["pseudoranges"]
            kw["pseudoranges"] = pr[(pr[:, 0] > t_lo) & (pr[:, 0] <= t_hi)]
        parts.append(flt.run(imu[a:b], fixes[sel], cfg, mode=mode, covariance=True, **kw))
    first = parts[0]
    cat = lambda name: np.concatenate([getattr(p, name) for p in parts])  # noqa: E731
    updates = {k: np.concatenate([p.updates[k] for p in parts]) for k in first.updates}
    counters = {k: sum(p.counters.get(k, 0) for p in parts) for k in first.counters}
    sol = flt.Solution(first.mode, first.n_states, cat("t"), cat("r_ecef"), cat("v_ecef"), cat("q_eb"),
                       cat("gyro_bias"), cat("accel_bias"), cat("sigma"), cat("standstill"), cat("heading_known"),
                       updates, counters, None if first.scale_factors is None else cat("scale_factors"),
                       None if first.clock is None else cat("clock"),
                       None if first.covariance is None else cat("covariance"),
                       {"fixes_after_end": parts[-1].extra["fixes_after_end"]})
    return sol, [float(imu[a, 0]) for a, _ in bounds[1:]]


def _fill(mask: np.ndarray, a: np.ndarray) -> np.ndarray:
    full = np.full((len(mask),) + a.shape[1:], np.nan)
    full[mask] = a
    return full


def _subset(sol: flt.Solution, m: np.ndarray) -> flt.Solution:
    return flt.Solution(sol.mode, sol.n_states, sol.t[m], sol.r_ecef[m], sol.v_ecef[m], sol.q_eb[m], sol.gyro_bias[m],
                        sol.accel_bias[m], sol.sigma[m], sol.standstill[m], sol.heading_known[m], sol.updates,
                        sol.counters)

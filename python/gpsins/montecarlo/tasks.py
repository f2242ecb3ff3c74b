"""What a Dask worker runs: one simulation per seed, one replay per (seed, mode, swept value).

Both write their files under the Monte Carlo's output directory and return small
dicts (paths, figures, and a few arrays on the coarse common time grid), so
nothing large travels through the scheduler or the client. They import the
heavy modules themselves: a worker process pays that once, the client never.
"""

from __future__ import annotations

import os
import shutil
import socket
import time
import traceback
from pathlib import Path

import numpy as np


def simulate_session(scenario, seed: int, directory: Path) -> Path:
    """Write the simulated session (with its truth file) of one seed: the simulator's public API."""
    from .. import sim
    from ..sim.session import write_session

    return write_session(sim.simulate(scenario, seed), directory)


def _run_series(out_dir: Path) -> dict:
    """The per-epoch arrays of one replay that the Monte Carlo needs (the one place results are read).

    Keys: t, nees9, heading_known, err_ned_m, sigma_ned_m, seg_labels, seg_t,
    upd_t, upd_kind, upd_dof, upd_nis, upd_accepted.
    """
    from ..replay import results

    names = ("t", "nees9", "heading_known", "err_ned_m", "sigma_ned_m", "seg_labels", "seg_t",
             "upd_t", "upd_kind", "upd_dof", "upd_nis", "upd_accepted")
    z = results.load(out_dir)
    missing = [k for k in names if k not in z]
    if missing:
        raise ValueError(f"{out_dir}: no {', '.join(missing)} in its results (a session without its truth file?)")
    return {k: z[k] for k in names}


def worker_place() -> str:
    return f"{socket.gethostname()}:{os.getpid()}"


def _failure(e: BaseException) -> str:
    """One line for the table; the traceback's last frame says where."""
    tb = traceback.extract_tb(e.__traceback__)
    at = f" ({Path(tb[-1].filename).name}:{tb[-1].lineno})" if tb else ""
    return f"{type(e).__name__}: {e}".splitlines()[0][:200] + at


def simulate_task(scenario, seed: int, directory: str) -> dict:
    """Simulate one seed into ``directory``; a failure is returned, so the seed's replays report it."""
    t0, c0 = time.perf_counter(), time.process_time()
    try:
        session = simulate_session(scenario, seed, Path(directory))
    except Exception as e:  # a seed that does not simulate is a result of the Monte Carlo
        return {"seed": seed, "error": f"simulate: {_failure(e)}"}
    return {"seed": seed, "session": str(session), "simulate_s": time.perf_counter() - t0,
            "simulate_cpu_s": time.process_time() - c0, "sim_worker": worker_place()}


def replay_task(simulated: dict, run: dict, grid_s: float) -> dict:
    """Replay one simulated session once and summarise it.

    ``run``: mode, out (directory), config, overrides, outages, value (the swept value or None).
    Returns the summary of ``summarise`` plus the run's identity and wall times.
    """
    head = {"seed": simulated["seed"], "mode": run["mode"], "value": run.get("value"), "out": run["out"]}
    if "error" in simulated:
        return {**head, "error": simulated["error"]}
    from ..replay import run as replay

    t0, c0 = time.perf_counter(), time.process_time()
    try:
        res = replay.replay(simulated["session"], run["out"], mode=run["mode"], config=run.get("config"),
                            overrides=run.get("overrides") or {}, outages=run.get("outages"),
                            estimator=run.get("estimator"),
                            overlap=False)  # a worker is one core's: the cluster runs replays side by side
        out = summarise(Path(run["out"]), res.summary, grid_s)
    except Exception as e:
        return {**head, "error": f"replay: {_failure(e)}", "simulate_s": simulated["simulate_s"]}
    out.update(head)
    # Wall times, and the CPU time of the worker process (less than wall on a machine shared with other work).
    out["wall"] = {"simulate_s": simulated["simulate_s"], **res.summary["wall_time_s"],
                   "task_s": time.perf_counter() - t0, "simulate_cpu_s": simulated["simulate_cpu_s"],
                   "task_cpu_s": time.process_time() - c0}
    out["worker"] = worker_place()
    return out


def discard_task(path: str, *done) -> str:
    """Delete a seed's session (or its whole directory) once the replays in ``done`` have read it."""
    shutil.rmtree(path, ignore_errors=True)
    return path


def grid_index(tau: np.ndarray, grid_s: float, n: int) -> tuple[np.ndarray, np.ndarray]:
    """Grid cell of each time since the start (cells centred on k grid_s), and which fall inside."""
    k = np.floor(tau / grid_s + 0.5).astype(np.int64)
    ok = (k >= 0) & (k < n)
    return k, ok


def _on_grid(tau: np.ndarray, values: np.ndarray, grid: np.ndarray, max_dt: float) -> np.ndarray:
    """The epoch nearest each grid time (NaN where none is within max_dt): values stay
    what the filter had at an epoch (a NEES is not interpolated between epochs)."""
    out = np.full((len(grid),) + values.shape[1:], np.nan)
    if not len(tau):
        return out
    j = np.clip(np.searchsorted(tau, grid), 1, len(tau) - 1) if len(tau) > 1 else np.zeros(len(grid), int)
    if len(tau) > 1:
        j = np.where(np.abs(tau[j - 1] - grid) <= np.abs(tau[j] - grid), j - 1, j)
    near = np.abs(tau[j] - grid) <= max_dt
    out[near] = values[j[near]]
    return out


def summarise(out_dir: Path, run_json: dict, grid_s: float) -> dict:
    """A replay's compact summary: figures from run.json, per-segment and per-outage errors, NIS per
    update kind, and on the common grid (``grid_s`` from the scenario's start) the 9-state NEES, the
    horizontal and vertical errors and sigmas, and the NIS sums per kind and cell."""
    from ..nav.runs import UPDATE_KINDS

    s = _run_series(out_dir)
    t0 = float(s["seg_t"][0, 0])  # the scenario's start on the replay's time base
    duration = float(s["seg_t"][-1, 1]) - t0
    n = int(np.floor(duration / grid_s)) + 1
    grid = np.arange(n) * grid_s
    tau = s["t"] - t0
    dt = float(np.median(np.diff(tau))) if len(tau) > 1 else grid_s
    h = np.hypot(s["err_ned_m"][:, 0], s["err_ned_m"][:, 1])
    v = np.abs(s["err_ned_m"][:, 2])
    series = {"nees9": _on_grid(tau, s["nees9"], grid, dt),
              "heading_known": _on_grid(tau, s["heading_known"].astype(float), grid, dt) == 1.0,
              "err_h_m": _on_grid(tau, h, grid, dt), "err_v_m": _on_grid(tau, v, grid, dt),
              "sigma_h_m": _on_grid(tau, np.hypot(s["sigma_ned_m"][:, 0], s["sigma_ned_m"][:, 1]), grid, dt),
              "sigma_v_m": _on_grid(tau, s["sigma_ned_m"][:, 2], grid, dt)}

    nis, nis_cells = {}, {}
    for code in np.unique(s["upd_kind"]):
        kind = UPDATE_KINDS.get(int(code), f"kind_{int(code)}")
        m = s["upd_kind"] == code
        acc = m & s["upd_accepted"]
        dof, val = s["upd_dof"][acc].astype(float), s["upd_nis"][acc]
        nis[kind] = {"updates": int(m.sum()), "accepted": int(acc.sum()), "dof_sum": float(dof.sum()),
                     "nis_sum": float(val.sum()),
                     "mean_per_dof": float(val.sum() / dof.sum()) if dof.sum() > 0 else float("nan")}
        k, ok = grid_index(s["upd_t"][acc] - t0, grid_s, n)
        nis_cells[kind] = {"nis": np.bincount(k[ok], val[ok], minlength=n),
                           "dof": np.bincount(k[ok], dof[ok], minlength=n)}

    segments = []
    for label, (a, b) in zip(s["seg_labels"], s["seg_t"]):
        m = (s["t"] >= a) & (s["t"] < b) & np.isfinite(h)
        seg = {"label": str(label), "t0_s": float(a - t0), "t1_s": float(b - t0), "n": int(m.sum())}
        if m.any():
            e = s["nees9"][m]
            seg.update(h_rms_m=float(np.sqrt(np.mean(h[m] ** 2))), v_rms_m=float(np.sqrt(np.mean(v[m] ** 2))),
                       h_max_m=float(h[m].max()), v_max_m=float(v[m].max()),
                       nees9_mean=float(np.mean(e[np.isfinite(e)])) if np.isfinite(e).any() else float("nan"))
        segments.append(seg)

    scoring = run_json.get("scoring", {})
    outages = [{"index": i, "start_s": o["start"] - t0, "end_s": o["end"] - t0, "max_h_m": o["max_h_m"],
                "max_v_m": o["max_v_m"]} for i, o in enumerate(scoring.get("per_outage", []))]
    known = np.flatnonzero(s["heading_known"])
    figures = dict(run_json.get("errors") or {})
    figures["first_heading_s"] = float(tau[known[0]]) if len(known) else float("nan")
    if "all" in scoring:
        figures.update({f"all_{k}": v for k, v in scoring["all"].items()})
    if outages:
        for axis in ("horizontal_m", "vertical_m"):
            figures.update({f"outage_{axis[0]}_drift_{k}_m": v for k, v in scoring[axis].items()})
    return {"figures": figures, "counters": dict(run_json.get("counters", {})), "nis": nis,
            "segments": segments, "outages": outages, "grid_s": grid_s,
            "series": series, "nis_cells": nis_cells, "imu_samples": run_json.get("imu_samples")}

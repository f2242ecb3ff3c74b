"""Robustness sweep: IMU rates x drive profiles x seeds through replay, loose and tight.

    python benchmarks/bench_robustness.py                                  # the full sweep (long)
    python benchmarks/bench_robustness.py --rates 64,200 --profiles default --seeds 1
    python benchmarks/bench_robustness.py --jobs 2 --json sweep.json --set gate_probability=0.999

For every (rate, profile, seed) the simulator writes a session directly to files
(sim/session: no ptys, no logger) at that IMU rate, and the session is replayed
through the Python API (``replay.replay``: decoding, time alignment, the filter,
the errors against the truth file) in each mode with one preset. The filter is
told the session's IMU rate (``imu_rate_hz``), as a user configures it; with
``--preset-rate`` it keeps the preset's.

Per run: final and RMS horizontal/vertical position errors and the largest
horizontal error over the whole run (every solution epoch, standstill and the
time before the heading is known included), rejected GNSS measurements, the
filter's divergence flag, its resets (any counter whose name says reset or
re-initialisation, so they appear once the filter has them), the mean 9-state
NEES over the whole run and from the known heading on (9 for a consistent
filter), and whether it converged: not diverged and a final horizontal error
under 5 m. A summary per rate, profile and mode follows.

Runs go to worker processes (``--jobs``, default 2), one process per run, so
each run's peak RSS is its own (printed). Another run starts only while the
estimated peaks of the running ones fit ``--memory-gb``; the estimate, 6.5 kB per
IMU sample, dates from before replay streamed its results and is now far above
what a run takes (at most 619 MB for the 5-minute profiles at 400 Hz).
"""

from __future__ import annotations

import argparse
import concurrent.futures as cf
import json
import multiprocessing as mp
import resource
import shutil
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

RATES = (50, 64, 100, 200, 400)
PROFILES = ("default", "urban_highway", "stop_and_go", "walk")
MODES = ("loose", "tight")
CONVERGED_FINAL_H_M = 5.0


def _counters(counters: dict) -> tuple[bool, int, dict]:
    """(diverged, resets, the reset counters found) from whatever counters the filter reports."""
    diverged = any(bool(v) for k, v in counters.items() if "diverg" in k and isinstance(v, (bool, int)))
    found = {k: int(v) for k, v in counters.items()
             if any(w in k for w in ("reset", "reinit", "re_init")) and isinstance(v, (bool, int, float))}
    return diverged, int(sum(found.values())), found


def _rejected(counters: dict, mode: str) -> str:
    if mode == "tight":
        used, rej = counters.get("pseudoranges_used", 0), counters.get("pseudoranges_rejected", 0)
        return f"{rej}/{used + rej}"
    return f"{counters.get('fixes_rejected', 0)}/{counters.get('fixes', 0)}"


def metrics(run_dir: Path, mode: str) -> dict:
    """Figures of one replay from its results and run.json."""
    from gpsins.replay import results as results_mod

    summary = json.loads((run_dir / "run.json").read_text())
    z = results_mod.load(run_dir)
    out = {"mode": mode, "rejected": _rejected(summary["counters"], mode)}
    diverged, resets, found = _counters(summary["counters"])
    out.update(diverged=diverged, resets=resets, reset_counters=found)
    if "err_ned_m" not in z:
        return {**out, "error": "no errors (no truth)"}
    err, nees = z["err_ned_m"], z["nees9"]
    ok = np.all(np.isfinite(err), axis=1)
    h, v = np.hypot(err[ok, 0], err[ok, 1]), np.abs(err[ok, 2])
    hk = z["heading_known"][ok]
    n_ok = nees[ok]
    out.update(final_h_m=float(h[-1]), final_v_m=float(v[-1]), rms_h_m=float(np.sqrt(np.mean(h ** 2))),
               rms_v_m=float(np.sqrt(np.mean(v ** 2))), max_h_m=float(h.max()),
               nees_all=float(np.mean(n_ok)), nees_heading=float(np.mean(n_ok[hk])) if hk.any() else float("nan"),
               heading_known_s=float(np.sum(np.diff(z["t"][ok])[hk[1:]])),
               t_first_s=float(z["t"][ok][0] - z["seg_t"][0, 0]) if "seg_t" in z else float("nan"))
    out["converged"] = bool(not diverged and out["final_h_m"] < CONVERGED_FINAL_H_M)
    return out


def run_case(rate: int, profile: str, seed: int, modes: tuple[str, ...], preset: str, overrides: dict,
             preset_rate: bool, keep: str | None) -> list[dict]:
    """Simulate one session and replay it in each mode (in a worker process)."""
    from gpsins.replay import run
    from gpsins import sim
    from gpsins.sim import scenario
    from gpsins.sim.scenario import with_imu_rate
    from gpsins.sim.session import write_session

    tmp = Path(tempfile.mkdtemp(prefix=f"robust-{profile}-{rate}-{seed}-", dir=keep))
    rows = []
    try:
        t0 = time.perf_counter()
        sc = with_imu_rate(scenario.load(profile), rate)
        s = sim.simulate(sc, seed)
        write_session(s, tmp / "session")
        del s
        sim_s = time.perf_counter() - t0
        cfg_over = dict(overrides)
        if not preset_rate:
            cfg_over.setdefault("imu_rate_hz", float(rate))
        for mode in modes:
            t1 = time.perf_counter()
            base = {"rate_hz": rate, "profile": profile, "seed": seed, "mode": mode, "simulate_s": sim_s}
            try:
                run.replay(tmp / "session", tmp / mode, mode=mode, config=preset, overrides=cfg_over)
                row = {**base, **metrics(tmp / mode, mode)}
            except Exception as e:  # a run that does not replay is a result of the sweep
                row = {**base, "error": f"{type(e).__name__}: {e}".splitlines()[0][:160], "converged": False}
            row["replay_s"] = time.perf_counter() - t1
            rows.append(row)
    finally:
        if keep is None:
            shutil.rmtree(tmp, ignore_errors=True)
    peak = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024
    for r in rows:
        r["peak_mb"] = peak
    return rows


HEADER = (f"{'rate':>4} {'profile':<14}{'seed':>4} {'mode':<6}{'fin_h':>8}{'fin_v':>8}{'rms_h':>8}{'rms_v':>8}"
          f"{'max_h':>9}{'rejected':>11}{'div':>5}{'rst':>4}{'nees':>9}{'nees_hk':>9}{'conv':>5}{'s':>6}")


def _num(x: float, width: int, digits: int) -> str:
    """Fixed point while it fits, else two significant digits (diverged runs reach 1e6 m)."""
    text = f"{x:.{digits}f}"
    return f"{text if len(text) < width else f'{x:.2g}':>{width}}"


def fmt(r: dict) -> str:
    head = f"{r['rate_hz']:>4} {r['profile']:<14}{r['seed']:>4} {r['mode']:<6}"
    if "error" in r:
        return head + f" FAILED: {r['error']}"
    return head + ("".join(_num(r[k], 8, 2) for k in ("final_h_m", "final_v_m", "rms_h_m", "rms_v_m"))
                   + _num(r["max_h_m"], 9, 1) + f"{r['rejected']:>11}{'yes' if r['diverged'] else '-':>5}"
                   f"{r['resets']:>4}" + _num(r["nees_all"], 9, 1) + _num(r["nees_heading"], 9, 1)
                   + f"{'ok' if r['converged'] else 'NO':>5}{r['simulate_s'] + r['replay_s']:>6.0f}")


def summary(rows: list[dict]) -> list[str]:
    """Per rate, profile and mode: runs converged, worst final and mean RMS horizontal error, NEES."""
    out = ["", f"{'rate':>4} {'profile':<14}{'mode':<6}{'conv':>7}{'worst fin_h':>12}{'mean rms_h':>11}"
           f"{'mean nees':>10}{'diverged':>9}{'resets':>7}"]
    keys = sorted({(r["rate_hz"], r["profile"], r["mode"]) for r in rows},
                  key=lambda k: (k[0], PROFILES.index(k[1]) if k[1] in PROFILES else 99, k[1], k[2]))
    for key in keys:
        rs = [r for r in rows if (r["rate_hz"], r["profile"], r["mode"]) == key]
        good = [r for r in rs if "error" not in r]
        conv = sum(bool(r.get("converged")) for r in rs)
        if good:
            worst = max(r["final_h_m"] for r in good)
            line = (_num(worst, 12, 2) + _num(float(np.mean([r["rms_h_m"] for r in good])), 11, 2)
                    + _num(float(np.mean([r["nees_all"] for r in good])), 10, 1)
                    + f"{sum(r['diverged'] for r in good):>9}{sum(r['resets'] for r in good):>7}")
        else:
            line = f"{'-':>12}{'-':>11}{'-':>10}{'-':>9}{'-':>7}"
        out.append(f"{key[0]:>4} {key[1]:<14}{key[2]:<6}{conv:>4}/{len(rs):<2}" + line)
    return out


def estimate_mb(rate: int, profile: str) -> float:
    """A run's peak RSS, from measured ones: about 6.5 kB per IMU sample (the replay keeps every
    epoch's state and covariance) plus the interpreter."""
    from gpsins.sim import scenario

    return 300.0 + 6.5e-3 * rate * scenario.load(profile).duration_s


def _list(text: str, kind=str) -> list:
    return [kind(x) for x in text.split(",") if x.strip()]


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--rates", default=",".join(map(str, RATES)), help="IMU rates in Hz, comma-separated")
    ap.add_argument("--profiles", default=",".join(PROFILES), help="built-in scenarios or TOML files, comma-separated")
    ap.add_argument("--seeds", default="3", help="N (seeds 1..N) or a comma-separated list")
    ap.add_argument("--modes", default=",".join(MODES))
    ap.add_argument("--preset", default="default")
    ap.add_argument("--set", action="append", default=[], metavar="KEY=VALUE", help="filter configuration override")
    ap.add_argument("--preset-rate", action="store_true", help="keep the preset's imu_rate_hz")
    ap.add_argument("--jobs", type=int, default=2)
    ap.add_argument("--memory-gb", type=float, default=8.0,
                    help="start another run only while the runs' estimated peaks fit (default 8)")
    ap.add_argument("--json", help="write every run's figures here")
    ap.add_argument("--keep", help="keep sessions and results under this directory")
    a = ap.parse_args()
    import tomllib

    overrides = {}
    for kv in a.set:
        k, _, v = kv.partition("=")
        try:
            overrides[k] = tomllib.loads(f"x = {v}")["x"]
        except tomllib.TOMLDecodeError:
            overrides[k] = v
    seeds = _list(a.seeds, int)
    if "," not in a.seeds and len(seeds) == 1:
        seeds = list(range(1, seeds[0] + 1))
    cases = [(r, p, s) for p in _list(a.profiles) for r in _list(a.rates, int) for s in seeds]
    modes = tuple(_list(a.modes))
    if a.keep:
        Path(a.keep).mkdir(parents=True, exist_ok=True)
    print(f"{len(cases)} sessions x {len(modes)} modes, preset {a.preset}"
          f"{', overrides ' + str(overrides) if overrides else ''}, {a.jobs} processes", flush=True)
    print(HEADER, flush=True)
    rows: list[dict] = []
    t0 = time.perf_counter()
    ctx = mp.get_context("spawn")
    budget = a.memory_gb * 1024
    todo = list(cases)
    running: dict[cf.Future, tuple] = {}
    with cf.ProcessPoolExecutor(max_workers=a.jobs, mp_context=ctx, max_tasks_per_child=1) as pool:
        while todo or running:
            # Start cases while processes are free and their estimated memory fits (one always may run).
            while todo and len(running) < a.jobs:
                case = todo[0]
                if running and sum(estimate_mb(*c[:2]) for c in running.values()) + estimate_mb(*case[:2]) > budget:
                    break
                todo.pop(0)
                running[pool.submit(run_case, *case, modes, a.preset, overrides, a.preset_rate, a.keep)] = case
            done, _ = cf.wait(running, return_when=cf.FIRST_COMPLETED)
            for fut in done:
                r, p, s = running.pop(fut)
                try:
                    got = fut.result()
                except Exception as e:  # the worker itself died (memory, a crash in the core)
                    got = [{"rate_hz": r, "profile": p, "seed": s, "mode": m, "error": f"worker: {e}",
                            "converged": False} for m in modes]
                for row in got:
                    rows.append(row)
                    print(fmt(row), flush=True)
    print("\n".join(summary(rows)))
    peak = max((r.get("peak_mb", 0) for r in rows), default=0)
    print(f"\n{len(rows)} runs in {time.perf_counter() - t0:.0f} s; largest worker peak RSS {peak:.0f} MB; "
          f"converged {sum(bool(r.get('converged')) for r in rows)}/{len(rows)}")
    if a.json:
        Path(a.json).write_text(json.dumps(rows, indent=1, default=float) + "\n")
    return 0 if all(r.get("converged") for r in rows) else 1


if __name__ == "__main__":
    sys.exit(main())

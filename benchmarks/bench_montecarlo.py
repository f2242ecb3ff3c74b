"""Monte Carlo on a local Dask cluster: speed-up over one worker, and the aggregate NEES result.

    python benchmarks/bench_montecarlo.py                      # default drive, 20 seeds, 1 then 2 workers
    python benchmarks/bench_montecarlo.py --seeds 8 --workers 1,2 --mode both --repeat 2

Each measurement is ``gpsins montecarlo SCENARIO --seeds N --workers K`` through the Python API
(``montecarlo.open_client`` + ``run_plan``), timed as a whole (cluster start-up, simulations,
replays, tables, aggregate and figures) and without the cluster's start-up. Task times summed
over the workers show how busy they were. On a machine shared with other work, CPU contention,
not the cluster, limits the speed-up; the share of task time spent on a core (CPU / wall of the
worker processes) says how much. ``--repeat`` alternates the worker counts and keeps each one's
fastest run; ``--wait-quiet`` starts each measurement only when the CPUs are mostly free (Linux
pressure stall information). The aggregate printed is that of the last run (the same for every
worker count: the seeds fix every number).
"""

from __future__ import annotations

import argparse
import os
import shutil
import sys
import tempfile
import time
from pathlib import Path


def measure(scenario, seeds: list[int], mode: str, workers: int, out: Path) -> dict:
    from gpsins.montecarlo.runner import Plan, open_client, run_plan

    modes = ["loose", "tight"] if mode == "both" else [mode]
    plan = Plan(scenario=scenario, seeds=seeds, out=out, modes=modes)
    t0 = time.perf_counter()
    cpu0 = os.times()
    with open_client(workers=workers) as client:
        t1 = time.perf_counter()
        outcome = run_plan(plan, client, progress=False)
        t2 = time.perf_counter()
    t3 = time.perf_counter()
    agg = outcome.aggregate
    tt = agg["task_time_s"]
    busy = tt["simulate_s"] + tt["replay_tasks_s"]
    cpu = tt["simulate_cpu_s"] + tt["replay_tasks_cpu_s"]
    return {"workers": outcome.workers, "whole_s": t3 - t0, "startup_s": t1 - t0, "run_plan_s": t2 - t1,
            "busy_s": busy, "utilisation": busy / (outcome.wall_s * outcome.workers), "task_cpu_s": cpu,
            "cpu_share": cpu / busy,
            # The time the workers' tasks waited for a core held by other work, taken out (their CPU time
            # stays; the client's share is not corrected, so this errs on the slow side).
            "uncontended_s": t3 - t0 - (busy - cpu) / outcome.workers,
            "client_cpu_s": sum(os.times()[:2]) - sum(cpu0[:2]), "failed": agg["failed"], "aggregate": agg,
            "load": os.getloadavg()[0]}


def cpu_pressure() -> float | None:
    """Share of the last 10 s in which some runnable task waited for a CPU (Linux PSI), percent."""
    try:
        line = Path("/proc/pressure/cpu").read_text().splitlines()[0]
    except (OSError, IndexError):
        return None
    return float(line.split()[1].split("=")[1])


def wait_quiet(max_wait_s: float, below_pct: float = 20.0) -> str:
    """Wait (up to max_wait_s) until other work leaves the CPUs mostly free; say how it looked."""
    t0 = time.monotonic()
    while True:
        p = cpu_pressure()
        if p is None or p < below_pct or time.monotonic() - t0 > max_wait_s:
            return f"CPU pressure {p if p is not None else float('nan'):.0f} % after {time.monotonic() - t0:.0f} s"
        time.sleep(5)


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--scenario", default="default")
    ap.add_argument("--seeds", type=int, default=20)
    ap.add_argument("--mode", default="loose", choices=("loose", "tight", "both"))
    ap.add_argument("--workers", default="1,2", help="worker counts to compare, comma-separated")
    ap.add_argument("--repeat", type=int, default=1, help="alternate the worker counts this many times")
    ap.add_argument("--keep", help="keep the outputs under this directory")
    ap.add_argument("--wait-quiet", type=float, default=0.0, metavar="S",
                    help="before each measurement wait up to S seconds for the CPUs to be mostly free of other work")
    a = ap.parse_args()
    from gpsins.sim import scenario as scenario_mod

    sc = scenario_mod.load(a.scenario)
    counts = [int(x) for x in a.workers.split(",")]
    root = Path(a.keep) if a.keep else Path(tempfile.mkdtemp(prefix="bench-mc-"))
    print(f"{sc.name} ({sc.duration_s:.0f} s), {a.seeds} seeds, mode {a.mode}, workers {counts}, "
          f"{os.cpu_count()} cores, load average {os.getloadavg()[0]:.2f} at the start", flush=True)
    best: dict[int, dict] = {}
    try:
        for r in range(a.repeat):
            for k in counts:
                out = root / f"w{k}-r{r}"
                quiet = wait_quiet(a.wait_quiet) if a.wait_quiet else ""
                m = measure(sc, list(range(a.seeds)), a.mode, k, out)
                print(f"  {k} worker(s): whole {m['whole_s']:.1f} s (cluster start {m['startup_s']:.1f} s, run "
                      f"{m['run_plan_s']:.1f} s), task time {m['busy_s']:.1f} s (CPU {m['task_cpu_s']:.1f} s: "
                      f"{100 * m['cpu_share']:.0f} % of it on a core), workers busy "
                      f"{100 * m['utilisation']:.0f} %, client CPU {m['client_cpu_s']:.1f} s, failed {m['failed']}, "
                      f"load average {m['load']:.2f}{'; before it ' + quiet if quiet else ''}", flush=True)
                if k not in best or m["whole_s"] < best[k]["whole_s"]:
                    best[k] = m
                if not a.keep:
                    shutil.rmtree(out, ignore_errors=True)
    finally:
        if not a.keep:
            shutil.rmtree(root, ignore_errors=True)
    one = best.get(min(counts))
    for k in counts:
        if k != min(counts):
            m = best[k]
            print(f"speed-up {k} vs {min(counts)} worker(s): whole command {one['whole_s'] / m['whole_s']:.2f}x "
                  f"({one['whole_s']:.1f} s -> {m['whole_s']:.1f} s); run alone "
                  f"{one['run_plan_s'] / m['run_plan_s']:.2f}x ({one['run_plan_s']:.1f} s -> {m['run_plan_s']:.1f} s); "
                  f"with the workers' waits for a core taken out {one['uncontended_s'] / m['uncontended_s']:.2f}x "
                  f"({one['uncontended_s']:.1f} s -> {m['uncontended_s']:.1f} s)")
    last = best[counts[-1]]["aggregate"]
    for g in last["groups"]:
        n, hk = g["nees9"], g["nees9_heading_known"]
        print(f"{g['mode']}: {g['succeeded']} runs; 9-state NEES averaged over runs, {100 * (1 - n['alpha']):.0f} % "
              f"band {n['band_all_runs'][0]:.2f}..{n['band_all_runs'][1]:.2f}: {100 * n['fraction_inside']:.1f} % of "
              f"{n['epochs']} epochs inside ({100 * n['fraction_below']:.1f} % below, "
              f"{100 * n['fraction_above']:.1f} % above), time average {n['time_averaged']:.2f}; "
              f"from the known heading on {100 * hk['fraction_inside']:.1f} % inside, "
              f"time average {hk['time_averaged']:.2f}; horizontal RMS "
              f"{g['errors']['horizontal_rms_m']['mean']:.2f} m")
        for kind, s in g["nis"].items():
            print(f"    NIS {kind}: mean per dof {s['mean_per_dof']:.2f} (band {s['band_mean_per_dof'][0]:.2f}.."
                  f"{s['band_mean_per_dof'][1]:.2f}), {100 * s['fraction_inside']:.1f} % of {s['cells']} 1-s cells "
                  "inside their band")
    return 0


if __name__ == "__main__":
    sys.exit(main())

"""The Monte Carlo on a Dask cluster: the task graph, progress, and the files it leaves.

Per seed one ``simulate`` task writes the session; per (seed, mode, swept value) one ``replay``
task depends on it, replays it into its own directory and returns its summary. The client
submits small task descriptions, receives small summaries, and writes the table, the
aggregate and the figures. Dask is imported only when a cluster is opened.
"""

from __future__ import annotations

import contextlib
import csv
import os
import threading
import time
import uuid
from dataclasses import dataclass, field
from pathlib import Path

from ..replay import results
from . import tasks

TABLE = "runs.csv"
SEGMENT_TABLE = "segments.csv"
OUTAGE_TABLE = "outages.csv"
AGGREGATE = "aggregate.json"


@dataclass
class Plan:
    """What to run. ``scenario``: a loaded ``sim.Scenario`` (shipped to the workers, so a remote
    worker needs no scenario file). ``sweep_values``: [None] without a sweep."""

    scenario: object
    seeds: list[int]
    out: Path
    modes: list[str] = field(default_factory=lambda: ["loose"])
    config: str | dict | None = None  # a preset name or a configuration table (load_config)
    overrides: dict = field(default_factory=dict)
    outages: str | None = None
    sweep_key: str | None = None
    sweep_values: list = field(default_factory=lambda: [None])
    sweep_texts: list[str] = field(default_factory=lambda: [""])
    grid_s: float = 1.0
    alpha: float = 0.05
    keep: str = "all"  # all: sessions and replay results; results: replay results; none: the tables only
    estimator: str | None = None  # a plug-in estimator (package.module:name) in the built-in filter's place

    def overrides_for(self, value) -> dict:
        if self.sweep_key is None:
            return dict(self.overrides)
        from ..nav.config import merge, parse_overrides

        return merge(self.overrides, parse_overrides([f"{self.sweep_key}={value}"]))

    def session_dir(self, seed: int) -> Path:
        return self.out / f"seed-{seed:04d}" / "session"

    def run_dir(self, seed: int, i_value: int, mode: str) -> Path:
        base = self.out / f"seed-{seed:04d}"
        return (base / f"sweep-{i_value:02d}" / mode) if self.sweep_key else base / mode


@dataclass
class Outcome:
    summaries: list[dict]
    aggregate: dict
    files: list[Path]
    wall_s: float
    workers: int


@contextlib.contextmanager
def open_client(scheduler: str | None = None, workers: int | None = None):
    """A Dask client: on an existing scheduler (``tcp://host:port`` or a scheduler file), else on
    a local cluster of ``workers`` processes (default: one per core) with one thread each."""
    from dask.distributed import Client, LocalCluster

    if scheduler:
        kw = {"scheduler_file": scheduler} if Path(scheduler).is_file() else {"address": scheduler}
        client = Client(timeout="30s", **kw)
        try:
            yield client
        finally:
            client.close()
        return
    import dask

    n = workers or os.cpu_count() or 1
    # Dask starts its workers with glibc's heap trimmed at 64 kB, which also pins the threshold
    # above which an allocation gets its own mapping at 128 kB: every NumPy temporary of a replay
    # is then mapped, faulted in and unmapped (4 seeds of the default drive: 3.5 s of system time
    # instead of 0.7 s, a quarter of the run). The workers keep Dask's thread limits and glibc's
    # own adaptive heap, as a replay run from the command line has.
    environ = {k: v for k, v in dask.config.get("distributed.nanny.pre-spawn-environ", {}).items()
               if k != "MALLOC_TRIM_THRESHOLD_"}
    # Processes, not threads: the simulator and replay hold the GIL for much of their time. The
    # scheduler's HTTP port is any free one, so two clusters on one machine do not collide.
    with dask.config.set({"distributed.nanny.pre-spawn-environ": environ}), \
            LocalCluster(n_workers=n, threads_per_worker=1, processes=True, dashboard_address=":0") as cluster, \
            Client(cluster) as client:
        yield client


def _warm() -> str:
    """Import what the tasks need, once per worker process, before the first task is timed."""
    from .. import sim  # noqa: F401
    from ..sim import session  # noqa: F401

    return tasks.worker_place()


def _preload_outputs() -> None:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot  # noqa: F401
    import scipy.stats  # noqa: F401


def run_plan(plan: Plan, client, progress: bool = True) -> Outcome:
    """Run every seed x mode x value on the client's cluster and write the tables, aggregate and figures."""
    from dask.distributed import as_completed

    t0 = time.perf_counter()
    plan.out = Path(plan.out).resolve()
    plan.out.mkdir(parents=True, exist_ok=True)
    try:
        client.run(_warm)
    except ImportError as e:
        raise ValueError(f"a Dask worker cannot import gpsins ({e}); install it where the workers run") from None
    workers = len(client.scheduler_info().get("workers", {}))
    token = uuid.uuid4().hex[:8]
    # Seed by seed, so a seed's replays run (and its session can go) before later seeds are simulated.
    sims, futures, cleanups = {}, {}, []
    for seed in plan.seeds:
        sims[seed] = client.submit(tasks.simulate_task, plan.scenario, seed, str(plan.session_dir(seed)),
                                   key=f"simulate-{seed}-{token}", pure=False)
        mine = []
        for i, value in enumerate(plan.sweep_values):
            for mode in plan.modes:
                run = {"mode": mode, "out": str(plan.run_dir(seed, i, mode)), "config": plan.config,
                       "overrides": plan.overrides_for(value), "outages": plan.outages,
                       "estimator": plan.estimator, "value": plan.sweep_texts[i] if plan.sweep_key else None}
                fut = client.submit(tasks.replay_task, sims[seed], run, plan.grid_s,
                                    key=f"replay-{mode}-{seed}-{i}-{token}", pure=False)
                futures[fut] = run | {"seed": seed}
                mine.append(fut)
        if plan.keep != "all":  # on a worker, after the seed's replays: the client may not see --out
            where = plan.session_dir(seed) if plan.keep == "results" else plan.session_dir(seed).parent
            cleanups.append(client.submit(tasks.discard_task, str(where), *mine, key=f"discard-{seed}-{token}",
                                          pure=False))
    # The client's own imports for the outputs, while the workers compute: not a serial tail after them.
    preload = threading.Thread(target=_preload_outputs, daemon=True)
    preload.start()
    summaries = []
    with _progress(len(futures), progress) as advance:
        for fut in as_completed(futures):
            run = futures[fut]
            try:
                s = fut.result()
            except Exception as e:  # the worker died (memory, a crash in the core)
                s = {"seed": run["seed"], "mode": run["mode"], "value": run["value"], "out": run["out"],
                     "error": f"worker: {type(e).__name__}: {e}".splitlines()[0][:200]}
            summaries.append(s)
            advance(s)
    client.gather(cleanups)
    for f in sims.values():
        f.release()
    values = plan.sweep_texts if plan.sweep_key else [None]
    summaries.sort(key=lambda s: (plan.seeds.index(s["seed"]), values.index(s["value"]), plan.modes.index(s["mode"])))
    preload.join()
    wall = time.perf_counter() - t0
    aggregate, files = write_outputs(plan, summaries, wall, workers)
    return Outcome(summaries, aggregate, files, wall, workers)


@contextlib.contextmanager
def _progress(total: int, show: bool):
    """A progress bar over the runs (rich), naming failed runs as they come."""
    if not show:
        yield lambda s: None
        return
    from rich.progress import BarColumn, MofNCompleteColumn, Progress, TextColumn, TimeElapsedColumn, \
        TimeRemainingColumn

    with Progress(TextColumn("{task.description}"), BarColumn(), MofNCompleteColumn(), TimeElapsedColumn(),
                  TimeRemainingColumn()) as bar:
        task = bar.add_task("runs", total=total)

        def advance(s: dict) -> None:
            if "error" in s:
                bar.console.print(f"seed {s['seed']} {s['mode']}{' ' + s['value'] if s['value'] else ''}: "
                                  f"FAILED: {s['error']}")
            bar.advance(task)

        yield advance


def _group_key(s: dict) -> tuple:
    return s["mode"], s["value"]


def write_outputs(plan: Plan, summaries: list[dict], wall_s: float, workers: int) -> tuple[dict, list[Path]]:
    """The run table, the segment and outage tables, aggregate.json and the figures."""
    from . import aggregate as agg, figure

    value_col = plan.sweep_key or "value"
    files = [_write_table(plan.out / TABLE, [_row(s, value_col) for s in summaries])]
    seg_rows = [[{"seed": s["seed"], "mode": s["mode"], value_col: s["value"], **seg}]
                for s in summaries if "error" not in s for seg in s["segments"]]
    files.append(_write_table(plan.out / SEGMENT_TABLE, seg_rows))
    out_rows = [[{"seed": s["seed"], "mode": s["mode"], value_col: s["value"], **o}]
                for s in summaries if "error" not in s for o in s["outages"]]
    if out_rows:
        files.append(_write_table(plan.out / OUTAGE_TABLE, out_rows))
    groups = []
    for key in dict.fromkeys(_group_key(s) for s in summaries):
        members = [s for s in summaries if _group_key(s) == key]
        groups.append({"mode": key[0], value_col: key[1], **agg.aggregate_group(members, plan.alpha)})
    name = getattr(plan.scenario, "name", str(plan.scenario))
    for g in groups:
        if g.get("succeeded"):
            label = f"{g['mode']}" + (f", {plan.sweep_key} = {g[plan.sweep_key]}" if plan.sweep_key else "")
            stem = f"montecarlo_{g['mode']}" + (f"_{plan.sweep_texts.index(g[plan.sweep_key]):02d}"
                                                if plan.sweep_key else "")
            path = figure.draw(g, plan.out / f"{stem}.png", f"{name}: {g['succeeded']} runs, {label}")
            g["figure"] = path.name
            files.append(path)
    result = {"scenario": name, "seeds": plan.seeds, "modes": plan.modes, "config": plan.config,
              "overrides": plan.overrides, "outages": plan.outages, "estimator": plan.estimator,
              "sweep": {"key": plan.sweep_key, "values": plan.sweep_texts} if plan.sweep_key else None,
              "grid_s": plan.grid_s, "alpha": plan.alpha, "workers": workers, "wall_time_s": wall_s,
              "task_time_s": _task_times(summaries),
              "runs": len(summaries), "failed": sum("error" in s for s in summaries),
              "tables": [p.name for p in files if p.suffix == ".csv"], "groups": groups}
    path = plan.out / AGGREGATE
    path.write_text(results.json_text(result, indent=1) + "\n", encoding="utf-8")
    files.append(path)
    return result, files


def _task_times(summaries: list[dict]) -> dict:
    """Summed time on the workers: simulations (once per seed) and replay tasks."""
    done = [s["wall"] for s in summaries if "wall" in s]
    per_seed = {s["seed"]: s["wall"] for s in summaries if "wall" in s}
    return {"simulate_s": float(sum(w["simulate_s"] for w in per_seed.values())),
            "simulate_cpu_s": float(sum(w["simulate_cpu_s"] for w in per_seed.values())),
            "replay_tasks_s": float(sum(w["task_s"] for w in done)),
            "replay_tasks_cpu_s": float(sum(w["task_cpu_s"] for w in done))}


def _row(s: dict, value_col: str) -> list[dict]:
    """One line of the run table, in column groups: identity and status, the run's figures, NIS
    per update kind, counters, wall times."""
    head = {"seed": s["seed"], "mode": s["mode"], value_col: s["value"],
            "status": "failed" if "error" in s else "ok", "error": s.get("error", ""), "dir": s.get("out", "")}
    if "error" in s:
        return [head]
    nis = {}
    for kind, n in s["nis"].items():
        nis.update({f"nis_{kind}_mean_per_dof": n["mean_per_dof"], f"nis_{kind}_accepted": n["accepted"],
                    f"nis_{kind}_updates": n["updates"]})
    counters = {k: v for k, v in s["counters"].items() if isinstance(v, (bool, int, float))}
    return [head, s["figures"], nis, counters, {**s["wall"], "worker": s.get("worker", "")}]


def _write_table(path: Path, rows: list[list[dict]]) -> Path:
    """CSV of rows given as column groups: each group's columns in first-seen order over all rows,
    empty cells where a row has none (a loose run has no pseudorange NIS)."""
    groups = max((len(r) for r in rows), default=0)
    columns = list(dict.fromkeys(k for g in range(groups) for r in rows if g < len(r) for k in r[g]))
    with open(path, "w", newline="", encoding="utf-8") as f:
        w = csv.DictWriter(f, columns, restval="")
        w.writeheader()
        for r in rows:
            w.writerow({k: _cell(v) for part in r for k, v in part.items()})
    return path


def _cell(v):
    if isinstance(v, bool):
        return int(v)
    if isinstance(v, float):
        return repr(v)
    return "" if v is None else v



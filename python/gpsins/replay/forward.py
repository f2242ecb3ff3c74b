"""The filter's passes of one mode's run: the run set up (``start``: an INS run's first pass up to its
free start, a plug-in estimator or the built-in filter), the forward pass written chunk by chunk
(``forward``) and the fixed-interval smoother's backward pass (``smooth``).
"""

from __future__ import annotations

import time
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from ..nav import estimator as estimator_mod
from ..nav import noise_from_data
from ..nav import runs as flt
from ..session import layouts
from . import results, solution
from .plan import Plan, lever_arm_body_m
from .scoring import Target, Scored, score_stream


def _ins_aiding_end(run: flt.ChunkedRun, fixes: np.ndarray) -> float | None:
    """Time of the fix after which the filter was initialised (heading known): the last one an INS run
    gets. Only the chunks up to that point are run."""
    for sol in run.chunks(covariance=False):
        known = np.flatnonzero(sol.heading_known)
        if len(known):
            t_known = sol.t[known[0]]
            used = fixes[(fixes[:, 0] <= t_known) & np.isin(fixes[:, 9], (2, 3))]
            return float(used[-1, 0]) if len(used) else float(t_known)
    return None


def start(inp, p: Plan, *, chunk_rows: int, overlap: bool, smooth: bool, estimator, output_every: int = 1):
    """The run of the plan: (run, the time an INS run's free navigation starts from, the estimator's
    name). An INS run first runs the filter up to the fix that completed its initialisation; the plan
    then gets its fixes up to there and the heading it searched. ``output_every``: an epoch out at every
    so many IMU samples."""
    if output_every < 1:
        raise ValueError(f"--output-every {output_every}: a whole number of IMU samples, at least 1")
    if estimator is not None and output_every != 1:
        raise ValueError("--output-every: the built-in filter's (a plug-in estimator gives every epoch)")

    def make_run(cfg_run: dict, fixes_run: np.ndarray, record: bool) -> flt.ChunkedRun:
        return flt.ChunkedRun(inp.imu, fixes_run, cfg_run, mode=p.filter_mode, record=record, chunk_rows=chunk_rows,
                              attitude=p.attitude, overlap=overlap, output_every=output_every, **p.tight)

    t2 = time.perf_counter()
    free_from, searched = None, None
    if p.mode == "ins":
        first = make_run(p.cfg, p.fixes, False)
        searched = first.heading_search
        free_from = _ins_aiding_end(first, p.fixes)
        if free_from is None:
            raise ValueError(f"{p.source}: --mode ins: the heading never became known, so free navigation never "
                             "started (set initial_yaw_deg, or use data that moves faster than heading_min_speed_mps)")
        if searched and searched["yaw_deg"] is not None:  # the searched heading: aided over the search's fixes
            p.cfg = flt.starting_at_yaw(p.cfg, searched["yaw_deg"], searched["sigma_deg"])
            used = p.fixes[(p.fixes[:, 0] <= searched["t_end"]) & np.isin(p.fixes[:, 9], (2, 3))]
            free_from = float(used[-1, 0]) if len(used) else free_from
        p.fixes = p.fixes[p.fixes[:, 0] <= free_from]
    if estimator is not None:
        est = estimator_mod.load(estimator) if isinstance(estimator, str) else estimator
        estimator = estimator if isinstance(estimator, str) else getattr(est, "__name__", type(est).__name__)
        run = estimator_mod.PluginRun(est, estimator, estimator_mod.EstimatorInputs(
            p.filter_mode, inp.week, np.asarray(inp.imu[:], dtype=float), p.fixes, lever_arm_body_m(p.cfg),
            dict(p.cfg), p.prs[:] if p.prs is not None else None, inp.ephemerides, inp.klobuchar, p.schedule),
            chunk_rows)
    else:
        run = make_run(p.cfg, p.fixes, smooth)
    if searched:
        run.heading_search = searched
    p.clock["filter_setup_s"] = time.perf_counter() - t2
    return run, free_from, estimator


class Output:
    """A results directory being written: its solution streams (``solution.Stream``) share the week, the
    lever arm, the receiver's fix times and the scoring target."""

    def __init__(self, out: Path, inp, target: Target, lever: np.ndarray, point: str, covariance_every: int,
                 what: str):
        self.out, self.week, self.lever, self.point, self.what = out, inp.week, lever, point, what
        self.fix_t, self.fix_sats = inp.fixes[:, 0], inp.fix_sats
        self.target, self.covariance_every = target, covariance_every
        out.mkdir(parents=True, exist_ok=True)
        for stale in (results.SMOOTHED, results.COVARIANCE, "smoothed.pos"):  # from an earlier run into this directory
            (out / stale).unlink(missing_ok=True)

    def stream(self, table: str, pos: str, note: str, newest_first: bool = False, cov: bool = False) -> solution.Stream:
        out, target = self.out, self.target
        return solution.Stream(out / table, out / pos, self.week, note, self.lever, self.fix_t, self.fix_sats,
                               truth=target.truth[0] if target.truth else None, score_point=target.point,
                               pos_point=self.point, bracket_epochs=target.bracket_epochs, newest_first=newest_first,
                               covariance_path=out / results.COVARIANCE if cov else None,
                               covariance_every=self.covariance_every)


@dataclass
class Forward:
    """The forward pass, written: its solution stream and what run.json says of its updates."""

    stream: solution.Stream
    events: dict  # t, kind, value of the filter's events
    update_kinds: dict  # update kind -> count
    sources: dict  # per-source update statistics (noise_from_data.SourceStats)
    counters: dict  # the filter's counters after the pass
    time_offset: tuple | None  # the last epoch's IMU time offset estimate and sigma (s), with estimate_time_offset
    write_s: float


def forward(run, output: Output, p: Plan) -> Forward:
    """The forward pass, chunk by chunk: each chunk's epochs into solution.parquet and solution.pos, its
    updates into updates.parquet, then dropped."""
    t3 = time.perf_counter()
    stream = output.stream(results.SOLUTION, "solution.pos", output.what, cov=output.covariance_every > 0)
    updates = results.TableWriter(output.out / results.UPDATES)
    events: dict[str, list] = {"t": [], "kind": [], "value": []}
    update_kinds: dict[int, int] = {}
    sources = noise_from_data.SourceStats()
    write_s = 0.0
    time_offset = None  # the last epoch's estimate and sigma (s), with estimate_time_offset
    # The full covariance only for the covariance file; the sigmas and NEES take the navigation block.
    for sol in run.chunks(navigation_covariance=output.covariance_every == 0):
        if sol.time_offset is not None and len(sol.t):
            time_offset = (float(sol.time_offset[-1]), float(sol.time_offset_sigma[-1]))
        w0 = time.perf_counter()
        stream.add(sol, stream.epochs)
        updates.append(sol.updates)
        write_s += time.perf_counter() - w0
        sources.add(sol.updates)
        for k in events:
            events[k].extend(np.asarray(sol.events.get(k, ())).tolist())
        for k, n in zip(*np.unique(sol.updates["kind"], return_counts=True)):
            update_kinds[int(k)] = update_kinds.get(int(k), 0) + int(n)
    stream.close()
    updates.close()
    p.clock["filter_s"] = time.perf_counter() - t3 - write_s
    if stream.epochs == 0:
        raise layouts.LogError(f"{p.source}: the filter never initialised (no usable fix after levelling)")
    return Forward(stream, events, update_kinds, sources.result(), run.counters, time_offset, write_s)


def smooth(run, output: Output, target: Target, score_sched: np.ndarray, p: Plan) -> tuple[dict, Scored]:
    """The fixed-interval smoother's pass (newest block first) into smoothed.parquet and smoothed.pos:
    run.json's "smoothed" and its scoring against the reference."""
    ts = time.perf_counter()
    back = output.stream(results.SMOOTHED, "smoothed.pos", output.what + ", fixed-interval smoothed",
                         newest_first=True)
    info = run.smooth(lambda first, sol: back.add(sol, first), navigation_covariance=True)  # no covariance file
    back.close()
    p.clock["smooth_s"] = time.perf_counter() - ts
    smoothed_summary = {"info": info}
    if back.score is not None and back.score.summary():
        smoothed_summary["errors"] = back.score.summary()
    sm_scored = score_stream(back, target.ref, score_sched, results.SMOOTH_PREFIX)
    if sm_scored.summary:
        smoothed_summary["scoring"] = sm_scored.summary
    return smoothed_summary, sm_scored

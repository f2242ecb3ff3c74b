"""The end of one mode's run: results.npz (the receiver's fixes, the outages, the truth's segments, the
scoring), config.toml (the exact configuration) and run.json (the summary: counters, events, what was
skipped, the alignment, timings, errors, health, provenance).
"""

from __future__ import annotations

import hashlib
import shlex
import sys
import time
from pathlib import Path

import numpy as np

from .. import __version__
from ..formats import reference as reference_mod
from ..nav import config as nav_config
from ..nav import runs as flt
from . import results
from .forward import Forward
from .plan import Plan
from .scoring import HEADING_AIDING_INTERVAL_S, Target, Scored, score_reference_system, score_stream
from .summary import health_lines


def write(out: Path, inp, p: Plan, run, fwd: Forward, target: Target, score_sched: np.ndarray, *, point: str,
          lever: np.ndarray, free_from: float | None, smoothed: tuple[dict, Scored] | None, estimator) -> dict:
    """Scores the forward pass, writes results.npz, config.toml and run.json; returns run.json's summary."""
    t4 = time.perf_counter()
    mode, forward, clock = p.mode, fwd.stream, p.clock
    small = dict(week=np.int64(inp.week), fixes=inp.fixes, fix_sats=inp.fix_sats, lever_arm_body_m=lever,
                 outages=p.schedule)
    if target.truth:
        small.update({k: v for k, v in target.truth[1].items() if k != "simulation"})  # arrays only
    scoring = {}
    if target.has_ref:
        scored = score_stream(forward, target.ref, score_sched)
        small.update(scored.arrays)
        scoring = {"reference": str(target.ref[2]), "point": target.point,
                   "n_reference_epochs": int(len(scored.arrays.get("ref_t", ()))), **scored.summary}
        if mode == "ins":
            scoring["ins_free_from"] = free_from
    if smoothed is not None:
        small.update(smoothed[1].arrays)
    np.savez(out / results.SMALL, **small)
    reference_system = score_reference_system(p.ref_system, inp.week, forward.brackets.rows())
    config_text = nav_config.to_toml(p.cfg)
    (out / "config.toml").write_text(config_text, encoding="utf-8")
    clock["write_s"] = fwd.write_s + time.perf_counter() - t4
    clock["total_s"] = sum(v for k, v in clock.items())
    summary = _summary(inp, p, run, fwd, scoring, reference_system, point=point, free_from=free_from,
                       smoothed=smoothed[0] if smoothed is not None else None, estimator=estimator,
                       config_text=config_text)
    (out / "run.json").write_text(results.json_text(summary) + "\n", encoding="utf-8")
    return summary


def _summary(inp, p: Plan, run, fwd: Forward, scoring: dict, reference_system: dict, *, point: str,
             free_from: float | None, smoothed: dict | None, estimator, config_text: str) -> dict:
    """run.json's summary of the run."""
    mode, forward, counters, events, clock = p.mode, fwd.stream, fwd.counters, fwd.events, p.clock
    info = {k: v for k, v in inp.info.items() if k not in ("decode_s", "align_s")}
    event_list = [{"t": float(t), "kind": flt.EVENT_KINDS.get(int(k), str(int(k))), "value": float(v)}
                  for t, k, v in zip(events["t"], events["kind"], events["value"])]
    summary = {"session": info.pop("session", str(p.source)), "kind": inp.kind, "mode": mode,
               "alignment": info.pop("alignment", {}), "counters": counters,
               "imu_gaps_longer_than_max_gap": info.pop("imu_gaps_longer_than_max_gap", []),
               "reinitialisations": {"count": int(counters.get("imu_gap_restarts", 0)),
                                     "at_t": [e["t"] for e in event_list if e["kind"] == "imu_gap_restart"],
                                     "how": "the filter restarted after an IMU gap longer than max_gap_s: attitude "
                                            "and biases kept, heading unknown, covariance inflated"},
               "gnss_resets": {"count": int(counters.get("gnss_resets", 0)),
                               "at_t": [e["t"] for e in event_list if e["kind"] == "gnss_reset"]},
               "events": event_list,
               "warnings": info.pop("warnings", []),
               "skipped": info.pop("skipped", {}), "fixes_after_end": run.fixes_after_end,
               "wall_time_s": clock, "imu_samples": p.n_imu, "epochs": forward.epochs,
               "errors": forward.score.summary() if forward.score is not None else {},
               "update_kinds": {flt.UPDATE_KINDS[k]: n for k, n in sorted(fwd.update_kinds.items())},
               "sources": fwd.sources, "noise_fit": p.noise_fit, "mounting_fit": p.mount_fit,
               "constraint_fit": p.constraint_fit, "lever_arm_fit": p.lever_fit,
               "health": health_lines(counters, fwd.sources),
               "solution_point": point,
               "heading_aiding": ({"source": reference_mod.FILE_NAME, "epochs": int(len(p.attitude)),
                                   "interval_s": HEADING_AIDING_INTERVAL_S} if p.attitude is not None else None),
               "outages": {"spec": p.spec.text() if p.spec is not None else None, "schedule": p.schedule.tolist(),
                           "gnss_first_t": inp.gnss_span[0], "gnss_last_t": inp.gnss_span[1],
                           "fixes_removed": int(p.fix_out.sum()),
                           "pseudoranges_removed": int(p.prs_removed)},
               "scoring": scoring}
    if reference_system:
        summary["reference_system"] = reference_system
    if run.heading_search is not None:
        summary["heading_search"] = run.heading_search
    if estimator is not None:
        summary["estimator"] = estimator
    if mode == "ins":
        summary["ins"] = {"aiding_until_t": free_from, "fixes_used": int(len(p.fixes)),
                          "how": "loose filter fed the fixes up to the one that completed the initialisation "
                                 "(heading known); zero-velocity and zero-rate updates off"}
    if fwd.time_offset is not None:
        # The residual the filter found on top of the declared offset (a data set's [imu] time_offset_s).
        summary["time_offset"] = {"estimate_s": fwd.time_offset[0], "sigma_s": fwd.time_offset[1],
                                  "applied_s": info.get("imu_time_offset_s"),  # None: not a data set
                                  "how": "the IMU stamps lag GNSS time by estimate_s after applied_s: add it to "
                                         "[imu] time_offset_s (final epoch of the forward pass)"}
    if smoothed is not None:
        summary["smoothed"] = smoothed
    # What made this result: enough to make it again.
    summary["provenance"] = {"gpsins": __version__, "command": shlex.join(["gpsins", *sys.argv[1:]])
                             if Path(sys.argv[0]).name in ("gpsins", "__main__.py", "cli.py") else None,
                             "config_sha256": hashlib.sha256(config_text.encode()).hexdigest(),
                             "source": str(p.source),
                             "simulation": (inp.truth[1].get("simulation") if inp.truth is not None else None)}
    if "stretch" in info:  # one of the stretches a receiver restart split the session into
        summary["stretch"] = info.pop("stretch")
    if "doctor" in info:  # what the data-set doctor measured
        summary["doctor"] = info.pop("doctor")
    if info:
        summary["dataset"] = info
    return summary

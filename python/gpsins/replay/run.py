"""Replay a logger session or a data set through the filter.

session directory -> decoded measurements -> time alignment -> filter -> results directory;
data-set TOML (``gpsins.dataset``) -> decoded files -> filter -> the same results directory:

- ``solution.parquet`` (per epoch), ``updates.parquet`` (per update), ``results.npz`` (the
  receiver's fixes, outages, scoring) and with ``--smooth`` ``smoothed.parquet``: the arrays of
  ``summary.RESULT_ARRAYS``, written chunk by chunk as the filter runs so that memory does not grow with
  the session (``results`` says why Parquet, ``results.load`` reads them all back);
- ``solution.pos``: RTKLIB-style positions (GPST, latitude, longitude, height,
  standard deviations), for RTKLIB's plot tools and comparisons;
- ``config.toml``: the exact filter configuration used;
- ``run.json``: counters, what was skipped and why, the alignment's summary,
  timings and summary statistics; with a reference (``--reference``, a data set's
  ``[scoring]``, or a session's simulated truth) the errors against it and, with
  ``--outages``, the per-outage drift (``outages.Score.summary``).

The filter runs in chunks of IMU samples (``nav.runs.ChunkedRun``); each chunk's epochs go through
``solution.Stream`` (derived columns, truth errors, .pos lines, running statistics) and are
dropped. ``--mode both`` decodes and aligns the session once for both filters (``load_inputs``,
then ``run_mode`` per mode). One mode's run is four steps: ``plan.plan`` (the configuration, the
outages removed, the noise and mounting taken from the data), ``forward.start`` and ``forward.forward``
(the filter's forward pass, written), ``forward.smooth`` (with ``--smooth``) and ``write.write``
(results.npz, config.toml, run.json).

What a data set gives the filter (each only where neither the data set's ``[filter]``
table nor ``--set`` names the key itself): ``lever_arm_body_m`` from ``[gnss] antenna_m``;
``imu_rate_hz`` from the median IMU interval (the core's gap bridging and standstill
window use it); ``imu_increments_cover_gaps`` for IMU rates (their increments cover every step);
``use_fix_velocity`` when the fixes carry velocities and ``fix_velocity_sigma_mps`` from their
stated sigmas (``dataset.fixes.velocity_sigma``, for fixes that state none); ``fix_velocity_lag_s``
from ``[gnss] velocity_lag_s`` (``"measured"``: ``dataset.fixes.velocity_lag``, which run.json
reports for any data set whose fixes allow it); ``pseudorange_decimation`` so that the tight filter
uses about one epoch per second whatever the receiver's rate. Fix position and velocity sigmas
travel per fix in the fix table's sigma columns (``dataset.fixes.fix_table``). The mounting rotation
and the IMU time offset are applied by ``dataset.load.load``.

Modes: ``loose`` (fixes), ``tight`` (pseudoranges; fixes only start the filter and give
the heading) and ``ins``: free inertial navigation after the initialisation. ``ins`` is
the loose filter fed the fixes only up to the one at which the heading became known
(levelling, position and heading done), with zero-velocity and zero-rate updates off
for the whole run; everything after that fix is the IMU alone. Its drift is scored over
that whole free stretch as one outage.

Outages (``--outages``): every fix and pseudorange whose time falls in an outage is
removed before the filter sees anything.
"""

from __future__ import annotations

import errno
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from ..evaluate import outages as outages_mod
from ..nav import runs as flt
from . import results
from .forward import Output, forward, start
from .forward import smooth as smooth_pass
from .inputs import DEFAULT_GPS_LATENCY_S, DEFAULT_IMU_LATENCY_S, Inputs, load_stretches, stretch_dir
from .plan import MODES, lever_arm_body_m, plan
from .scoring import scoring_target
from .write import write


@dataclass
class ReplayResult:
    out: Path
    mode: str
    summary: dict
    stretches: list = field(default_factory=list)  # a restarted receiver's session: every stretch's result


def replay(source: str | Path, out: str | Path, *, mode: str = "loose", config=None, overrides: dict | None = None,
           timing_method: str = "robust", gps_latency_s: float = DEFAULT_GPS_LATENCY_S,
           imu_latency_s: float = DEFAULT_IMU_LATENCY_S, truth: bool = True,
           nav: str | Path | None = None, outages: str | outages_mod.OutageSpec | None = None,
           reference: str | Path | None = None, reference_q=(1,), point: str = "antenna",
           smooth: bool = False, covariance_every: int = 0, chunk_rows: int = flt.CHUNK_ROWS,
           aid_heading: bool = False, overlap: bool = True, force: bool = False,
           estimator: str | None = None, output_every: int = 1) -> ReplayResult:
    """Replay a session directory or a data-set TOML (see the module doc); ``outages``: FIRST:LENGTH:PERIOD[:END] (None:
    the data set's [scoring] schedule, if any; "none": no outage at all); ``reference``: an RTKLIB .pos (its
    ``reference_q`` epochs) at the antenna point; ``point``: the point solution.pos gives (antenna or imu); ``smooth``:
    also the fixed-interval smoother (smoothed.parquet, smoothed.pos, run.json "smoothed"); ``covariance_every``: also
    the full covariance of every so many epochs (covariance.parquet); ``output_every``: the solution (and its scoring)
    at every so many IMU samples only (200 at 200 Hz: a 1 Hz .pos); ``chunk_rows``: IMU samples per filter call (memory,
    not results); ``overlap``: the filter's next chunk runs on a second thread while this one is scored and written
    (results unchanged; off for one run per core, as Monte Carlo workers are). A session whose receiver restarted (GPS
    time going back) is replayed stretch by stretch into ``out/stretch-N``: the result is the first stretch's, with
    every stretch's in ``stretches``."""
    if mode not in MODES:
        raise ValueError(f"--mode {mode!r}: one of {', '.join(MODES)}")
    stretches = load_stretches(source, modes=(mode,), config=config, overrides=overrides,
                               timing_method=timing_method, gps_latency_s=gps_latency_s,
                               imu_latency_s=imu_latency_s, truth=truth, nav=nav, force=force)
    results = [run_mode(inp, Path(out) / stretch_dir(j, len(stretches)), mode=mode, overrides=overrides,
                        outages=outages, reference=reference, reference_q=reference_q, point=point, smooth=smooth,
                        covariance_every=covariance_every, chunk_rows=chunk_rows, aid_heading=aid_heading,
                        overlap=overlap, estimator=estimator, output_every=output_every)
               for j, inp in enumerate(stretches)]
    results[0].stretches = results
    return results[0]


RESULT_FILES = (results.SOLUTION, results.SMOOTHED, results.UPDATES, results.COVARIANCE, results.SMALL,
                "solution.pos", "smoothed.pos", "config.toml", "run.json")


def run_mode(inp: Inputs, out: str | Path, **options) -> ReplayResult:
    """One filter mode over decoded inputs (``load_inputs``), written to ``out`` (see ``_run_mode``). A run
    that fails leaves no partial results behind: the files it writes are removed (the directory too,
    if it made it and it is left empty); a full disk is said so, naming the results directory."""
    out = Path(out)
    made = not out.exists()
    try:
        return _run_mode(inp, out, **options)
    except BaseException as e:
        for name in RESULT_FILES:
            (out / name).unlink(missing_ok=True)
        if made and out.is_dir() and not any(out.iterdir()):
            out.rmdir()
        if isinstance(e, OSError) and e.errno == errno.ENOSPC:
            raise OSError(e.errno, "no space left on the device for the results (the partial ones are removed)",
                          str(out)) from None
        raise


def _run_mode(inp: Inputs, out: Path, *, mode: str = "loose", overrides: dict | None = None,
             outages: str | outages_mod.OutageSpec | None = None, reference: str | Path | None = None,
             reference_q=(1,), point: str = "antenna", smooth: bool = False, covariance_every: int = 0,
             chunk_rows: int = flt.CHUNK_ROWS, aid_heading: bool = False, last_use: bool = False,
             overlap: bool = True, estimator=None, output_every: int = 1) -> ReplayResult:
    """One filter mode over decoded inputs (``load_inputs``), written to ``out`` (see ``replay``);
    ``estimator``: a plug-in estimator, or its ``package.module:name``, run in the built-in filter's
    place (``gpsins.nav.estimator``), scored and written the same way;
    ``aid_heading``: the session's reference system's dual-antenna heading and pitch (``reference.csv``)
    aid the filter (then it no longer scores the attitude independently); ``last_use``: no later call
    uses ``inp``, so its IMU samples and pseudoranges are let go once the filter has run, before the
    scoring (a day's: 240 MB)."""
    p = plan(inp, mode=mode, overrides=overrides, outages=outages, point=point, smooth=smooth,
             aid_heading=aid_heading, estimator=estimator)
    run, free_from, estimator = start(inp, p, chunk_rows=chunk_rows, overlap=overlap, smooth=smooth,
                                      estimator=estimator, output_every=output_every)
    target = scoring_target(inp, p.ref_system, reference, reference_q)
    lever = lever_arm_body_m(p.cfg)
    output = Output(Path(out), inp, target, lever, point, covariance_every,
                    f"mode {mode}, {inp.kind} {p.source.name}, {point} point")
    fwd = forward(run, output, p)
    if last_use:
        run.release_inputs()
        inp.imu = inp.pseudoranges = p.prs = p.tight = None
    score_sched = p.schedule
    if mode == "ins":  # the whole free stretch is one outage
        score_sched = np.array([[free_from, max(fwd.stream.last_t, free_from) + 1e-6]])
    smoothed = smooth_pass(run, output, target, score_sched, p) if smooth else None
    summary = write(output.out, inp, p, run, fwd, target, score_sched, point=point, lever=lever,
                    free_from=free_from, smoothed=smoothed, estimator=estimator)
    return ReplayResult(output.out, mode, summary)

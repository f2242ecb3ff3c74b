"""Live navigation beside the logger (``gpsins live SESSION_DIR --out DIR``).

A separate process follows the session the logger is writing, read only. Every ``--interval`` (0.02 s)
it looks at the record files' sizes; when GPS records have landed it reads only the bytes added since
(``session.growing``: parts as they rotate, damaged records skipped as replay skips them), times the new IMU
samples by the last clock fit extended along the IMU's frame counter (the robust alignment, fitted again
on everything when the data grew by ``REFIT_S`` or ``REFIT_SHARE``, after a round's outputs, or at once
for a gap the counter cannot count; samples wait for a fit that agrees with the one before, and when a fit
moves what was fed (over 1 ms; 10 us in its first 20 000 samples), a new filter is fed it all again:
``refeeds`` in the status), feeds the samples, fixes and pseudoranges up to the newest fix to the
streaming filter (the C++ core, as a replay's chunks are fed), and writes:

- NMEA 0183 GGA, RMC and GST of every output epoch (or every ``nmea_every``-th) to the clients of a TCP
  port on the loopback interface (``--nmea-port``), for gpsd, QGIS or OpenCPN: first, as soon as a fix is in;
- ``live.pos``: the solution at the IMU point, RTKLIB-style, growing (flushed each round);
- ``live.f64``: the same epochs at full precision, rows of EPOCH_COLUMNS float64 (``read_epochs``);
- ``status.jsonl``: one JSON line per round: the last epoch's time, position, attitude, their sigmas,
  the GNSS state, the filter's counters, the alignment's warnings.

``--http-port`` serves a status page (``live.page``); ``run_root`` follows the newest session under a
logger's root and moves on when the logger starts another (a restart). A u-blox session is decoded and
aligned whole each round (the incremental reader is the Superstar II's). Against a replay of the
finished session: samples fed during the drive were timed by the fit of their time, which the rest of the
session refines (the fit is one line over the session), so the two solutions agree to a fraction of a
millimetre at real time, not bit for bit; ``tests/test_live_follower.py``, ``tests/test_live.py`` and
``benchmarks/bench_live.py`` measure it.
"""

from __future__ import annotations

import json
import math
import time
from pathlib import Path

import numpy as np

from .. import evaluate
from ..nav import runs as flt
from ..formats import gpstime
from ..formats import nmea
from ..replay import results, solution
from .outputs import NmeaServer, nis_per_source
from .follower import Follower


POLL_S = 0.02  # the default period of the rounds: the record files' sizes polled (a stat each)
STOP_CHECK_S = 1.0  # how often ``stop_when`` (a newer session under the root?) is asked


def run(session: str | Path, out: str | Path, *, mode: str = "loose", config=None, overrides=None,
        nmea_port: int | None = None, nmea_every: int = 1, http_port: int | None = None, interval_s: float = POLL_S,
        gps_latency_s: float = 0.0, imu_latency_s: float = 0.0, hold_s: float = 0.0, until_finished: bool = True,
        max_s: float | None = None, on_round=None, on_start=None, stop_when=None) -> dict:
    """Follow the session until the logger stops it (or ``max_s``, or ``stop_when()`` is true: a newer
    session under a root); returns the last status. ``on_start`` gets {"nmea_port", "http_port"} once
    they listen; ``on_round`` each round's status."""
    from scipy.stats import chi2  # noqa: F401 (the status's NIS bands: imported now, not in the first round)

    session, out = Path(session), Path(out)
    if out.resolve() == session.resolve() or session.resolve() in out.resolve().parents:
        raise ValueError(f"{out}: live never writes into the session directory; give another --out")
    out.mkdir(parents=True, exist_ok=True)
    fol = Follower(session, mode=mode, config=config, overrides=overrides, gps_latency_s=gps_latency_s,
                   imu_latency_s=imu_latency_s, hold_s=hold_s)
    server = NmeaServer(nmea_port) if nmea_port is not None else None
    page = None
    if http_port is not None:
        from .page import StatusPage

        page = StatusPage(http_port)
    if on_start is not None:
        on_start({"nmea_port": server.port if server else None, "http_port": page.port if page else None})
    pos = None
    status: dict = {}
    t0 = next_stop_check = time.monotonic()
    try:
        with open(out / "status.jsonl", "w", encoding="utf-8") as status_file, open(out / "live.f64", "wb") as table:
            while True:
                finished = until_finished and fol.finished()
                sol = fol.poll(final=finished)
                if sol is not None:
                    a = solution.epoch_arrays(sol)
                    if server is not None:  # first: what a client waits for
                        _send_nmea(server, fol, sol, a, nmea_every)
                    if pos is None:
                        pos = solution.PosWriter(out / "live.pos", fol.week, f"gpsins live, mode {mode}, IMU point")
                    pos.add(sol.t, a["llh"], a["sigma_ned_m"], np.zeros(len(sol.t), int))
                    pos.flush()
                    table.write(np.column_stack([sol.t, sol.r_ecef, sol.v_ecef, sol.q_eb, a["sigma_ned_m"]])
                                .astype("<f8").tobytes())
                    table.flush()
                    status = json.loads(results.json_text(_status(fol, sol, a), indent=None))
                    status_file.write(json.dumps(status) + "\n")
                    status_file.flush()
                    if page is not None:
                        page.update(status, sol.r_ecef, evaluate.c_en(a["llh"][:1, 0], a["llh"][:1, 1])[0].T)
                    if on_round is not None:
                        on_round(status)
                elif finished:
                    break
                if fol.fed:
                    fol.maintain()  # right after feeding a fix: the next one is the furthest away
                if max_s is not None and time.monotonic() - t0 > max_s:
                    break
                if stop_when is not None and time.monotonic() >= next_stop_check:
                    next_stop_check = time.monotonic() + STOP_CHECK_S
                    if stop_when():
                        break
                if not finished:
                    time.sleep(interval_s)
    finally:
        if pos is not None:
            pos.close()
        if server is not None:
            server.close()
        if page is not None:
            page.close()
    return status


def newest_session(root: Path) -> Path | None:
    """The newest session directory under a logger's root (by its sidecar's start time)."""
    best, best_t = None, -math.inf
    for side in Path(root).glob("*/session.json"):
        try:
            start = json.loads(side.read_text(encoding="utf-8")).get("start", {})
        except (OSError, ValueError):
            continue
        t = start.get("realtime", side.stat().st_mtime) if isinstance(start, dict) else side.stat().st_mtime
        if t > best_t:
            best, best_t = side.parent, t
    return best


def run_root(root: str | Path, out: str | Path, *, max_s: float | None = None, interval_s: float = POLL_S,
             **options) -> list[Path]:
    """Follow the newest session under ``root``, and the next when the logger starts one (a restart):
    each into ``out/SESSION_NAME``. Until ``max_s`` (None: until stopped). Returns the sessions followed."""
    root, out = Path(root), Path(out)
    done: list[Path] = []
    t0 = time.monotonic()
    while max_s is None or time.monotonic() - t0 < max_s:
        current = newest_session(root)
        if current is None or current in done:
            time.sleep(max(interval_s, STOP_CHECK_S / 4))  # the root's sidecars read at most 4 times a second
            continue
        done.append(current)
        left = None if max_s is None else max(0.0, max_s - (time.monotonic() - t0))
        run(current, out / current.name, interval_s=interval_s, max_s=left,
            stop_when=lambda current=current: newest_session(root) not in (current, None), **options)
    return done


def _status(fol: Follower, sol: flt.Solution, a: dict) -> dict:
    k = -1
    return {"t": float(sol.t[k]), "week": fol.week, "llh_deg_m": [math.degrees(a["llh"][k, 0]),
                                                                  math.degrees(a["llh"][k, 1]), a["llh"][k, 2]],
            "r_ecef": a["r_ecef"][k], "ypr_deg": a["ypr_deg"][k], "sigma_ned_m": a["sigma_ned_m"][k],
            "sigma_ypr_deg": a["sigma_ypr_deg"][k], "heading_known": bool(sol.heading_known[k]),
            "imu_fed": fol.n_imu, "fixes_fed": fol.n_fix, "pseudoranges_fed": fol.n_pr, "refeeds": fol.refeeds,
            "clock_settled": fol.clock_settled,
            "counters": {c: fol.counters.get(c) for c in ("fixes_accepted", "fixes_rejected", "gnss_resets",
                                                          "imu_gap_restarts", "pseudoranges_used", "diverged")},
            "nis_per_dof": nis_per_source(sol.updates), "warnings": fol.warnings}


def _send_nmea(server: NmeaServer, fol: Follower, sol: flt.Solution, a: dict, every: int) -> None:
    base = fol.week * gpstime.SECONDS_PER_WEEK
    llh = a["llh"]
    c = evaluate.c_en(llh[:, 0], llh[:, 1])
    v_ned = np.einsum("nji,nj->ni", c, sol.v_ecef)
    lines = []
    for k in range(0, len(sol.t), max(1, every)):
        aided = bool(sol.heading_known[k])
        t = base + float(sol.t[k])
        lines += [nmea.gga(t, fol.leap_s, llh[k, 0], llh[k, 1], llh[k, 2], aided, 0, 1.0),
                  nmea.rmc(t, fol.leap_s, llh[k, 0], llh[k, 1], v_ned[k], aided),
                  nmea.gst(t, fol.leap_s, a["sigma_ned_m"][k])]
    server.send("".join(lines))

"""The ``gpsins`` command: one subcommand per job, each a thin layer over a module.

Expected failures (a missing or damaged file, a bad configuration key, data
that cannot be aligned) end in one line on stderr,
``gpsins CMD: <file or key>: <what, and what to do>``, and exit status 2;
``--debug`` shows the traceback instead.
"""

from __future__ import annotations

import argparse
import errno
import os
import sys

from . import __version__
from .errors import CommandError
from .commands import (cmd_allan, cmd_batch, cmd_calibrate, cmd_check, cmd_dataset_init, cmd_dump, cmd_emulate,
                       cmd_lab, cmd_live, cmd_montecarlo, cmd_replay, cmd_report, cmd_run, cmd_score, cmd_sim,
                       cmd_spp)


EXIT_USAGE = 2


def _montecarlo_options(p: argparse.ArgumentParser) -> None:
    """Options shared by ``montecarlo`` and ``sweep``."""
    p.add_argument("scenario", help="built-in scenario name (default, long, ...) or a TOML file")
    p.add_argument("--seeds", type=int, required=True, metavar="N", help="number of runs (seeds FIRST..FIRST+N-1)")
    p.add_argument("--first-seed", type=int, default=0, metavar="FIRST", help="first seed (default 0)")
    p.add_argument("--mode", choices=("loose", "tight", "both", "ins"), default="loose",
                   help="filter(s) each session is replayed through (default loose)")
    p.add_argument("--config", help="filter configuration: TOML file or preset name")
    p.add_argument("--set", action="append", metavar="KEY=VALUE", help="override one configuration key")
    p.add_argument("--outages", metavar="FIRST:LENGTH:PERIOD[:END]", help="simulated GNSS outages (as replay)")
    p.add_argument("--estimator", metavar="MODULE:NAME", help="a plug-in estimator in the built-in filter's place")
    p.add_argument("--out", help="output directory, new or empty (default out/montecarlo-SCENARIO)")
    p.add_argument("--scheduler", metavar="ADDRESS",
                   help="an existing Dask scheduler (tcp://host:port, or its scheduler file) instead of a local "
                        "cluster; its workers must see --out at the same path")
    p.add_argument("--workers", type=int, metavar="K", help="local cluster: worker processes (default: one per core)")
    p.add_argument("--grid", type=float, default=1.0, metavar="S",
                   help="common time grid of the aggregate NEES, NIS and errors, s (default 1)")
    p.add_argument("--keep", choices=("all", "results", "none"), default="all",
                   help="what stays in --out besides the tables: sessions and replay results (all, default), "
                        "replay results only, or none")
    p.add_argument("--quiet", action="store_true", help="no progress bar")
    p.set_defaults(func=cmd_montecarlo)


def build_parser() -> argparse.ArgumentParser:
    parser = argparse.ArgumentParser(prog="gpsins", description=__doc__)
    parser.add_argument("--version", action="version", version=f"gpsins {__version__}")
    parser.add_argument("--debug", action="store_true", help="show the traceback of a failure (anywhere on the line)")
    sub = parser.add_subparsers(dest="command", required=True, metavar="COMMAND")

    p = sub.add_parser("run", help="the main job on its built-in default")
    p.add_argument("--out", default="out", help="output directory (default: out)")
    p.add_argument("--scenario", default="default", help="built-in name or a TOML file")
    p.add_argument("--seed", type=int, default=0)
    p.add_argument("--speed", type=float, default=1.0, help="time scale of the emulated drive (4 = four times faster)")
    p.add_argument("--device", choices=("superstar2", "ublox"), default="superstar2",
                   help="GPS hardware: the report's Superstar II + BP3010, or an F9R-like u-blox with its own IMU")
    p.set_defaults(func=cmd_run)

    p = sub.add_parser("dump", help="summarise a session directory or a raw device capture")
    p.add_argument("path", help="session directory, or with --raw a capture file")
    p.add_argument("--raw", choices=("superstar2", "bp3010"), help="PATH is a raw byte stream of this device")
    p.add_argument("--csv", action="store_true", help="list every record as CSV on stdout")
    p.add_argument("--format", choices=("text", "json"), default="text")
    p.set_defaults(func=cmd_dump)

    p = sub.add_parser("sim", help="simulate a drive: truth + session files")
    p.add_argument("--scenario", default="default", help="built-in name or a TOML file (default: default)")
    p.add_argument("--out", required=True, help="session directory to create")
    p.add_argument("--seed", type=int, default=0)
    p.add_argument("--imu-rate", type=int, help="IMU rate in Hz instead of the scenario's (BP3010 frame layout)")
    p.add_argument("--dataset", action="store_true",
                   help="also write a data set (IMU CSV, receiver .pos, truth .pos, dataset.toml) in OUT/dataset")
    p.add_argument("--fix-rate", type=float, default=5.0,
                   help="the data set's fixes per second (default 5; the session's receiver keeps its own rate)")
    p.add_argument("--block-s", type=float, help="simulate and write in blocks of about this many seconds "
                   "(default 60; memory grows with the block, not the drive; the output is the same for any block)")
    p.set_defaults(func=cmd_sim)

    p = sub.add_parser("emulate", help="serve a scenario or a recorded session on pty serial devices")
    src = p.add_mutually_exclusive_group()
    src.add_argument("--scenario", default="default", help="built-in name or a TOML file")
    src.add_argument("--session", help="replay a recorded session directory instead (gpsfake-like)")
    p.add_argument("--seed", type=int, default=0)
    p.add_argument("--dir", default="dev", help="directory for the device links gps and imu (default: dev)")
    p.add_argument("--speed", type=float, default=1.0, help="time scale (2 = twice real time)")
    p.add_argument("--device", choices=("superstar2", "ublox"), default="superstar2", help="the GPS receiver")
    p.add_argument("--ubx", help="u-blox: serve this UBX capture at its own timing instead of a scenario")
    p.add_argument("--baud", type=int, default=460800, help="u-blox: line rate (default 460800)")
    p.add_argument("--bp3010", action="store_true", help="u-blox: no ESF-RAW; a BP3010 IMU at DIR/imu instead")
    p.add_argument("--config-fault", choices=("nak", "silent"), help="u-blox: refuse or ignore configuration")
    p.set_defaults(func=cmd_emulate)

    p = sub.add_parser("replay", help="replay a logger session or a data set through the filter")
    p.add_argument("session", help="session directory, or a data-set file (DATASET.toml)")
    p.add_argument("--out", required=True, help="results directory")
    p.add_argument("--mode", choices=("loose", "tight", "both", "ins"), default="loose",
                   help="loosely coupled (fixes), tightly coupled (pseudoranges), both, or ins: free inertial "
                        "navigation after the initialisation")
    p.add_argument("--outages", metavar="FIRST:LENGTH:PERIOD[:END]",
                   help="simulated GNSS outages, seconds from the first GNSS epoch (no GNSS inside them); "
                        "none: no outage, also where the data set's [scoring] schedules some")
    p.add_argument("--reference", metavar="FILE.pos",
                   help="reference trajectory (RTKLIB .pos) at the antenna point: errors and drift per outage")
    p.add_argument("--reference-q", type=int, nargs="+", default=[1], metavar="Q",
                   help="the reference's Q values that count (default: 1, fixed)")
    p.add_argument("--point", choices=("antenna", "imu"), default="antenna",
                   help="the point solution.pos gives (default: antenna)")
    p.add_argument("--smooth", action="store_true",
                   help="also smooth the run (fixed-interval, forward-backward): smoothed.parquet, smoothed.pos")
    p.add_argument("--aid-heading", action="store_true",
                   help="aid the filter with the session's dual-antenna heading and pitch (reference.csv), 1 Hz")
    p.add_argument("--covariance-every", type=int, default=0, metavar="N",
                   help="also write the full error-state covariance of every Nth epoch (covariance.parquet)")
    p.add_argument("--output-every", type=int, default=1, metavar="N",
                   help="the solution at every Nth IMU sample only (200 with a 200 Hz IMU: a 1 Hz .pos); the "
                        "scoring uses the epochs written")
    p.add_argument("--force", action="store_true",
                   help="replay a data set even where the data-set doctor finds the data at odds with it")
    p.add_argument("--estimator", metavar="MODULE:NAME",
                   help="run this plug-in estimator in the built-in filter's place (gpsins.nav.estimator documents "
                        "what it gets and returns), scored the same way")
    p.add_argument("--nav", help="RINEX 2 navigation file: ephemerides and Klobuchar when the log lacks them")
    p.add_argument("--config", help="filter configuration: TOML file or preset name (default, report2005)")
    p.add_argument("--set", action="append", metavar="KEY=VALUE",
                   help="override one configuration key (TABLE.KEY inside a table; --set help lists them)")
    p.add_argument("--timing", choices=("robust", "report"), default="robust", help="IMU time alignment method")
    p.add_argument("--gps-latency", type=float, default=0.0205, help="GPS epoch to ID 23 stamp, s (default 0.0205)")
    p.add_argument("--imu-latency", type=float, default=0.0005, help="IMU sample to stamp, s (default 0.0005)")
    p.add_argument("--no-truth", action="store_true", help="ignore a truth file next to the session")
    p.set_defaults(func=cmd_replay)

    p = sub.add_parser("report", help="figures and a summary page from replay results")
    p.add_argument("results", nargs="+", metavar="[NAME=]RESULTS",
                   help="results directories of gpsins replay --out or gpsins score (one per run, or one holding "
                        "its runs per mode and stretch), each named NAME on the figures and tables if given")
    p.add_argument("--out", help="report directory (default: RESULTS/report)")
    p.set_defaults(func=cmd_report)

    p = sub.add_parser("allan", help="Allan deviation, PSD and noise terms of IMU data")
    p.add_argument("source", help="session directory, or a CSV/NPY of rate samples (columns: axes)")
    p.add_argument("--rate", type=float, help="sample rate of a CSV/NPY file, Hz")
    p.add_argument("--taus", default="10", help="points per decade, or octave | decade | all (default 10)")
    p.add_argument("--json", help="write tau, deviations, bounds and fitted terms here")
    p.add_argument("--out", help="directory for plots and the filter parameter files (imu_noise.toml, imu.yaml)")
    p.add_argument("--columns", help="column kinds of a CSV/NPY file: gyro_x,...,accel_z, time or skip; a unit "
                                      "after a colon: accel_x:g, gyro_x:deg/s")
    p.add_argument("--start-s", type=float, help="analyse from this many seconds into the record")
    p.add_argument("--end-s", type=float, help="... up to this many seconds")
    p.add_argument("--estimator", choices=("overlapping", "non-overlapping"), default="overlapping")
    p.set_defaults(func=cmd_allan)

    p = sub.add_parser("lab", help="IMU lab workflow from a lab plan: calibration, noise, filter preset, report")
    p.add_argument("plan", nargs="?", help="lab plan TOML (sessions: up-down, rate table, drift run)")
    p.add_argument("--out", required=True, help="output directory")
    p.add_argument("--simulate", action="store_true", help="first simulate a BP3010 lab day (and its plan) in OUT")
    p.add_argument("--quick", action="store_true", help="with --simulate: a short day (about 40 min)")
    p.add_argument("--seed", type=int, default=0)
    p.add_argument("--speed", type=float, help="with --simulate: record through the pty emulators and the logger "
                                               "at this many times real time")
    p.set_defaults(func=cmd_lab)

    p = sub.add_parser("calibrate", help="deterministic calibration: accelerometer up-down, gyro rate table")
    p.add_argument("kind", choices=("accel-updown", "gyro-rate-table"))
    p.add_argument("table", help="CSV: up-down rows 'z_up,z_down' per axis; rate table rows 'table_rate,output'; "
                                 "for accel-updown also a session directory with the up and down positions")
    p.add_argument("--lat-deg", type=float, default=59.35, help="latitude of the test, deg (default 59.35)")
    p.add_argument("--height-m", type=float, default=30.0)
    p.add_argument("--axis-up", action="store_true", help="the gyro axis points up (Earth rate along it)")
    p.add_argument("--drift-bias", type=float, help="gyro bias from a drift test, rad/s (else fitted)")
    p.set_defaults(func=cmd_calibrate)

    p = sub.add_parser("dataset", help="data sets: `dataset init IMU_FILE GNSS_FILE` writes a first data-set TOML")
    dsub = p.add_subparsers(dest="dataset_command", required=True)
    q = dsub.add_parser("init", help="a commented data-set TOML with what the files show, guesses marked")
    q.add_argument("imu_file", help="IMU text table (CSV or whitespace: a time column and six axes)")
    q.add_argument("gnss_file", help="RTKLIB .pos, a UBX stream or a RINEX observation file")
    q.add_argument("--out", default="dataset.toml", help="the data-set file to write (default dataset.toml)")
    q.add_argument("--force", action="store_true", help="replace the file if it exists")
    q.set_defaults(func=cmd_dataset_init)

    p = sub.add_parser("batch", help="two configurations or estimators over many recordings, paired, on Dask")
    p.add_argument("sources", nargs="+", help="directories searched for sessions and data sets, lists, or files")
    p.add_argument("--config", action="append", default=[], metavar="CONFIG",
                   help="arm A's configuration (preset or TOML); given twice, arm B's too")
    p.add_argument("--estimator", metavar="MODULE:NAME", help="arm B: this plug-in estimator")
    p.add_argument("--mode", choices=("loose", "tight"), default="loose")
    p.add_argument("--outages", metavar="FIRST:LENGTH:PERIOD[:END]", help="outages for every recording")
    p.add_argument("--scheduler", help="a running Dask scheduler (address or scheduler file); default: local")
    p.add_argument("--workers", type=int, help="local cluster workers (default: one per core)")
    p.add_argument("--out", required=True, help="output directory: batch.csv, paired.json, paired.png, the runs")
    p.set_defaults(func=cmd_batch)

    p = sub.add_parser("live", help="navigate live beside the logger: follow a session as it is written")
    p.add_argument("session", help="the session directory the logger is writing (read only); with --follow-root "
                   "the logger's root of sessions")
    p.add_argument("--follow-root", action="store_true",
                   help="SESSION is the logger's root: follow its newest session, and the next when the logger "
                        "starts one; each into OUT/SESSION_NAME")
    p.add_argument("--http-port", type=int, metavar="PORT",
                   help="serve the status page on this port of the loopback interface (0: any free)")
    p.add_argument("--out", required=True, help="output directory: live.pos, live.f64, status.jsonl")
    p.add_argument("--mode", choices=("loose", "tight"), default="loose")
    p.add_argument("--config", help="filter configuration: TOML file or preset name")
    p.add_argument("--set", action="append", metavar="KEY=VALUE", help="override one configuration key")
    p.add_argument("--nmea-port", type=int, metavar="PORT",
                   help="serve NMEA GGA, RMC, GST on this TCP port of the loopback interface (0: any free)")
    p.add_argument("--nmea-every", type=int, default=1, metavar="N", help="one sentence set every N epochs")
    p.add_argument("--interval", type=float, default=0.02, metavar="S",
                   help="seconds between looks at the record files (default 0.02): a round decodes and feeds what "
                        "came since the last")
    p.add_argument("--gps-latency", type=float, default=0.0, help="as replay's")
    p.add_argument("--imu-latency", type=float, default=0.0, help="as replay's")
    p.set_defaults(func=cmd_live)

    p = sub.add_parser("score", help="score a solution computed elsewhere against a session or data set")
    p.add_argument("solution", help="RTKLIB .pos or KF-GINS navigation result")
    p.add_argument("--against", required=True, help="session directory or data-set TOML: truth, reference, outages")
    p.add_argument("--out", required=True, help="results directory (as gpsins replay --out: gpsins report reads it)")
    p.add_argument("--format", choices=("pos", "kf-gins", "csv"), help="the solution's format (default: by its "
                   "suffix; csv with --columns)")
    p.add_argument("--columns", help="a CSV's columns, e.g. t,lat_deg,lon_deg,h_m,vn,ve,vd,roll_deg,pitch_deg,"
                   "yaw_deg or t,x,y,z,vx,vy,vz,qw,qx,qy,qz ('-' skips one)")
    p.add_argument("--time", default="gps_abs", choices=("gps_abs", "gpst_unix", "utc_unix", "gps_sow"),
                   help="a CSV's time scale (default gps_abs: GPS seconds since 1980-01-06)")
    p.add_argument("--week", type=int, help="the GPS week of a CSV's seconds of week")
    p.add_argument("--point", choices=("antenna", "imu"),
                   help="where the solution is (default: antenna for a .pos, imu otherwise)")
    p.add_argument("--outages", metavar="FIRST:LENGTH:PERIOD[:END]", help="the outages to score the drift over")
    p.add_argument("--reference", help="reference trajectory (RTKLIB .pos) at the antenna point")
    p.add_argument("--reference-q", type=int, nargs="+", default=[1], metavar="Q")
    p.set_defaults(func=cmd_score)

    p = sub.add_parser("check", help="the data-set doctor: the data against what the data set declares")
    p.add_argument("dataset", help="data-set TOML")
    p.add_argument("--mode", choices=("loose", "tight", "both", "ins"), default="loose",
                   help="the filter mode to check the content for (default loose)")
    p.set_defaults(func=cmd_check)

    p = sub.add_parser("spp", help="single-point positioning from pseudoranges (session, raw capture or RINEX)")
    p.add_argument("session", nargs="?", help="session directory")
    p.add_argument("--raw", help="a raw Superstar II byte stream or .raw capture")
    p.add_argument("--rinex", help="RINEX 2 observation file (with --nav)")
    p.add_argument("--nav", help="RINEX 2 navigation file (ephemerides, Klobuchar)")
    p.add_argument("--out", help="write an RTKLIB-style .pos file")
    p.add_argument("--ecef", action="store_true", help=".pos in ECEF instead of latitude, longitude, height")
    p.add_argument("--mask-deg", type=float, default=15.0, help="elevation mask (default 15)")
    p.add_argument("--no-iono", action="store_true")
    p.add_argument("--no-trop", action="store_true")
    p.set_defaults(func=cmd_spp)

    p = sub.add_parser("montecarlo", help="Monte Carlo: simulate + replay per seed as Dask tasks, aggregate NEES/NIS")
    _montecarlo_options(p)
    p.add_argument("--sweep", metavar="KEY=v1,v2,...", help="also sweep a configuration key over these values")

    p = sub.add_parser("sweep", help="parameter sweep: a configuration key over values, each a Monte Carlo")
    _montecarlo_options(p)
    p.add_argument("--key", required=True, help="configuration key (TABLE.KEY inside a table)")
    p.add_argument("--values", required=True, metavar="v1,v2,...", help="TOML values, comma-separated")

    sub.add_parser("log", help="run the logger daemon (same as gpsins-logger; gpsins log --help)", add_help=False)
    return parser


def _subject(args: argparse.Namespace) -> str | None:
    """The file a command works on, to name it in a message that does not."""
    for key in ("session", "path", "source", "table", "raw", "rinex"):
        value = getattr(args, key, None)
        if value:
            return str(value)
    results = getattr(args, "results", None)
    return str(results[0]) if results else None


_HINTS = {
    errno.ENOENT: "no such file or directory; check the path",
    errno.ENOTDIR: "not a directory; give the session directory, not a file in it",
    errno.EISDIR: "is a directory; give a file",
    errno.EACCES: "permission denied",
    errno.ENOSPC: "no space left on the device",
}


def _message(e: BaseException, args: argparse.Namespace) -> str:
    """One line naming the file or key, from an exception raised for bad input."""
    if isinstance(e, OSError) and e.filename is not None:
        text = f"{e.filename}: {_HINTS.get(e.errno, e.strerror or str(e))}"
    elif isinstance(e, OSError):
        text = e.strerror or str(e)
    else:
        text = str(e) or type(e).__name__
    from .timing import AlignmentError

    subject = _subject(args)
    names_a_file = isinstance(e, OSError) and e.filename is not None
    if subject and subject not in text and not names_a_file and not isinstance(e, CommandError) \
            and not _is_config_error(e):
        text = f"{subject}: {text}"
    if isinstance(e, AlignmentError):
        text += " (the GPS and IMU stamps cannot be mapped to GPS time; `gpsins dump` shows what the session holds)"
    return " ".join(text.split())


def _is_config_error(e: BaseException) -> bool:
    from .nav.config import ConfigError

    return isinstance(e, ConfigError)


def _run_logger(argv: list[str]) -> int:
    """``gpsins log ...``: the logger daemon's own command line, unchanged."""
    from gpsins_logger import daemon

    return daemon.main(argv)


def _quiet_broken_pipe() -> None:
    """The reader of our stdout went away (``| head``): stop without a traceback."""
    try:
        devnull = os.open(os.devnull, os.O_WRONLY)
        os.dup2(devnull, sys.stdout.fileno())
    except (OSError, ValueError):
        pass


def main(argv: list[str] | None = None) -> int:
    argv = list(sys.argv[1:] if argv is None else argv)
    if argv[:2] == ["--debug", "log"]:
        argv = argv[1:]  # the logger reports its own errors
    if argv[:1] == ["log"]:
        return _run_logger(argv[1:])
    debug = "--debug" in argv  # accepted anywhere on the line
    args = build_parser().parse_args([a for a in argv if a != "--debug"])
    try:
        return int(args.func(args) or 0)
    except BrokenPipeError:
        _quiet_broken_pipe()
        return 0
    except KeyboardInterrupt:
        print(f"gpsins {args.command}: interrupted", file=sys.stderr)
        return 130
    except (ValueError, OSError) as e:  # LogError, AlignmentError, ConfigError, ... are ValueErrors
        if debug:
            raise
        print(f"gpsins {args.command}: {_message(e, args)}", file=sys.stderr)
        return EXIT_USAGE


if __name__ == "__main__":
    sys.exit(main())

"""The ``gpsins`` command: one subcommand per job, each a thin layer over a module."""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

from . import __version__


def _cmd_log(args: argparse.Namespace) -> int:
    from gpsins_logger import daemon

    return daemon.main(args.logger_args)


def _cmd_run(args: argparse.Namespace) -> int:
    from . import mainjob

    return mainjob.run(args)


def _cmd_dump(args: argparse.Namespace) -> int:
    from . import dump

    return dump.main(args)


def _cmd_sim(args: argparse.Namespace) -> int:
    from .sim import cli as sim_cli

    return sim_cli.run_sim(args)


def _cmd_emulate(args: argparse.Namespace) -> int:
    from .sim import cli as sim_cli

    return sim_cli.run_emulate(args)


def _overrides(pairs: list[str]) -> dict:
    """--set key=value (value parsed as TOML: numbers, booleans, lists, strings)."""
    import tomllib

    out = {}
    for item in pairs or []:
        key, sep, value = item.partition("=")
        if not sep:
            raise SystemExit(f"gpsins: --set expects key=value, got '{item}'")
        try:
            out[key.strip()] = tomllib.loads(f"v = {value}")["v"]
        except tomllib.TOMLDecodeError:
            out[key.strip()] = value
    return out


def _cmd_replay(args: argparse.Namespace) -> int:
    from . import replay

    modes = ["loose", "tight"] if args.mode == "both" else [args.mode]
    for mode in modes:
        res = replay.replay(args.session, Path(args.out) / mode if len(modes) > 1 else args.out, mode=mode,
                            config=args.config, overrides=_overrides(args.set), timing_method=args.timing,
                            gps_latency_s=args.gps_latency, imu_latency_s=args.imu_latency, truth=not args.no_truth,
                            nav=args.nav)
        c = res.summary["counters"]
        print(f"{mode}: {res.summary['imu_samples']} IMU samples, {c['fixes_accepted']} fixes used, "
              f"{c['updates_rejected']} updates rejected; results in {res.out}")
        if res.summary["skipped"]:
            print("  skipped: " + "; ".join(f"{k}: {v}" for k, v in res.summary["skipped"].items()))
        e = res.summary["errors"]
        if e:
            print(f"  vs truth: horizontal RMS {e['horizontal_rms_m']:.2f} m, vertical RMS {e['vertical_rms_m']:.2f} m")
    return 0


def _cmd_report(args: argparse.Namespace) -> int:
    from . import report

    page = report.make_report(args.results, args.out or Path(args.results[0]) / "report")
    print(report.comparison_table(args.results))
    print(f"report: {page}")
    return 0


def _cmd_allan(args: argparse.Namespace) -> int:
    from .imu import cli as imu_cli

    return imu_cli.run_allan(args)


def _cmd_calibrate(args: argparse.Namespace) -> int:
    from .imu import cli as imu_cli

    return imu_cli.run_calibrate(args)


def _cmd_lab(args: argparse.Namespace) -> int:
    from .imu import cli as imu_cli

    return imu_cli.run_lab(args)


def _cmd_spp(args: argparse.Namespace) -> int:
    from . import spp

    return spp.main(args)


def build_parser() -> argparse.ArgumentParser:
    parser = argparse.ArgumentParser(prog="gpsins", description=__doc__)
    parser.add_argument("--version", action="version", version=f"gpsins {__version__}")
    sub = parser.add_subparsers(dest="command", required=True, metavar="COMMAND")

    p = sub.add_parser("run", help="the main job on its built-in default")
    p.add_argument("--out", default="out", help="output directory (default: out)")
    p.add_argument("--scenario", default="default", help="built-in name or a TOML file")
    p.add_argument("--seed", type=int, default=0)
    p.add_argument("--speed", type=float, default=1.0, help="time scale of the emulated drive (4 = four times faster)")
    p.set_defaults(func=_cmd_run)

    p = sub.add_parser("dump", help="summarise a session directory or a raw device capture")
    p.add_argument("path", help="session directory, or with --raw a capture file")
    p.add_argument("--raw", choices=("superstar2", "bp3010"), help="PATH is a raw byte stream of this device")
    p.add_argument("--csv", action="store_true", help="list every record as CSV on stdout")
    p.add_argument("--format", choices=("text", "json"), default="text")
    p.set_defaults(func=_cmd_dump)

    p = sub.add_parser("sim", help="simulate a drive: truth + session files")
    p.add_argument("--scenario", default="default", help="built-in name or a TOML file (default: default)")
    p.add_argument("--out", required=True, help="session directory to create")
    p.add_argument("--seed", type=int, default=0)
    p.set_defaults(func=_cmd_sim)

    p = sub.add_parser("emulate", help="serve a scenario or a recorded session on pty serial devices")
    src = p.add_mutually_exclusive_group()
    src.add_argument("--scenario", default="default", help="built-in name or a TOML file")
    src.add_argument("--session", help="replay a recorded session directory instead (gpsfake-like)")
    p.add_argument("--seed", type=int, default=0)
    p.add_argument("--dir", default="dev", help="directory for the device links gps and imu (default: dev)")
    p.add_argument("--speed", type=float, default=1.0, help="time scale (2 = twice real time)")
    p.set_defaults(func=_cmd_emulate)

    p = sub.add_parser("replay", help="replay a logger session through the filter")
    p.add_argument("session", help="session directory")
    p.add_argument("--out", required=True, help="results directory")
    p.add_argument("--mode", choices=("loose", "tight", "both"), default="loose",
                   help="loosely coupled (receiver fixes), tightly coupled (pseudoranges) or both")
    p.add_argument("--nav", help="RINEX 2 navigation file: ephemerides and Klobuchar when the log lacks them")
    p.add_argument("--config", help="filter configuration: TOML file or preset name (default, report2005)")
    p.add_argument("--set", action="append", metavar="KEY=VALUE", help="override one configuration key")
    p.add_argument("--timing", choices=("robust", "report"), default="robust", help="IMU time alignment method")
    p.add_argument("--gps-latency", type=float, default=0.0205, help="GPS epoch to ID 23 stamp, s (default 0.0205)")
    p.add_argument("--imu-latency", type=float, default=0.0005, help="IMU sample to stamp, s (default 0.0005)")
    p.add_argument("--no-truth", action="store_true", help="ignore a truth file next to the session")
    p.set_defaults(func=_cmd_replay)

    p = sub.add_parser("report", help="figures and a summary page from replay results")
    p.add_argument("results", nargs="+", help="one results directory per filter run")
    p.add_argument("--out", help="report directory (default: RESULTS/report)")
    p.set_defaults(func=_cmd_report)

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
    p.set_defaults(func=_cmd_allan)

    p = sub.add_parser("lab", help="IMU lab workflow from a lab plan: calibration, noise, filter preset, report")
    p.add_argument("plan", nargs="?", help="lab plan TOML (sessions: up-down, rate table, drift run)")
    p.add_argument("--out", required=True, help="output directory")
    p.add_argument("--simulate", action="store_true", help="first simulate a BP3010 lab day (and its plan) in OUT")
    p.add_argument("--quick", action="store_true", help="with --simulate: a short day (about 40 min)")
    p.add_argument("--seed", type=int, default=0)
    p.add_argument("--speed", type=float, help="with --simulate: record through the pty emulators and the logger "
                                               "at this many times real time")
    p.set_defaults(func=_cmd_lab)

    p = sub.add_parser("calibrate", help="deterministic calibration: accelerometer up-down, gyro rate table")
    p.add_argument("kind", choices=("accel-updown", "gyro-rate-table"))
    p.add_argument("table", help="CSV: up-down rows 'z_up,z_down' per axis; rate table rows 'table_rate,output'; "
                                 "for accel-updown also a session directory with the up and down positions")
    p.add_argument("--lat-deg", type=float, default=59.35, help="latitude of the test, deg (default 59.35)")
    p.add_argument("--height-m", type=float, default=30.0)
    p.add_argument("--axis-up", action="store_true", help="the gyro axis points up (Earth rate along it)")
    p.add_argument("--drift-bias", type=float, help="gyro bias from a drift test, rad/s (else fitted)")
    p.set_defaults(func=_cmd_calibrate)

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
    p.set_defaults(func=_cmd_spp)

    p = sub.add_parser("log", help="run the logger daemon (same as gpsins-logger)", add_help=False)
    p.add_argument("logger_args", nargs=argparse.REMAINDER)
    p.set_defaults(func=_cmd_log)
    return parser


def main(argv: list[str] | None = None) -> int:
    args = build_parser().parse_args(argv)
    return int(args.func(args) or 0)


if __name__ == "__main__":
    sys.exit(main())

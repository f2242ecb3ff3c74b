"""The ``gpsins`` subcommands, one function each (``cli`` parses the command line and calls them): each
checks its arguments, raising ``errors.CommandError`` with the line to print, then runs its module.
"""

from __future__ import annotations

import argparse
import os
from pathlib import Path

from .errors import CommandError


def _session_dir(path: str) -> str:
    """A session argument that is at least a directory (the readers say what is wrong inside it)."""
    p = Path(path)
    if not p.exists():
        raise CommandError(f"{path}: no such directory; give a session directory (written by gpsins log or gpsins sim)")
    if not p.is_dir():
        raise CommandError(f"{path}: is a file; give the session directory that holds session.json and the .bin files")
    return path


def cmd_run(args: argparse.Namespace) -> int:
    from . import mainjob

    return mainjob.run(args)


def cmd_dump(args: argparse.Namespace) -> int:
    from .session import dump

    if not args.raw:
        _session_dir(args.path)
    return dump.main(args)


def cmd_sim(args: argparse.Namespace) -> int:
    from .sim import cli as sim_cli

    return sim_cli.run_sim(args)


def cmd_emulate(args: argparse.Namespace) -> int:
    from .devices import cli as devices_cli

    if getattr(args, "device", "superstar2") == "ublox":
        from .devices import ublox as ublox_emulate

        return ublox_emulate.run_ublox(args)
    return devices_cli.run_emulate(args)


def cmd_replay(args: argparse.Namespace) -> int:
    from .replay import inputs as replay_inputs
    from .nav import config as nav_config

    if args.set and "help" in args.set:
        if replay_inputs.is_dataset(args.session) and Path(args.session).is_file():
            # The values a replay of this data set starts from: its [filter] table (or --config) and
            # what it takes from its data; the noise fit, where on, scales the noise at the run.
            inp = replay_inputs.load_inputs(args.session, config=args.config, force=True)
            print(nav_config.describe_keys(inp.base_config, inp.data_config,
                                           f"values for {args.session}: its [filter] table and, from its data, "
                                           f"{', '.join(sorted(inp.data_config)) or 'nothing'}"))
        else:
            print(nav_config.describe_keys(args.config))
        return 0
    overrides = nav_config.parse_overrides(args.set or [])
    nav_config.load_config(args.config, overrides)  # a bad key or value fails here, before any decoding
    if replay_inputs.is_dataset(args.session):
        if not Path(args.session).is_file():
            raise CommandError(f"{args.session}: no such data-set file")
    else:
        _session_dir(args.session)
    if args.outages:
        from .evaluate import outages

        if not outages.is_none(args.outages):
            outages.parse(args.outages)
    if args.reference and not Path(args.reference).is_file():
        raise CommandError(f"{args.reference}: no such reference file (--reference takes an RTKLIB .pos)")

    from . import memory

    memory.map_large_arrays()  # a day-long replay: freed whole-run arrays go back to the system
    modes = ["loose", "tight"] if args.mode == "both" else [args.mode]
    stretches = replay_inputs.load_stretches(args.session, modes=modes, config=args.config, overrides=overrides,
                                             timing_method=args.timing, gps_latency_s=args.gps_latency,
                                             imu_latency_s=args.imu_latency, truth=not args.no_truth, nav=args.nav,
                                             force=args.force)
    if len(stretches) > 1:
        print(f"{args.session}: GPS time goes back {len(stretches) - 1} time(s) (receiver restarts): "
              f"{len(stretches)} stretches, each replayed on its own")
    for j, inp in enumerate(stretches):
        outs = [Path(args.out) / replay_inputs.stretch_dir(j, len(stretches)) / (mode if len(modes) > 1 else "")
                for mode in modes]
        if len(modes) > 1 and len(os.sched_getaffinity(0)) > 1:
            # The modes side by side, one per core: the filter core lets go of the GIL, and a mode's
            # writing and scoring overlap the other's filter. The decoded inputs are shared read-only
            # and kept until both are done (no last_use), so the peak holds both modes' working sets.
            from concurrent.futures import ThreadPoolExecutor

            with ThreadPoolExecutor(max_workers=len(modes), thread_name_prefix="gpsins-mode") as pool:
                runs = [pool.submit(_run_one, args, inp, out, mode, overrides, False) for out, mode in zip(outs, modes)]
                for r in runs:
                    _print_one(r.result())  # in the modes' order, each as soon as it and those before are done
        else:
            for i, (out, mode) in enumerate(zip(outs, modes)):
                _print_one(_run_one(args, inp, out, mode, overrides, last_use=i == len(modes) - 1))
    return 0


def _run_one(args: argparse.Namespace, inp, out: Path, mode: str, overrides: dict, last_use: bool):
    from .replay import run

    return run.run_mode(inp, out, mode=mode, overrides=overrides, outages=args.outages,
                        reference=args.reference, reference_q=args.reference_q, point=args.point,
                        smooth=args.smooth, covariance_every=args.covariance_every,
                        aid_heading=args.aid_heading, last_use=last_use, estimator=args.estimator,
                        output_every=args.output_every)


def _print_one(res) -> None:
    """A mode's lines on the terminal: what it used, its warnings, fits and errors."""
    from . import memory
    from .report import data as report_data
    from .report import terminal as report_terminal
    from .nav import noise_from_data

    mode = res.mode
    c = res.summary["counters"]
    stretch = res.summary.get("stretch")
    where = f" (stretch {stretch['index']} of {stretch['of']})" if stretch else ""
    print(f"{mode}{where}: {res.summary['imu_samples']} IMU samples, {c['fixes_accepted']} fixes used, "
          f"{c['updates_rejected']} updates rejected; results in {res.out}")
    for line in res.summary.get("health", []):
        print(f"  WARNING: {line}")
    for f in res.summary.get("doctor", []):
        if f["level"] in ("warning", "error"):
            print(f"  data-set doctor: {f['level']}: {f['check']}: {f['text']}")
    for line in noise_from_data.summary_lines(res.summary):
        print(f"  {line}")
    if res.summary["skipped"]:
        print("  skipped: " + "; ".join(f"{k}: {v}" for k, v in res.summary["skipped"].items()))
    e = res.summary["errors"]
    if e:
        print(f"  vs truth: horizontal RMS {e['horizontal_rms_m']:.2f} m, vertical RMS {e['vertical_rms_m']:.2f} m")
    to = res.summary.get("time_offset")
    if to:
        applied = f" to add to the applied {to['applied_s'] * 1e3:.1f} ms" if to["applied_s"] is not None else ""
        print(f"  IMU time offset: {to['estimate_s'] * 1e3:+.1f} ms (sigma {to['sigma_s'] * 1e3:.1f} ms){applied}")
    if report_data.shows_outage_table(res.summary):
        report_terminal.print_outage_table(res.summary)
    memory.trim()


def cmd_dataset_init(args: argparse.Namespace) -> int:
    from .dataset import init

    out = Path(args.out)
    for f in (args.imu_file, args.gnss_file):
        if not Path(f).is_file():
            raise CommandError(f"{f}: no such file")
    if out.exists() and not args.force:
        raise CommandError(f"{out}: exists; --force replaces it")
    out.write_text(init.template(args.imu_file, args.gnss_file, out.parent), encoding="utf-8")
    print(f"{out}: written; set the lines marked SET, check those marked GUESSED, then `gpsins check {out}`")
    return 0


def cmd_batch(args: argparse.Namespace) -> int:
    from .montecarlo import batch
    from .montecarlo.runner import open_client

    if len(args.config) > 2 or (len(args.config) == 2 and args.estimator):
        raise CommandError("--config twice, or --config (once or not) and --estimator: two arms")
    if len(args.config) < 2 and not args.estimator:
        raise CommandError("arm B: a second --config or --estimator")
    a = batch.Arm(Path(args.config[0]).stem if args.config else "default", args.config[0] if args.config else None)
    b = batch.Arm(Path(args.config[1]).stem, args.config[1]) if len(args.config) == 2 else \
        batch.Arm(args.estimator.rpartition(":")[2], a.config, args.estimator)
    if a.name == b.name:
        b = batch.Arm(b.name + "-B", b.config, b.estimator)
    with open_client(args.scheduler, args.workers) as client:
        comparison = batch.run(args.sources, (a, b), args.out, mode=args.mode, outages=args.outages, client=client)
    for line in batch.summary_lines(comparison):
        print(line)
    print(f"tables and figure in {args.out} (batch.csv, paired.json, paired.png)")
    return 0


def cmd_live(args: argparse.Namespace) -> int:
    from .live import service
    from .nav import config as nav_config

    overrides = nav_config.parse_overrides(args.set or [])

    def started(info):
        if info["nmea_port"] is not None:
            print(f"NMEA on tcp://127.0.0.1:{info['nmea_port']}", flush=True)
        if info["http_port"] is not None:
            print(f"status page on http://127.0.0.1:{info['http_port']}/", flush=True)

    def round_done(st):
        s = st["sigma_ned_m"]
        print(f"t {st['t']:.1f} s: {st['llh_deg_m'][0]:.7f} {st['llh_deg_m'][1]:.7f} {st['llh_deg_m'][2]:.2f} m, "
              f"sigma N/E/D {s[0]:.2f}/{s[1]:.2f}/{s[2]:.2f} m, fixes used {st['counters']['fixes_accepted']}",
              flush=True)

    options = dict(mode=args.mode, config=args.config, overrides=overrides, nmea_port=args.nmea_port,
                   nmea_every=args.nmea_every, http_port=args.http_port, interval_s=args.interval,
                   gps_latency_s=args.gps_latency, imu_latency_s=args.imu_latency, on_start=started,
                   on_round=round_done)
    import gc

    from scipy.stats import chi2  # noqa: F401 (imported before the first round, as live.run does)

    gc.freeze()  # the process's own: what the imports made is never scanned again by the collector (pauses)
    if args.follow_root:
        service.run_root(args.session, args.out, **options)
    else:
        service.run(args.session, args.out, **options)
    return 0


def cmd_score(args: argparse.Namespace) -> int:
    from .report import data as report_data
    from .report import terminal as report_terminal
    from .replay import score

    if not Path(args.solution).is_file():
        raise CommandError(f"{args.solution}: no such solution file")
    res = score.score(args.solution, args.against, args.out, fmt=args.format, point=args.point,
                      outages=args.outages, reference=args.reference, reference_q=args.reference_q,
                      columns=args.columns.split(",") if args.columns else None, time=args.time, week=args.week)
    e = res.summary["errors"]
    print(f"{args.solution}: {res.summary['epochs']} epochs scored; results in {res.out}")
    if e:
        print(f"  vs truth: horizontal RMS {e['horizontal_rms_m']:.2f} m, vertical RMS {e['vertical_rms_m']:.2f} m")
    if report_data.shows_outage_table(res.summary):
        report_terminal.print_outage_table(res.summary)
    return 0


def cmd_check(args: argparse.Namespace) -> int:
    from .dataset import load, doctor

    if not Path(args.dataset).is_file():
        raise CommandError(f"{args.dataset}: no such data-set file")
    diagnosis = doctor.diagnose(load.load(args.dataset), ["loose", "tight"] if args.mode == "both" else
                                [args.mode])
    for f in diagnosis.findings:
        print(f.line())
    return 2 if diagnosis.errors() else 0


def cmd_report(args: argparse.Namespace) -> int:
    from .report import data as report_data
    from .report import page as report_page
    from .report import terminal as report_terminal

    from .replay import results

    given = [report_data.named(a) for a in args.results]
    out = args.out or Path(given[0][1]) / "report"
    runs = []
    for name, path in given:  # a directory of several runs: NAME becomes "NAME loose", "NAME tight", ...
        dirs = report_data.result_dirs(path)
        runs += [(d, None if name is None else name if len(dirs) == 1 else f"{name} {d.name}") for d in dirs]
    for path, _ in runs:
        if not results.exists(path) or not (Path(path) / "run.json").is_file():
            raise CommandError(f"{path}: no {results.SOLUTION}, {results.SMALL} and run.json; give a directory "
                               "written by gpsins replay --out")
    page = report_page.make_report(runs, out)
    report_terminal.print_comparison(runs)
    print(f"report: {page} (self-contained: {page.with_suffix('.html')})")
    return 0


def cmd_allan(args: argparse.Namespace) -> int:
    from .imu import cli as imu_cli

    return imu_cli.run_allan(args)


def cmd_calibrate(args: argparse.Namespace) -> int:
    from .imu import cli as imu_cli

    return imu_cli.run_calibrate(args)


def cmd_lab(args: argparse.Namespace) -> int:
    from .imu import cli as imu_cli

    return imu_cli.run_lab(args)


def cmd_spp(args: argparse.Namespace) -> int:
    from .gnss import spp

    if args.session:
        _session_dir(args.session)
    return spp.main(args)


def cmd_montecarlo(args: argparse.Namespace) -> int:
    from .montecarlo import cli as mc_cli

    return mc_cli.run(args)

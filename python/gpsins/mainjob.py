"""The main job on its built-in default: simulate the report's drive, serve it
through the two emulated serial devices, record it with the real logger
daemon exactly as on the vehicle, replay the session through the filter, and
write the report."""

from __future__ import annotations

import argparse
import json
import signal
import subprocess
import sys
import time
from pathlib import Path

import numpy as np

from .session import dump, logs
from . import sim
from .sim import scenario
from .devices.emulate import Emulators
from .devices.ublox import UbloxEmulators
from .sim import ublox as sim_ublox
from .sim.messages import MEASUREMENT_DELAY_S, SimSource
from .sim.ublox import UbloxSimSource

MODES = ("loose", "tight")


DEVICES = ("superstar2", "ublox")
UBLOX_BAUD = 460800
# The emulated drive's time scale at most: the suite checks 1 to 8 (alignment within 1 ms); 16 runs
# (bench: gpsins run --speed 16); beyond, the pty and the logger's stamps fall behind the frames.
MAX_SPEED = 16.0
UBLOX_MESSAGES = ["RXM-RAWX", "RXM-SFRBX", "NAV-PVT", "NAV-TIMEGPS", "ESF-RAW"]


def _logger_config(path: Path, devdir: Path, root: Path, device: str = "superstar2") -> Path:
    if device == "ublox":  # an F9R-like receiver: its own IMU (ESF-RAW) on the same port
        sensors = f"""[gps]
device = "ublox"
port = "{devdir / 'gps'}"
baud = {UBLOX_BAUD}
messages = {json.dumps(UBLOX_MESSAGES)}
"""
    else:
        sensors = f"""[gps]
port = "{devdir / 'gps'}"
[imu]
port = "{devdir / 'imu'}"
"""
    path.write_text(f"""# written by gpsins run
[session]
root = "{root}"
{sensors}""", encoding="utf-8")
    return path


def record_drive(simulation: sim.Simulation, out: Path, speed: float = 1.0, device: str = "superstar2",
                 session: Path | None = None, progress=None) -> Path:
    """Serve a simulation on ptys and record it with the logger daemon; returns the session directory
    (``session``, by default OUT/session). ``progress()``: text for the end of the progress line."""
    devdir, session = out / "dev", session or out / "session"
    cfg = _logger_config(out / "logger.toml", devdir, out / "sessions", device)
    if device == "ublox":
        em = UbloxEmulators(devdir, UbloxSimSource(simulation), speed=speed, gps_baud=UBLOX_BAUD)
    else:
        em = Emulators(devdir, SimSource(simulation), speed=speed)
    proc = subprocess.Popen([sys.executable, "-m", "gpsins_logger.daemon", "--config", str(cfg), "--session-dir",
                             str(session)], stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
    try:
        line = proc.stdout.readline().strip()
        if line != str(session):
            from .errors import CommandError

            why = " ".join((line + " " + (proc.stderr.read() if proc.poll() is not None else "")).split())
            raise CommandError(f"{cfg}: the logger daemon did not start ({why or 'no output'})")
        em.start()
        total = simulation.scenario.duration_s / speed
        t0 = time.monotonic()
        while not em.wait(1.0):
            done = min(1.0, (time.monotonic() - t0) / total)
            extra = progress() if progress is not None else ""
            clear = "\033[K" if sys.stdout.isatty() else ""  # the rest of a longer line before
            print(f"\r  recording: {100 * done:5.1f} % of {total:.0f} s{extra}{clear}", end="", flush=True)
        print()
        time.sleep(0.3)  # the last frames through the logger
        proc.send_signal(signal.SIGINT)
        _, err = proc.communicate(timeout=30)
        if proc.returncode != 0:
            from .errors import CommandError

            raise CommandError(f"{cfg}: the logger daemon exited with {proc.returncode}: {' '.join(err.split())}")
    finally:
        if proc.poll() is None:
            proc.kill()
            proc.wait()
        em.stop()
    return session


def replay_latencies(device: str, speed: float) -> dict:
    """The emulated devices' delays from the measurement to its first byte (shrunk on a faster
    than real-time drive), plus the logger's."""
    from .replay import inputs as replay_inputs

    if device == "ublox":
        return {"gps_latency_s": sim_ublox.MEASUREMENT_DELAY_S / speed + replay_inputs.DEFAULT_IMU_LATENCY_S,
                "imu_latency_s": sim_ublox.ESF_DELAY_S / speed + replay_inputs.DEFAULT_IMU_LATENCY_S}
    return {"gps_latency_s": MEASUREMENT_DELAY_S / speed + replay_inputs.DEFAULT_IMU_LATENCY_S}


def _live_beside(simulation: sim.Simulation, session: Path, out: Path, device: str, speed: float) -> dict:
    """gpsins live following the session as it is recorded, in a thread; the dict it returns holds the
    latest round's error against the simulator's truth as text for the progress line."""
    import threading

    from . import evaluate
    from .live import service

    shown: dict = {}
    tow0 = simulation.scenario.start.gps_tow_s

    def on_round(st):
        t = st["t"] - tow0
        if not st["heading_known"] or not simulation.truth.t[0] <= t <= simulation.truth.t[-1]:
            return
        r_true = simulation.truth.position_at(np.array([t]))[0]
        lat, lon = np.radians(st["llh_deg_m"][0]), np.radians(st["llh_deg_m"][1])
        ned = evaluate.c_en(np.array([lat]), np.array([lon]))[0].T @ (np.asarray(st["r_ecef"]) - r_true)
        s = st["sigma_ned_m"]
        shown["text"] = (f"; live: H error {np.hypot(ned[0], ned[1]):5.2f} m (sigma {np.hypot(s[0], s[1]):4.2f}), "
                         f"V {abs(ned[2]):5.2f} m")

    limit = simulation.scenario.duration_s / speed + 120.0
    threading.Thread(target=service.run, args=(session, out), name="gpsins-live", daemon=True,
                     kwargs=dict(interval_s=1.0, max_s=limit, on_round=on_round,
                                 **replay_latencies(device, speed))).start()
    return shown


def run(args: argparse.Namespace) -> int:
    from .errors import CommandError

    if not 0 < args.speed <= MAX_SPEED:
        raise CommandError(f"--speed {args.speed:g}: the emulated drive runs 0 to {MAX_SPEED:g} times real time "
                           f"(above that the serial devices' frames outrun the logger); 1 is real time")
    out = Path(args.out)
    out.mkdir(parents=True, exist_ok=True)
    # A rerun into the same --out records a new session beside the earlier ones; the results and the
    # report are the new run's.
    session, k = out / "session", 1
    while session.exists():
        k += 1
        session = out / f"session-{k}"
    sc = scenario.load(args.scenario)
    print(f"1. simulating {sc.name}: {sc.description} (seed {args.seed})")
    simulation = sim.simulate(sc, args.seed)
    from .formats.truth import write_truth

    write_truth(simulation, out / "truth.npz")
    print(f"2. serving it on emulated serial devices at {args.speed:g}x real time, recording with the logger daemon "
          f"and navigating live beside it (gpsins live, {out / 'live'})")
    device = getattr(args, "device", "superstar2")
    shown = _live_beside(simulation, session, out / "live", device, args.speed)
    session = record_drive(simulation, out, args.speed, device, session, progress=lambda: shown.get("text", ""))
    summary = dump.session_summary(session)
    dump.print_summary(summary, sys.stdout)
    got = logs.read_session(session)
    if device == "ublox":
        offered = len(list(UbloxSimSource(simulation).gps_messages()))
        print(f"3. recorded {got.sensors['gps'].count} UBX frames from the u-blox receiver (it offered {offered} "
              f"messages and NMEA, sending what the logger enabled; its IMU is in ESF-RAW)")
    else:
        offered = len(list(SimSource(simulation).gps_messages()))
        print(f"3. recorded {got.sensors['gps'].count} GPS frames (the receiver offered {offered}, sending what the "
              f"logger requested) and {got.sensors['imu'].count} IMU frames of {len(simulation.imu_t)}")
    from .replay import run as replay
    from .replay import inputs as replay_inputs
    from .report import page as report_page
    from .report import terminal as report_terminal

    results = []
    # The emulated receiver sends ID 23 its measurement delay after the epoch; on a
    # faster-than-real-time drive that delay shrinks with the speed.
    try:
        inp = replay_inputs.load_inputs(session, modes=MODES, **replay_latencies(device, args.speed))
    except ValueError as e:  # name the recorded session in the one-line message
        raise type(e)(f"{session}: {e}") from e
    for mode in MODES:
        print(f"4. replaying the session through the {mode} filter")
        try:
            res = replay.run_mode(inp, out / mode, mode=mode)
        except ValueError as e:
            raise type(e)(f"{session}: {e}") from e
        wall = res.summary["wall_time_s"]["total_s"]
        print(f"   {res.summary['imu_samples']} IMU samples in {wall:.2f} s; results in {res.out}")
        results.append(res.out)
    page = report_page.make_report(results, out / "report")
    print("5. comparison against the simulator's truth (from the first known heading on)")
    report_terminal.print_comparison(results)
    (out / "run.json").write_text(json.dumps({"scenario": sc.name, "seed": args.seed, "speed": args.speed,
                                              "session": str(session), "truth": str(out / "truth.npz"),
                                              "results": [str(r) for r in results], "report": str(page)}, indent=2))
    print(f"session: {session}\ntruth:   {out / 'truth.npz'}\nreport:  {page} and {page.with_suffix('.html')}")
    return 0

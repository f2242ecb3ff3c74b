"""u-blox device figures: frames recorded vs sent, stamp latency through the pty, and the
loose and tight errors of a simulated drive through an emulated F9R-like receiver next to
the same drive through the Superstar II + BP3010.

    PYTHONPATH=python:logger python benchmarks/bench_ublox.py [--speed 2] [--walk-speed 10] [--no-walk]

The stamp latency is meaningful at --speed 1 only: the logger backs a frame's first byte
out of the read time at the configured baud rate, and a faster-than-real-time emulator
sends its bytes faster than that (stamps then come out early by the difference).

Real ptys, the real logger daemon (a subprocess), the replay with the simulator's truth.
"""

from __future__ import annotations

import argparse
import json
import signal
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

from gpsins.session import logs
from gpsins import mainjob, sim
from gpsins.replay import run
from gpsins.devices.ublox import UbloxEmulators
from gpsins.sim.scenario import parse
from gpsins.formats.truth import write_truth
from gpsins.sim.ublox import UbloxSimSource
from gpsins.devices.sources import UbxCaptureSource
from gpsins_logger.ubx import NmeaCounter

ROOT = Path(__file__).resolve().parents[1]
START = {"gps_week": 1590, "gps_tow_s": 419400.0, "lat_deg": 59.37, "lon_deg": 17.95, "height_m": 30.0,
         "heading_deg": 160.0}
DRIVE = [{"label": "stand", "duration_s": 8, "speed_mps": 0}, {"label": "go", "duration_s": 6, "speed_mps": 8},
         {"label": "curve", "duration_s": 10, "turn_deg": 70}, {"label": "on", "duration_s": 8, "speed_mps": 11},
         {"label": "turn", "duration_s": 10, "turn_deg": -90}, {"label": "stop", "duration_s": 8, "speed_mps": 0}]


def record(tmp: Path, source, speed: float, serve_all: bool = False):
    em = UbloxEmulators(tmp / "dev", source, speed=speed, serve_all=serve_all)
    cfg = mainjob._logger_config(tmp / "logger.toml", tmp / "dev", tmp / "sessions", "ublox")
    session = tmp / "session"
    proc = subprocess.Popen([sys.executable, "-m", "gpsins_logger.daemon", "--config", str(cfg), "--session-dir",
                             str(session)], stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
    try:
        proc.stdout.readline()
        em.start()
        em.wait(source.duration_s / speed + 60)
        time.sleep(0.5)
        proc.send_signal(signal.SIGINT)
        proc.communicate(timeout=30)
    finally:
        if proc.poll() is None:
            proc.kill()
            proc.wait()
        em.stop()
    return em, logs.read_session(session), json.loads((session / "session.json").read_text())


def frames_line(name: str, em, got, side) -> None:
    ubx_sent = [s for s in em.gps.sent if s.frame[0] == 0xB5]
    ok = [s for s in ubx_sent if s.fate == "ok"]
    frames = got.sensors["gps"].frames()
    same = frames == [s.frame for s in ok]
    counter = NmeaCounter()  # the served stretches between frames may hold several sentences each
    for x in em.gps.sent:
        if x.frame[0] != 0xB5 and x.fate == "ok":
            counter.feed(x.frame)
    nmea = counter.sentences
    print(f"{name}: UBX frames sent {len(ubx_sent)} (intact {len(ok)}), recorded {len(frames)}, byte for byte "
          f"{'yes' if same else 'NO'}; NMEA sentences sent {nmea}, counted {side['counts']['gps']['nmea_sentences']}")
    if same and ok:
        lat_ms = (got.sensors["gps"].stamps - np.array([s.first_byte_realtime for s in ok])) * 1e3
        print(f"  stamp - first byte on the pty: median {np.median(lat_ms):.3f} ms, p99 "
              f"{np.percentile(lat_ms, 99):.3f} ms, max {lat_ms.max():.3f} ms")


def main() -> None:
    ap = argparse.ArgumentParser()
    ap.add_argument("--speed", type=float, default=2.0)
    ap.add_argument("--walk-speed", type=float, default=10.0)
    ap.add_argument("--no-walk", action="store_true")
    args = ap.parse_args()
    with tempfile.TemporaryDirectory() as d:
        tmp = Path(d)
        walk = ROOT / "tests" / "data" / "walk_0827" / "gnss_1730.ubx"
        if not args.no_walk:
            (tmp / "walk").mkdir()
            em, got, side = record(tmp / "walk", UbxCaptureSource(walk), args.walk_speed, serve_all=True)
            frames_line(f"walk capture ({walk.name}, {args.walk_speed:g}x)", em, got, side)

        s = sim.simulate(parse({"name": "bench", "start": START, "segment": DRIVE}), seed=7)
        rows = {}
        for device in ("ublox", "superstar2"):
            out = tmp / device
            out.mkdir()
            write_truth(s, out / "truth.npz")
            if device == "ublox":
                em, got, side = record(out, UbloxSimSource(s), args.speed)
                frames_line(f"simulated drive ({s.scenario.duration_s:.0f} s, {args.speed:g}x)", em, got, side)
                session = out / "session"
            else:
                session = mainjob.record_drive(s, out, args.speed)
            for mode in ("loose", "tight"):
                res = run.replay(session, out / mode, mode=mode, **mainjob.replay_latencies(device, args.speed))
                rows[(device, mode)] = res.summary["errors"]
        print(f"\nerrors against the truth (from the first known heading), drive of {s.scenario.duration_s:.0f} s:")
        print(f"{'device':<11} {'mode':<6} {'h RMS m':>8} {'h max m':>8} {'v RMS m':>8} {'NEES9':>7} "
              f"{'in 3 sigma':>10}")
        for (device, mode), e in rows.items():
            print(f"{device:<11} {mode:<6} {e['horizontal_rms_m']:8.2f} {e['horizontal_max_m']:8.2f} "
                  f"{e['vertical_rms_m']:8.2f} {e['nees9_mean']:7.2f} {100 * e['inside_3_sigma']:9.1f}%")


if __name__ == "__main__":
    main()

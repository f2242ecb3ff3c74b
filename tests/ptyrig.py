"""Run the pty emulators against the real logger daemon (a subprocess)."""

from __future__ import annotations

import json
import signal
import subprocess
import sys
import time
from dataclasses import dataclass
from pathlib import Path

from gpsins import logs
from gpsins.emulate import Emulators, Faults
from gpsins.sources import StaticSource


@dataclass
class RigResult:
    emulators: Emulators
    session: logs.SessionLog
    sidecar: dict
    returncode: int
    stderr: str


def write_config(path: Path, devdir: Path, root: Path, imu_rate_hz: int = 64, extra: str = "",
                 session_extra: str = "", reconnect_extra: str = "") -> Path:
    path.write_text(f"""
[session]
root = "{root}"
fsync_interval_s = 0.2
clock_pair_interval_s = 0.5
{session_extra}
[reconnect]
{reconnect_extra or "initial_backoff_s = 0.05"}
[gps]
port = "{devdir / 'gps'}"
[imu]
port = "{devdir / 'imu'}"
rate_hz = {imu_rate_hz}
{extra}
""")
    return path


def run_rig(tmp: Path, seconds: float = 4.0, stop_signal=signal.SIGINT, gps_faults: Faults | None = None,
            imu_faults: Faults | None = None, imu_rate_hz: int = 64, speed: float = 1.0,
            during=None, source=None, before=None, session_dir: Path | None = None, prefix: tuple = (),
            session_extra: str = "", reconnect_extra: str = "") -> RigResult:
    """`before(em)` runs before the daemon starts, `during(proc, em)` while the
    emulators stream; `prefix` goes before the daemon's command (e.g. setpriv)."""
    devdir = tmp / "dev"
    source = source or StaticSource(seconds, seed=1)
    em = Emulators(devdir, source, speed=speed, gps_faults=gps_faults, imu_faults=imu_faults)
    cfg = write_config(tmp / "logger.toml", devdir, tmp / "sessions", imu_rate_hz, session_extra=session_extra,
                       reconnect_extra=reconnect_extra)
    session_dir = session_dir or tmp / "session"
    if before:
        before(em)
    proc = subprocess.Popen([*prefix, sys.executable, "-m", "gpsins_logger.daemon", "--config", str(cfg),
                             "--session-dir", str(session_dir)], stdout=subprocess.PIPE, stderr=subprocess.PIPE,
                            text=True)
    try:
        assert proc.stdout.readline().strip() == str(session_dir)
        em.start()
        if during:
            during(proc, em)
        assert em.wait(seconds / speed + 30), "emulators did not finish"
        time.sleep(0.3)  # let the last frames through
        proc.send_signal(stop_signal)
        _, err = proc.communicate(timeout=20)
    finally:
        if proc.poll() is None:
            proc.kill()
            proc.wait()
        em.stop()
    sidecar = json.loads((session_dir / "session.json").read_text())
    return RigResult(em, logs.read_session(session_dir), sidecar, proc.returncode, err)


def sent_ok(emulator) -> list[bytes]:
    return [s.frame for s in emulator.sent if s.fate == "ok"]


def faulted_bytes(emulator) -> int:
    """Bytes put on the line that belong to no intact frame."""
    return emulator.garbage_bytes + sum(s.wire_bytes for s in emulator.sent if s.fate in ("flipped", "truncated"))

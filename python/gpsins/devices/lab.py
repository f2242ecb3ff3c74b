"""A simulated laboratory day (``sim.lab``) recorded as a real one is: each recording served on a pty
by the BP3010 emulator and recorded by the logger daemon.
"""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np

from gpsins_logger import bp3010

from ..sim.lab import LabDay, Session, truth_doc, plan_text


class LabSessionSource:
    """One recording of the lab day as a message source for the pty emulators (IMU only: a lab
    recording has no receiver)."""

    def __init__(self, day: LabDay, session: Session):
        self.day, self.session = day, session
        self.duration_s = (session.i1 - session.i0) / day.rate_hz

    def gps_messages(self):
        return iter(())

    def imu_samples(self, rate_hz: int, t0: float = 0.0):
        from ..formats.messages import TimedSample
        from ..sim.messages import combine_increments

        s, base = self.session, self.day.rate_hz
        m = max(1, int(round(base / rate_hz)))
        dth, dv = self.day.dtheta[s.i0:s.i1], self.day.dv[s.i0:s.i1]
        t = (np.arange(len(dth)) + 1.0) / base
        if m > 1:
            dth, dv = combine_increments(dth, dv, m)
            t = t[m - 1::m][:len(dth)]
        for k in np.flatnonzero(t >= t0 - 1e-9):
            yield TimedSample(float(t[k]), bp3010.ImuSample(tuple(map(float, dth[k])), tuple(map(float, dv[k]))))


def record_through_logger(day: LabDay, directory: str | Path, speed: float = 1.0, timeout_s: float = 60.0,
                          sessions: list[str] | None = None) -> Path:
    """Serve each recording on a pty (the BP3010 emulator) and record it with the logger daemon
    (a subprocess), as a lab day would be recorded; then the truth and the plan. speed > 1 plays
    the day faster than real time. Returns the plan's path."""
    import signal
    import subprocess
    import sys
    import tempfile
    import time

    from .emulate import Emulators

    directory = Path(directory)
    directory.mkdir(parents=True, exist_ok=False)
    chosen = [s for s in day.sessions if sessions is None or s.name in sessions]
    with tempfile.TemporaryDirectory(prefix="gpsins-lab-") as tmp:
        tmp = Path(tmp)
        for s in chosen:
            devdir = tmp / f"dev-{s.name}"
            source = LabSessionSource(day, s)
            em = Emulators(devdir, source, speed=speed)
            cfg = tmp / f"logger-{s.name}.toml"
            cfg.write_text(f'[session]\nroot = "{tmp / "sessions"}"\nfsync_interval_s = 0.5\n'
                           f'[gps]\nport = "{devdir / "gps"}"\n[imu]\nport = "{devdir / "imu"}"\n'
                           f"rate_hz = {day.rate_hz}\n", encoding="utf-8")
            proc = subprocess.Popen([sys.executable, "-m", "gpsins_logger.daemon", "--config", str(cfg),
                                     "--session-dir", str(directory / s.name)], stdout=subprocess.PIPE,
                                    stderr=subprocess.PIPE, text=True)
            try:
                proc.stdout.readline()  # the daemon prints its session directory once it is recording
                em.start()
                if not em.wait(source.duration_s / speed + timeout_s):
                    raise RuntimeError(f"lab session {s.name}: the emulator did not finish")
                time.sleep(0.3)  # the last frames through the pty
                proc.send_signal(signal.SIGINT)
                proc.communicate(timeout=20)
            finally:
                if proc.poll() is None:
                    proc.kill()
                    proc.wait()
                em.stop()
    (directory / "truth.json").write_text(json.dumps(truth_doc(day), indent=1, default=list) + "\n",
                                          encoding="utf-8")
    plan = directory / "lab_plan.toml"
    plan.write_text(plan_text(day, [s.name for s in chosen]), encoding="utf-8")
    return plan

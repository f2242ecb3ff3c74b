"""Run the pty emulators against the real logger daemon (a subprocess).

Nothing here waits a fixed time and then expects a result: every wait is for
a condition (bytes read, frames counted, a file's size, a log line, a port
state) with a generous deadline, and fails naming what it waited for, so a
loaded machine makes the tests slower, not wrong."""

from __future__ import annotations

import json
import os
import select
import signal
import subprocess
import sys
import threading
import time
from dataclasses import dataclass
from pathlib import Path

from gpsins.session import logs
from gpsins.devices.emulate import Emulators
from gpsins.devices.pty import Faults
from gpsins.devices.sources import StaticSource

# How long any one condition may take before the test fails: far beyond what
# an idle machine needs (milliseconds to a few seconds), so load cannot trip it.
DEADLINE_S = 60.0


def wait_until(predicate, what: str, timeout: float = DEADLINE_S, interval: float = 0.02, detail=None):
    """Poll predicate() until it returns something true and return that; after
    timeout seconds fail with `what` (and detail(), the state seen, if given)."""
    end = time.monotonic() + timeout
    while True:
        value = predicate()
        if value:
            return value
        if time.monotonic() >= end:
            seen = f"; {detail()}" if detail is not None else ""
            raise AssertionError(f"waited {timeout:.0f} s for {what}{seen}")
        time.sleep(interval)


@dataclass
class RigResult:
    emulators: Emulators
    session: logs.SessionLog
    sidecar: dict
    returncode: int
    stderr: str


class DaemonProcess(subprocess.Popen):
    """The daemon as a Popen whose stderr is collected as it comes (so a test can
    wait for a log line) and whose sidecar can be read while it runs."""

    def __init__(self, args, session_dir: Path):
        super().__init__(args, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
        self.session_dir = Path(session_dir)
        self._lines: list[str] = []
        self._reader = threading.Thread(target=self._read_stderr, name="daemon-stderr", daemon=True)
        self._reader.start()

    def _read_stderr(self) -> None:
        for line in self.stderr:
            self._lines.append(line)

    def stderr_text(self) -> str:
        return "".join(self._lines)

    def log_lines(self, needle: str) -> list[str]:
        return [ln for ln in self.stderr_text().splitlines() if needle in ln]

    def wait_for_log(self, needle: str, timeout: float = DEADLINE_S) -> str:
        """The first stderr line containing needle, once it is there."""
        return self.wait_for(lambda: self.log_lines(needle), f"a log line with {needle!r}", timeout)[0]

    def sidecar(self) -> dict:
        """The sidecar as last written ({} before the first); the daemon
        rewrites it every fsync_interval_s (write, then rename)."""
        try:
            return json.loads((self.session_dir / "session.json").read_text())
        except (FileNotFoundError, json.JSONDecodeError):
            return {}

    def count(self, sensor: str, key: str = "frames_written") -> int:
        return self.sidecar().get("counts", {}).get(sensor, {}).get(key, 0)

    def port_state(self, sensor: str) -> dict:
        return self.sidecar().get("sensors", {}).get(sensor, {}).get("port_state", {})

    def wait_for(self, predicate, what: str, timeout: float = DEADLINE_S):
        """wait_until, failing at once (with the daemon's stderr) if the daemon exits meanwhile."""
        def check():
            value = predicate()
            if not value and self.poll() is not None:
                self._reader.join(timeout=5.0)  # its last lines
                value = predicate()
                if not value:
                    raise AssertionError(f"the daemon exited ({self.returncode}) while a test waited for {what}:\n"
                                         f"{self.stderr_text()}")
            return value
        return wait_until(check, what, timeout, detail=lambda: f"sidecar counts {self.sidecar().get('counts')}; "
                                                               f"stderr so far:\n{self.stderr_text()}")

    def wait_for_frames(self, counts: dict[str, int], timeout: float = DEADLINE_S) -> None:
        """Until the sidecar counts at least counts[sensor] frames written for every sensor named."""
        self.wait_for(lambda: all(self.count(n) >= k for n, k in counts.items()),
                      "frames written: " + ", ".join(f"{n} >= {k}" for n, k in counts.items()), timeout)

    def wait_for_state(self, sensor: str, state: str, timeout: float = DEADLINE_S) -> dict:
        """Until the sidecar shows sensor's port in state; returns the port state."""
        def seen():
            st = self.port_state(sensor)
            return st if st.get("state") == state else {}
        return self.wait_for(seen, f"{sensor}'s port state {state!r}", timeout)

    def finish(self, timeout: float = 20.0) -> str:
        """Wait for the exit (the caller stopped it) and return all of stderr."""
        self.wait(timeout=timeout)
        self._reader.join(timeout=10.0)
        self.stdout.close()
        return self.stderr_text()


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


def start_daemon(cfg: Path, session_dir: Path, prefix: tuple = ()) -> DaemonProcess:
    """The daemon, started: it has created the session and said so on stdout."""
    proc = DaemonProcess([*prefix, sys.executable, "-m", "gpsins_logger.daemon", "--config", str(cfg),
                          "--session-dir", str(session_dir)], session_dir)
    first = proc.stdout.readline().strip()  # the session directory, or EOF when it failed to start
    if first != str(session_dir):
        proc.kill()
        raise AssertionError(f"the daemon did not start its session (stdout {first!r}):\n{proc.finish()}")
    return proc


def line_bytes(device) -> int:
    """Bytes the emulator put on the line that the host can still read: every
    frame sent whole (intact or faulted) with the garbage before it. Frames cut
    by an unplug, or unread when the device vanished, are left out (so a host
    that read part of them has read at least this many)."""
    return sum(s.garbage_before + s.wire_bytes for s in list(device.sent) if s.fate in ("ok", "flipped", "truncated"))


def wait_until_read(proc: DaemonProcess, devices: dict, timeout: float = DEADLINE_S) -> None:
    """Until the daemon has read every byte the emulators put on the line (its
    sidecar's bytes_read per sensor), or has exited. After this a stop loses
    nothing: a sensor thread records all it has read before it ends."""
    def done():
        return proc.poll() is not None or all(proc.count(n, "bytes_read") >= line_bytes(d) for n, d in devices.items())

    wait_until(done, "the daemon to read every byte the emulators sent", timeout,
               detail=lambda: ", ".join(f"{n}: read {proc.count(n, 'bytes_read')} of {line_bytes(d)}"
                                        for n, d in devices.items()))


def wait_until_quiet(proc: DaemonProcess, devices: dict, versions: int = 2, timeout: float = DEADLINE_S) -> None:
    """For an emulator that sends without being asked (a u-blox receiver's NMEA,
    flushed when the daemon opens the port after it), where line_bytes is not
    what the daemon can read: until no device has unread bytes in its port and
    the daemon's bytes_read stayed the same over `versions` new sidecars after
    that (each fsync_interval_s), or the daemon has exited. Call it when the
    emulators send nothing more."""
    seen = {"mark": None, "new": 0}

    def quiet():
        if proc.poll() is not None:
            return True
        if any(d.pty.unread_bytes() for d in devices.values()):
            seen.update(mark=None, new=0)
            return False
        doc = proc.sidecar()
        version = json.dumps(doc.get("written")) if "written" in doc else file_mtime(proc.session_dir / "session.json")
        counts = tuple(doc.get("counts", {}).get(n, {}).get("bytes_read", 0) for n in devices)
        if seen["mark"] is None or seen["mark"][1] != counts:
            seen.update(mark=(version, counts), new=0)
        elif seen["mark"][0] != version:
            seen.update(mark=(version, counts), new=seen["new"] + 1)
        return seen["new"] >= versions

    wait_until(quiet, f"the daemon to read all it was sent (ports empty, bytes_read the same over {versions} sidecars)",
               timeout, detail=lambda: ", ".join(f"{n}: {d.pty.unread_bytes()} bytes unread, read "
                                                 f"{proc.count(n, 'bytes_read')}" for n, d in devices.items()))


def host_wrote(device) -> bool:
    """Whether the host has written to the emulated device (bytes wait unread on
    its pty): the daemon has opened the port, after which nothing is flushed."""
    return bool(select.select([device.pty.master], [], [], 0)[0])


def unplug(device, down_s: float) -> None:
    """Unplug the emulated device now, for down_s seconds (of its run time). The
    emulator's own thread does it, exactly as a scheduled Faults.disconnects
    entry: this adds one due at once. The test starts it when the daemon is seen
    logging, instead of at a fixed time that a loaded daemon may not have reached."""
    device._pending_disconnects.append((0.0, down_s))


def run_rig(tmp: Path, seconds: float = 4.0, stop_signal=signal.SIGINT, gps_faults: Faults | None = None,
            imu_faults: Faults | None = None, imu_rate_hz: int = 64, speed: float = 1.0,
            during=None, source=None, before=None, session_dir: Path | None = None, prefix: tuple = (),
            session_extra: str = "", reconnect_extra: str = "") -> RigResult:
    """`before(em)` runs before the daemon starts, `during(proc, em)` while the
    emulators stream (proc: a DaemonProcess); `prefix` goes before the daemon's
    command (e.g. setpriv). The daemon is stopped once the emulators are done
    and it has read all they sent."""
    devdir = tmp / "dev"
    source = source or StaticSource(seconds, seed=1)
    em = Emulators(devdir, source, speed=speed, gps_faults=gps_faults, imu_faults=imu_faults)
    cfg = write_config(tmp / "logger.toml", devdir, tmp / "sessions", imu_rate_hz, session_extra=session_extra,
                       reconnect_extra=reconnect_extra)
    session_dir = session_dir or tmp / "session"
    if before:
        before(em)
    proc = None
    try:
        proc = start_daemon(cfg, session_dir, prefix)
        em.start()
        if during:
            during(proc, em)
        assert em.wait(seconds / speed + DEADLINE_S), "emulators did not finish"
        wait_until_read(proc, {"gps": em.gps, "imu": em.imu})
        proc.send_signal(stop_signal)
        err = proc.finish()
    finally:
        if proc is not None and proc.poll() is None:
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


def file_size(path: Path) -> int:
    try:
        return os.path.getsize(path)
    except FileNotFoundError:
        return 0


def file_mtime(path: Path) -> int:
    try:
        return os.stat(path).st_mtime_ns
    except FileNotFoundError:
        return 0

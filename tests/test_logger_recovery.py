"""Issue 37, the daemon's part: faults that each cost a whole session on a vehicle, against the real daemon through
ptys (and the recorder or the u-blox set-up alone where a clock must be controlled): the session directory deleted
while logging, a u-blox receiver refusing or ignoring its set-up, SIGKILL just after SIGHUP, a second daemon
taking the devices over, a nearly full disk at start.

Every wait is on a condition with a generous deadline, so the tests hold on a loaded machine."""

import contextlib
import io
import json
import os
import random
import re
import shutil
import signal
import subprocess
import sys
import time
import types
from pathlib import Path

import numpy as np
import pytest

from gpsins.session import dump, logs
from gpsins.devices.emulate import Emulators
from gpsins.devices.ublox import UbloxEmulators
from gpsins.devices.sources import StaticSource
from gpsins_logger import bp3010, ubx
from gpsins_logger.recorder import SensorInfo, Session
from ptyrig import sent_ok, write_config

IMU_RECORD = bp3010.FRAME_LEN + 8  # a BP3010 record: the frame and its stamp


# --- helpers ---------------------------------------------------------------------------------------------


def wait_until(cond, timeout: float, step: float = 0.02):
    """cond()'s first true value within timeout seconds, else None."""
    deadline = time.monotonic() + timeout
    while True:
        v = cond()
        if v or time.monotonic() > deadline:
            return v
        time.sleep(step)


def wait_for(cond, timeout: float, what: str):
    v = wait_until(cond, timeout)
    assert v, f"no {what} within {timeout} s"
    return v


def read_json(path: Path):
    """A sidecar as it is on disk now; None while it is missing."""
    try:
        return json.loads(path.read_text())
    except (OSError, ValueError):
        return None


def file_size(path: Path) -> int:
    try:
        return path.stat().st_size
    except OSError:
        return 0


def port_state(session_dir: Path, sensor: str) -> dict:
    side = read_json(session_dir / "session.json")
    return side["sensors"][sensor]["port_state"] if side else {}


class Daemon:
    """The real daemon in a subprocess, its log in a file (a pipe nobody reads could block it)."""

    def __init__(self, cfg: Path, session_dir: Path, log: Path):
        self.session_dir, self.log = session_dir, log
        with open(log, "w") as err:
            self.proc = subprocess.Popen([sys.executable, "-m", "gpsins_logger.daemon", "--config", str(cfg),
                                          "--session-dir", str(session_dir)], stdout=subprocess.PIPE, stderr=err,
                                         text=True)
        assert self.proc.stdout.readline().strip() == str(session_dir), self.stderr()

    def stderr(self) -> str:
        return self.log.read_text() if self.log.exists() else ""

    def stop(self, sig=signal.SIGINT) -> int:
        if self.proc.poll() is None:
            self.proc.send_signal(sig)
        try:
            return self.proc.wait(timeout=30)
        finally:
            self.close()

    def close(self) -> None:
        if self.proc.poll() is None:
            self.proc.kill()
            self.proc.wait()
        self.proc.stdout.close()


@contextlib.contextmanager
def daemons():
    """Daemons started in the block are killed at its end if still running."""
    started: list[Daemon] = []
    try:
        yield started
    finally:
        for d in started:
            d.close()


def lines_with(text: str, needle: str) -> list[str]:
    return [ln for ln in text.splitlines() if needle in ln]


def wait_streams_done(em, timeout: float) -> None:
    assert em.wait(timeout), "emulators did not finish"


def wait_all_written(side_path: Path, em, timeout: float = 10.0, lost_too: bool = False) -> None:
    """Until the sidecar counts as many frames as were sent (written, or lost to the disk): the daemon caught up.
    A frame that never comes shows in the asserts after this."""
    def caught_up():
        s = read_json(side_path)
        return s and all(s["counts"][n]["frames_written"] + lost_too * s["counts"][n]["frames_lost_to_disk_errors"]
                         >= len(sent_ok(getattr(em, n))) for n in ("gps", "imu"))
    wait_until(caught_up, timeout)


def dump_text(directory: Path) -> str:
    out = io.StringIO()
    dump.print_summary(dump.session_summary(directory), out)
    return out.getvalue()


# --- 1: the session directory deleted or replaced while logging ------------------------------------------


@pytest.mark.parametrize("how", ["deleted", "replaced"])
def test_session_directory_gone_while_logging_goes_on_in_a_continuation(tmp_path, how):
    """rm -rf of the session 2 s in (or the directory moved aside and another made in its place): the daemon
    used to write on into deleted inodes for the rest of the run, exiting 0. Now it says so once, goes on in
    <session>-cont1 and carries over the records since it last saw the directory, so no frame is lost."""
    dev, session = tmp_path / "dev", tmp_path / "session"
    em = Emulators(dev, StaticSource(6.0, seed=1))
    cfg = write_config(tmp_path / "logger.toml", dev, tmp_path / "sessions")
    cont = tmp_path / "session-cont1"
    try:
        with daemons() as ds:
            d = Daemon(cfg, session, tmp_path / "daemon.log")
            ds.append(d)
            em.start()
            wait_for(lambda: file_size(session / "imu-000.bin") >= 120 * IMU_RECORD, 30, "IMU records")
            gone_at = time.time()
            if how == "deleted":
                subprocess.run(["rm", "-rf", str(session)])  # as on the vehicle; a race with the daemon may leave it
            else:
                os.rename(session, tmp_path / "moved")
                session.mkdir()
            wait_for(lambda: read_json(cont / "session.json"), 15, "continuation directory")
            wait_streams_done(em, 60)
            wait_all_written(cont / "session.json", em)
            assert d.stop() == 0, d.stderr()
            err = d.stderr()
    finally:
        em.stop()
    assert "Traceback" not in err and not lines_with(err, "work again"), err
    said = lines_with(err, "continuing in")
    assert len(said) == 1 and str(cont) in said[0], err
    side = read_json(cont / "session.json")
    assert side["state"] == "stopped"
    c = side["continues"]
    assert c["previous"] == "session" and ("deleted" in c["reason"] if how == "deleted" else "replaced" in c["reason"])
    # The 64 Hz IMU always has records between the last look at the directory and the one that found it gone.
    assert (c["frames_carried_over"]["imu"] > 0) == (how == "deleted"), c
    r = logs.read_session(cont)
    for name in ("gps", "imu"):
        ok = sent_ok(getattr(em, name))
        got = r.sensors[name].frames()
        assert got and got == ok[len(ok) - len(got):], f"{name}: the continuation is not the tail of what was sent"
        # This directory's records are the run's counts less those in the previous one.
        assert side["counts"][name]["frames_written"] - c["frames_before"][name] == len(got)
        if how == "deleted":
            # Every frame sent after the deletion is here, and the records since the directory was last seen.
            after = sum(s.first_byte_realtime > gone_at for s in getattr(em, name).sent if s.fate == "ok")
            assert len(got) >= after, f"{name}: {after - len(got)} frames sent after the deletion are lost"
            carried = c["frames_carried_over"][name]
            assert np.all(r.sensors[name].stamps[:carried] < c["noticed"]["realtime"]), name
        else:
            # Moved: the old files kept their records; the two directories together hold every frame once.
            before = logs.read_session(tmp_path / "moved").sensors[name].frames()
            assert before + got == ok, name
            assert c["frames_carried_over"][name] == 0
    print(f"{how}: frames lost after the directory went: 0; "
          f"carried over {c['frames_carried_over']}, in the continuation "
          f"{ {n: r.sensors[n].count for n in r.sensors} }")
    text = dump_text(cont)
    assert "continues session session" in text and ("deleted" in text if how == "deleted" else "replaced" in text)


# --- 2: a u-blox receiver that refuses or ignores its set-up ---------------------------------------------

START = {"gps_week": 1590, "gps_tow_s": 419400.0, "lat_deg": 59.37, "lon_deg": 17.95, "height_m": 30.0,
         "heading_deg": 160.0}


def _ublox_source(seconds: float):
    from gpsins import sim
    from gpsins.sim.scenario import parse
    from gpsins.sim.ublox import UbloxSimSource

    sc = parse({"name": "stand", "start": START, "segment": [{"label": "stand", "duration_s": seconds,
                                                               "speed_mps": 0}]})
    return UbloxSimSource(sim.simulate(sc, seed=7))


def _ublox_config(path: Path, devdir: Path, root: Path, extra: str) -> Path:
    path.write_text(f"""
[session]
root = "{root}"
fsync_interval_s = 0.2
clock_pair_interval_s = 0.5
[gps]
device = "ublox"
port = "{devdir / 'gps'}"
baud = 460800
messages = ["RXM-RAWX", "NAV-PVT", "NAV-TIMEGPS"]
{extra}
""")
    return path


@pytest.mark.parametrize("fault", ["nak", "silent"])
def test_unconfigured_receiver_is_set_up_again_when_it_comes_round(tmp_path, fault):
    """The receiver NAKs (or ignores) its CFG-VALSET for the first seconds. The daemon used to try once, then log
    NMEA only for the whole drive with the port 'open'. Now the port state says 'unconfigured: NAK CFG-VALSET',
    the set-up is sent again with back-off, and once the receiver acknowledges, UBX flows."""
    dev, session = tmp_path / "dev", tmp_path / "session"
    em = UbloxEmulators(dev, _ublox_source(14.0), gps_baud=460800, config_fault=fault)
    cfg = _ublox_config(tmp_path / "logger.toml", dev, tmp_path / "sessions",
                        "ack_timeout_s = 0.5\nsetup_retry_max_s = 2.0")
    try:
        with daemons() as ds:
            d = Daemon(cfg, session, tmp_path / "daemon.log")
            ds.append(d)
            em.start()
            state = wait_for(lambda: (p := port_state(session, "gps")).get("state") == "unconfigured" and p, 20,
                             "'unconfigured' port state")
            # Let it try a few more times before the receiver comes round.
            wait_for(lambda: len(em.gps.config_log) >= 3, 20, "set-up retries")
            fixed_at = time.time()
            em.gps.config_fault = None  # the receiver answers now (booted, or no longer busy)
            opened = wait_for(lambda: (p := port_state(session, "gps")).get("state") == "open" and p, 20,
                              "the port 'open' again after the set-up was acknowledged")
            wait_streams_done(em, 60)
            assert d.stop() == 0, d.stderr()
            err = d.stderr()
    finally:
        em.stop()
    want = "NAK CFG-VALSET" if fault == "nak" else "no answer CFG-VALSET"
    assert state["reason"] == want, state
    assert opened["since"] >= fixed_at - 0.05
    tries = [a for _, a in em.gps.config_log]
    assert tries[-1] == "ack" and tries.count("ack") == 1 and len(tries) >= 4, tries
    side = read_json(session / "session.json")
    rec = side["sensors"]["gps"]["receiver"]
    assert rec["configured"] and rec["attempts"] >= 4 and rec["configuration"][0]["result"] == "ack"
    r = logs.read_session(session)
    st, frames = r.sensors["gps"].stamps, r.sensors["gps"].frames()
    rawx = st[[(f[2], f[3]) == ubx.RXM_RAWX for f in frames]]
    # Set-up retried within its maximum back-off (2 s) plus the ACK timeout: RAWX at 10 Hz from then on.
    assert len(rawx) >= 20 and rawx[0] - fixed_at < 2.0 + 0.5 + 1.5, (len(rawx), rawx[:1] - fixed_at)
    # The retries are not logged one by one: the first failure, then a reminder a minute at most.
    noisy = [ln for ln in err.splitlines() if re.search(r"refused|no ACK|incomplete|unconfigured", ln)]
    assert len(noisy) <= 3, err
    print(f"{fault}: {len(tries) - 1} refused attempts, first RAWX {rawx[0] - fixed_at:.2f} s after the receiver "
          f"came round, {len(rawx)} RAWX logged (before: 0 for the whole drive)")


def test_set_up_backs_off_to_its_maximum_and_reminds_once_a_minute(monkeypatch, caplog):
    """The set-up's timing with a controlled clock: attempts 1, 2, 4, 8, then every 10 s (the default
    maximum); one warning a minute while unconfigured; done once the receiver acknowledges."""
    caplog.set_level("INFO", logger="gpsins_logger")
    clock = [1000.0]
    monkeypatch.setattr(ubx, "time", types.SimpleNamespace(monotonic=lambda: clock[0]))
    steps = ubx.setup_steps(9, "uart1", 10.0, ["NAV-PVT"])
    setup = ubx.Setup(steps, ack_timeout_s=1.0, poll_version=False)
    assert setup.retry_max_s == 10.0
    sent: list[float] = []
    setup.start(lambda frame: sent.append(clock[0]))

    def run_until(cond, limit_s: float) -> None:
        end = clock[0] + limit_s
        while not cond() and clock[0] < end:
            clock[0] += 0.05
            setup.tick()

    run_until(lambda: False, 300.0)  # a silent receiver for five minutes
    gaps = np.diff(sent)
    # Attempts start 1, 2, 4, 8 s apart, then every 10 s (the first waits out its 1 s ACK timeout).
    assert np.allclose(gaps[:4], [1.0, 2.0, 4.0, 8.0], atol=0.11), gaps[:6]
    assert len(gaps) > 25 and np.all(np.abs(gaps[4:] - 10.0) < 0.11), gaps
    assert setup.unconfigured() == "no answer CFG-VALSET" and not setup.done
    reminders = [r.getMessage() for r in caplog.records if "still unconfigured" in r.getMessage()]
    assert len(reminders) == 4, reminders  # minutes 1 to 5, at the first attempt a minute after the last warning
    # The next attempt is refused: the reason says so. The one after is acknowledged: done, nothing more is sent.
    n = len(sent)
    run_until(lambda: len(sent) > n, 12.0)
    assert setup.on_frame(ubx.encode_frame(ubx.ACK_NAK, bytes(ubx.CFG_VALSET)))
    assert setup.unconfigured() == "NAK CFG-VALSET"
    n = len(sent)
    run_until(lambda: len(sent) > n, 12.0)
    assert setup.on_frame(ubx.encode_frame(ubx.ACK_ACK, bytes(ubx.CFG_VALSET)))
    assert setup.done and setup.unconfigured() == "" and setup.record()["configured"]
    n = len(sent)
    run_until(lambda: False, 100.0)
    assert len(sent) == n


# --- 5: SIGKILL just after SIGHUP ------------------------------------------------------------------------


def _records_on_disk(directory: Path, sidecar: dict) -> dict[str, int]:
    """Records in every record file on disk, found by name, listed or not."""
    return {name: sum(logs.read_record_file(p, info["device"]).count for p in sorted(directory.glob(f"{name}-*.bin")))
            for name, info in sidecar["sensors"].items()}


@pytest.mark.parametrize("when", ["as_the_new_part_appears", "0_to_30_ms_after"])
def test_sigkill_just_after_sighup_leaves_every_record_listed(tmp_path, when):
    """The new part's files used to be created before the sidecar listed them: a SIGKILL in between (4 of 30
    runs at 0-30 ms) left imu-001.bin unread. Now the sidecar names a part before its files exist."""
    dev = tmp_path / "dev"
    em = Emulators(dev, StaticSource(600.0, seed=1))
    cfg = write_config(tmp_path / "logger.toml", dev, tmp_path / "sessions")
    rng = random.Random(37)
    runs = 5 if when == "as_the_new_part_appears" else 12
    bad = []
    try:
        em.start()
        for k in range(runs):
            session = tmp_path / f"s{k}"
            with daemons() as ds:
                d = Daemon(cfg, session, tmp_path / f"daemon{k}.log")
                ds.append(d)
                wait_for(lambda session=session: file_size(session / "imu-000.bin") >= 10 * IMU_RECORD, 30,
                         "IMU records")
                d.proc.send_signal(signal.SIGHUP)
                if when == "as_the_new_part_appears":
                    wait_until(lambda session=session: any((session / f"{n}-001.bin").exists() for n in ("gps", "imu")),
                               10, step=0.0002)
                else:
                    time.sleep(rng.uniform(0.0, 0.03))
                d.proc.kill()
                d.proc.wait()
            side = read_json(session / "session.json")
            listed = {f for s in side["sensors"].values() for f in s["files"]}
            on_disk = {p.name for p in session.glob("*.bin")}
            readable = {n: f.count for n, f in logs.read_session(session).sensors.items()}
            if not on_disk <= listed or readable != _records_on_disk(session, side):
                bad.append((k, sorted(on_disk - listed), readable, _records_on_disk(session, side)))
            # A killed daemon's sidecar is at most a write period behind: dump does not call it stale.
            assert dump.session_summary(session)["sidecar"]["older_than_records"] is None
    finally:
        em.stop()
    assert not bad, f"{len(bad)} of {runs} runs left records the sidecar does not list: {bad}"


# --- 6: a second daemon taking over the devices ---------------------------------------------------------


def has_last_frames(directory: Path, em) -> bool:
    """Whether the session's files end with the last frame each emulator sent."""
    for name, device in (("gps", "superstar2"), ("imu", "bp3010")):
        files = sorted(directory.glob(f"{name}-*.bin"))
        if not files or logs.read_record_file(files[-1], device).frames()[-1:] != sent_ok(getattr(em, name))[-1:]:
            return False
    return True


def test_second_daemon_takes_over_the_devices_within_half_a_second(tmp_path):
    """Daemon B starts while A holds both devices (locked), a third C too; A stops. B used to wait out its 5 s
    retry period (a lock going away changes nothing on the node): 4.9 s lost. Now the locked device is tried
    every 0.1 s. C, which never got a device, removes its empty session directory at exit."""
    dev = tmp_path / "dev"
    em = Emulators(dev, StaticSource(9.0, seed=1))
    cfg = write_config(tmp_path / "logger.toml", dev, tmp_path / "sessions")  # the shipped retry: 5 s
    a_dir, b_dir, c_dir = tmp_path / "a", tmp_path / "b", tmp_path / "c"
    try:
        with daemons() as ds:
            a = Daemon(cfg, a_dir, tmp_path / "a.log")
            ds.append(a)
            em.start()
            wait_for(lambda: file_size(a_dir / "imu-000.bin") >= 64 * IMU_RECORD, 30, "A's IMU records")
            b = Daemon(cfg, b_dir, tmp_path / "b.log")
            ds.append(b)
            c = Daemon(cfg, c_dir, tmp_path / "c.log")
            ds.append(c)
            for x in (b_dir, c_dir):
                for n in ("gps", "imu"):
                    st = wait_for(lambda x=x, n=n: (p := port_state(x, n)).get("state") == "unopenable" and p, 20,
                                  f"{x.name}: {n} unopenable")
                    assert "busy" in st["reason"], st
            # C gives up first (so it cannot race B for the devices): it never had one.
            assert c.stop() == 0, c.stderr()
            c_err = c.stderr()
            assert a.stop(signal.SIGTERM) == 0, a.stderr()
            wait_streams_done(em, 60)
            wait_until(lambda: has_last_frames(b_dir, em), 20)
            assert b.stop() == 0, b.stderr()
    finally:
        em.stop()
    ra, rb = logs.read_session(a_dir), logs.read_session(b_dir)
    lost = {}
    for name in ("gps", "imu"):
        ok = sent_ok(getattr(em, name))
        fa, fb = ra.sensors[name].frames(), rb.sensors[name].frames()
        assert fa and fb and fa == ok[:len(fa)] and fb == ok[len(ok) - len(fb):], name
        gap = rb.sensors[name].stamps[0] - ra.sensors[name].stamps[-1]
        lost[name] = (len(ok) - len(fa) - len(fb), gap)
    print("handover: " + ", ".join(f"{n} {k} frames lost, {g * 1e3:.0f} ms from A's last to B's first record"
                                   for n, (k, g) in lost.items()))
    # The IMU streams at 64 Hz: its gap is the handover. The GPS waits for its next 10 Hz slot after the requests.
    assert lost["imu"][1] < 0.5 and lost["gps"][1] < 0.5 + 0.1, lost
    assert not c_dir.exists(), sorted(os.listdir(c_dir))
    assert len(lines_with(c_err, "removed the empty session directory")) == 1, c_err


# --- 7: a nearly full disk at start ----------------------------------------------------------------------


@contextlib.contextmanager
def tmpfs(path: Path, size_kb: int):
    """A small tmpfs at path, or a clear skip where this test may not mount one (as in test_logger_faults)."""
    path.mkdir(parents=True, exist_ok=True)
    if os.geteuid() != 0 or not shutil.which("mount"):
        pytest.skip("mounting a small tmpfs needs root")
    r = subprocess.run(["mount", "-t", "tmpfs", "-o", f"size={size_kb}k,mode=0755", "tmpfs", str(path)],
                       capture_output=True, text=True)
    if r.returncode:
        pytest.skip(f"cannot mount a tmpfs here ({r.stderr.strip()})")
    try:
        yield path
    finally:
        subprocess.run(["umount", "-l", str(path)], capture_output=True)


def leave_free(directory: Path, kb: int) -> None:
    """Fill the file system to the last byte, then give back kb kilobytes."""
    filler = directory / "filler"
    fd = os.open(filler, os.O_WRONLY | os.O_CREAT, 0o644)
    try:
        for size in (1 << 16, 1 << 10, 1):
            while True:
                try:
                    if os.write(fd, b"\0" * size) < size:
                        break
                except OSError:
                    break
        os.ftruncate(fd, max(0, os.fstat(fd).st_size - kb * 1024))
    finally:
        os.close(fd)


def test_nearly_full_disk_at_start_keeps_the_sidecar_current(tmp_path):
    """Started with 48 kB free: the records fill the disk in a few seconds. The sidecar used to stay at an
    early version for the whole run (a new temporary needs free blocks); its versions now reuse their own
    blocks, so the sidecar on disk follows the run to its stop, and its counts are the records on disk."""
    dev, disk = tmp_path / "dev", tmp_path / "disk"
    em = Emulators(dev, StaticSource(16.0, seed=1))
    cfg = write_config(tmp_path / "logger.toml", dev, tmp_path / "sessions")
    session = disk / "session"
    with tmpfs(disk, 1024):
        leave_free(disk, 48)
        try:
            with daemons() as ds:
                d = Daemon(cfg, session, tmp_path / "daemon.log")
                ds.append(d)
                em.start()
                full = wait_for(lambda: (s := read_json(session / "session.json")) and s["disk"]["state"] == "failing"
                                and s, 40, "a sidecar on disk that says the disk is failing")
                lost0 = full["counts"]["imu"]["frames_lost_to_disk_errors"]
                # ...and it keeps following the run while the disk stays full.
                wait_for(lambda: read_json(session / "session.json")["counts"]["imu"]["frames_lost_to_disk_errors"]
                         > lost0 + 64, 20, "sidecar updates while the disk is full")
                wait_streams_done(em, 60)
                wait_all_written(session / "session.json", em, lost_too=True)
                assert d.stop() == 0, d.stderr()
        finally:
            em.stop()
        side = read_json(session / "session.json")
        r = logs.read_session(session)
        summary = dump.session_summary(session)
    assert side["state"] == "stopped"
    for name in ("gps", "imu"):
        c = side["counts"][name]
        assert c["frames_written"] == r.sensors[name].count, name
        assert c["frames_written"] + c["frames_lost_to_disk_errors"] == len(sent_ok(getattr(em, name))), name
    assert side["counts"]["imu"]["frames_lost_to_disk_errors"] > 0
    assert summary["sidecar"]["older_than_records"] is None
    print(f"written {[side['counts'][n]['frames_written'] for n in ('gps', 'imu')]}, lost to the full disk "
          f"{[side['counts'][n]['frames_lost_to_disk_errors'] for n in ('gps', 'imu')]}; sidecar final")


def test_dump_notes_a_sidecar_older_than_the_records(tmp_path):
    """If no sidecar write got through after some point (a disk without room even for the reserved
    versions, then a kill), dump says the sidecar is older than the records rather than trusting its counts."""
    t0 = time.time()
    s = Session(tmp_path / "s", {"imu": SensorInfo("bp3010", 1, settings={"rate_hz": 64})})
    early = json.loads((tmp_path / "s" / "session.json").read_text())  # what a failing disk would have kept
    frame = bp3010.ImuSample((0.0, 0.0, 0.0), (0.0, 0.0, -0.15)).encode()
    for k in range(64):
        s.record("imu", frame, t0 + k / 64)
    s.close()
    assert dump.session_summary(tmp_path / "s")["sidecar"]["older_than_records"] is None
    # That version as if written 30 s before these records (the session went on, its sidecar writes failing).
    for key in ("start", "written"):
        early[key]["realtime"] -= 30.0
    (tmp_path / "s" / "session.json").write_text(json.dumps(early))
    out = dump.session_summary(tmp_path / "s")
    behind = out["sidecar"]["older_than_records"]
    assert behind and 30.0 < behind["behind_s"] < 32.0, behind
    assert out["sensors"]["imu"]["records"] == 64  # the records are all read anyway
    assert "the sidecar is older than the records" in dump_text(tmp_path / "s")

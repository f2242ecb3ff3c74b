"""What a vehicle does to the logger, against the real daemon through ptys: a full or read-only disk, an
unwritable session root, unplugged, locked and forbidden devices, a port closing mid-decision, stamps in order."""

import contextlib
import fcntl
import os
import shutil
import subprocess
import sys
import time
import tomllib
from pathlib import Path

import numpy as np
import pytest

from corpora import bp_frames
from gpsins.session import logs
from gpsins.devices.pty import PtyLink
from gpsins_logger.port import SensorThread
from gpsins_logger.recorder import SensorInfo, Session
from ptyrig import file_size, run_rig, sent_ok, unplug, wait_until, write_config
from systemd_units import exposure, settings


@contextlib.contextmanager
def tmpfs(path, size_kb: int):
    """A small tmpfs at path, or a clear skip where this test may not mount one
    (test_dump_and_disk's /dev/full test then covers the recorder alone)."""
    path.mkdir(parents=True, exist_ok=True)
    if os.geteuid() != 0 or not shutil.which("mount"):
        pytest.skip("mounting a small tmpfs needs root; the /dev/full recorder test covers full disks here")
    r = subprocess.run(["mount", "-t", "tmpfs", "-o", f"size={size_kb}k,mode=0755", "tmpfs", str(path)],
                       capture_output=True, text=True)
    if r.returncode:
        pytest.skip(f"cannot mount a tmpfs here ({r.stderr.strip()}); the /dev/full recorder test covers full disks")
    try:
        yield path
    finally:
        subprocess.run(["umount", "-l", str(path)], capture_output=True)


def fill(path) -> None:
    """Write a file until the file system is full, to the last byte."""
    fd = os.open(path, os.O_WRONLY | os.O_CREAT, 0o644)
    try:
        for size in (1 << 16, 1 << 10, 1):
            while True:
                try:
                    if os.write(fd, b"\0" * size) < size:
                        break
                except OSError:
                    break
    finally:
        os.close(fd)


def without_privileges() -> list[str]:
    """A command prefix that runs the daemon without the root capabilities that
    bypass file modes; [] when not root. Skips where that is not possible."""
    if os.geteuid() != 0:
        return []
    if not shutil.which("setpriv"):
        pytest.skip("root bypasses permission checks and setpriv is missing to drop the capabilities")
    return ["setpriv", "--bounding-set=-all", "--inh-caps=-all", "--"]


def lines_with(text: str, needle: str) -> list[str]:
    return [ln for ln in text.splitlines() if needle in ln]


IMU_RECORD = 1 + 8 + 15  # a BP3010 record: header byte, stamp, the rest of the 16-byte frame


def imu_losing(proc, em, imu_file, frames: int = 32):
    """A condition: the IMU has lost frames to the full disk. The sidecar says so where it can
    still be written; else the IMU file has not grown while the IMU sent `frames` intact frames
    and the daemon has read all the IMU sent (so it tried to write them)."""
    last = {"size": -1, "sent": 0}

    def losing() -> bool:
        if proc.count("imu", "frames_lost_to_disk_errors") > 0:
            return True
        size, sent = file_size(imu_file), len(sent_ok(em.imu))
        if size != last["size"]:
            last.update(size=size, sent=sent)
            return False
        return sent - last["sent"] >= frames and em.imu.pty.unread_bytes() == 0

    return losing


# --- disk --------------------------------------------------------------------------------------------


def test_full_disk_mid_run_is_survived_and_logging_resumes(tmp_path):
    disk = tmp_path / "disk"
    with tmpfs(disk, 2048):
        marks = {}

        def during(proc, em):
            imu_file = proc.session_dir / "imu-000.bin"
            proc.wait_for_frames({"gps": 5, "imu": 32})
            # Fill when the IMU file's last page is nearly used (that page still takes records on a full
            # disk): then the IMU loses frames soon after, not up to a page of records (2.7 s) later.
            page = os.sysconf("SC_PAGE_SIZE")
            proc.wait_for(lambda: 8 * IMU_RECORD <= -file_size(imu_file) % page <= 24 * IMU_RECORD,
                          "the IMU file's last page to be nearly full")
            marks["full"] = time.time()
            fill(disk / "filler")
            proc.wait_for(imu_losing(proc, em, imu_file), "the IMU to lose frames on the full disk")
            (disk / "filler").unlink()
            marks["free"] = time.time()
            proc.wait_for_log("work again")

            def late():
                return any(s.fate == "ok" and s.first_byte_realtime > marks["free"] + 0.5 for s in em.imu.sent)

            proc.wait_for(lambda: late() or em.imu.done.is_set(), "IMU frames sent 0.5 s after the disk was freed")
            assert late(), "the IMU stream ended within 0.5 s of the disk being freed"

        r = run_rig(tmp_path, seconds=6.0, during=during, session_dir=disk / "session",
                    session_extra="raw_reserve_mb = 0")
    assert r.returncode == 0, r.stderr
    assert "Traceback" not in r.stderr
    # One line when writing starts failing, one when it works again naming what was lost.
    assert len(lines_with(r.stderr, "are failing")) == 1, r.stderr
    back = lines_with(r.stderr, "work again")
    assert len(back) == 1 and "imu" in back[0], r.stderr
    assert r.sidecar["state"] == "stopped" and r.sidecar["disk"]["state"] == "ok"
    assert r.sidecar["disk"]["failing_episodes"] == 1
    for name in ("gps", "imu"):
        em = getattr(r.emulators, name)
        ok = [s for s in em.sent if s.fate == "ok"]
        got = r.session.sensors[name].frames()
        c = r.sidecar["counts"][name]
        # Every intact frame was either written or counted as lost; the files hold no torn record.
        assert c["frames_written"] == len(got)
        assert c["frames_written"] + c["frames_lost_to_disk_errors"] == len(ok), name
        assert r.session.sensors[name].stats()["discarded_bytes"] == 0
        # The frames lost are those sent while the disk was full: none after space came back.
        it = iter(got)
        missing, nxt = [], next(it, None)
        for s in ok:
            if s.frame == nxt:
                nxt = next(it, None)
            else:
                missing.append(s.first_byte_realtime)
        assert nxt is None, f"{name}: written frames are not in sent order"
        assert len(missing) == c["frames_lost_to_disk_errors"]
        if missing:
            assert marks["full"] - 0.5 < min(missing) and max(missing) < marks["free"] + 0.5, name
        assert np.count_nonzero(r.session.sensors[name].stamps > marks["free"] + 0.5) > 0, name
    # The files' last partly filled pages take records for a while after the disk is full; then the IMU loses frames.
    lost = {n: r.sidecar["counts"][n]["frames_lost_to_disk_errors"] for n in ("gps", "imu")}
    print(f"frames lost while the disk was full: {lost}; after recovery: 0")
    assert lost["imu"] > 0


def _start_daemon(tmp_path, root, prefix=()):
    for dev in ("gps", "imu"):
        (tmp_path / dev).write_text("")  # the config only checks that the ports exist; no port is opened
    cfg = write_config(tmp_path / "logger.toml", tmp_path, root)
    return subprocess.run([*prefix, sys.executable, "-m", "gpsins_logger.daemon", "--config", str(cfg)],
                          capture_output=True, text=True, timeout=60)


def test_starting_on_a_full_disk_exits_2_and_leaves_nothing(tmp_path):
    disk = tmp_path / "disk"
    with tmpfs(disk, 256):
        fill(disk / "filler")
        p = _start_daemon(tmp_path, disk / "sessions")
        left = sorted(os.listdir(disk))
    assert p.returncode == 2, p.stderr
    assert len(p.stderr.strip().splitlines()) == 1 and "No space left on device" in p.stderr, p.stderr
    assert left == ["filler"]


def test_starting_on_a_read_only_disk_exits_2(tmp_path):
    disk = tmp_path / "disk"
    with tmpfs(disk, 256):
        subprocess.run(["mount", "-o", "remount,ro", str(disk)], check=True)
        p = _start_daemon(tmp_path, disk / "sessions")
    assert p.returncode == 2, p.stderr
    assert len(p.stderr.strip().splitlines()) == 1 and "Read-only file system" in p.stderr, p.stderr


def test_unwritable_session_root_exits_2(tmp_path):
    prefix = without_privileges()
    root = tmp_path / "root"
    root.mkdir()
    root.chmod(0o555)
    p = _start_daemon(tmp_path, root / "sessions", prefix)
    assert p.returncode == 2, p.stderr
    assert len(p.stderr.strip().splitlines()) == 1 and "Permission denied" in p.stderr, p.stderr
    assert os.listdir(root) == []


# --- devices -----------------------------------------------------------------------------------------


def test_replug_is_noticed_within_half_a_second(tmp_path):
    # The shipped back-off settings: a doubling back-off used to wait up to 3.2 s after a replug.
    def during(proc, em):
        # Unplugged once the daemon is seen logging both (not at fixed times a loaded daemon may not have
        # reached), each for 2.5 s, the GPS while the IMU is away.
        proc.wait_for_frames({"gps": 5, "imu": 32})
        unplug(em.imu, 2.5)
        proc.wait_for_state("imu", "absent")
        unplug(em.gps, 2.5)
        for name in ("gps", "imu"):
            proc.wait_for(lambda name=name: (proc.count(name, "reconnects") == 1
                                             and proc.port_state(name).get("state") == "open"),
                          f"the {name} port reopened after its unplug")
        assert not (em.gps.done.is_set() or em.imu.done.is_set()), "the streams ended before both ports were back"

    r = run_rig(tmp_path, seconds=7.0, during=during, reconnect_extra="initial_backoff_s = 0.2\nmax_backoff_s = 5.0")
    assert r.returncode == 0, r.stderr
    for name in ("gps", "imu"):
        em = getattr(r.emulators, name)
        assert len(em.replugged_realtime) == 1
        back = em.replugged_realtime[0]
        stamps = r.session.sensors[name].stamps
        gap = stamps[stamps > back][0] - back
        print(f"{name}: first frame {gap * 1e3:.0f} ms after the replug")
        # GPS: the link reopens, then waits for the next ID 23 slot (0.1 s).
        assert gap < 0.5, f"{name}: first frame {gap * 1e3:.0f} ms after the replug"
        assert r.session.sensors[name].frames() == sent_ok(em), name
        assert r.sidecar["counts"][name]["reconnects"] == 1
    assert lines_with(r.stderr, "is absent")


def test_forbidden_device_is_named_and_retried_when_its_mode_changes(tmp_path):
    prefix = without_privileges()
    seen = {}

    def before(em):
        os.chmod(os.path.realpath(em.imu.pty.link), 0)

    def during(proc, em):
        seen["state"] = proc.wait_for_state("imu", "unopenable")
        os.chmod(os.path.realpath(em.imu.pty.link), 0o660)
        seen["fixed"] = time.time()

    r = run_rig(tmp_path, seconds=4.0, prefix=prefix, before=before, during=during,
                reconnect_extra="unopenable_retry_s = 60")
    assert r.returncode == 0, r.stderr
    assert seen["state"]["state"] == "unopenable" and "Permission denied" in seen["state"]["reason"]
    named = lines_with(r.stderr, "cannot be opened")
    assert len(named) == 1 and "imu" in named[0] and "Permission denied" in named[0], r.stderr
    imu = r.session.sensors["imu"].stamps
    assert len(imu) > 64 and imu[0] - seen["fixed"] < 0.5  # retried at the mode change, not after 60 s
    assert r.session.sensors["gps"].frames() == sent_ok(r.emulators.gps)


def _lock(link):
    fd = os.open(link, os.O_RDWR | os.O_NOCTTY | os.O_NONBLOCK)
    fcntl.flock(fd, fcntl.LOCK_EX | fcntl.LOCK_NB)  # what another serial program holds
    return fd


def test_busy_device_is_retried_on_the_slow_period(tmp_path):
    held = {}

    def before(em):
        held["fd"] = _lock(em.imu.pty.link)

    def during(proc, em):
        held["state"] = proc.wait_for_state("imu", "unopenable")
        os.close(held.pop("fd"))
        held["released"] = time.time()

    try:
        r = run_rig(tmp_path, seconds=4.0, before=before, during=during, reconnect_extra="unopenable_retry_s = 0.4")
    finally:
        if "fd" in held:
            os.close(held["fd"])
    assert r.returncode == 0, r.stderr
    assert held["state"]["state"] == "unopenable" and "busy" in held["state"]["reason"]
    assert len(lines_with(r.stderr, "cannot be opened")) == 1, r.stderr
    imu = r.session.sensors["imu"].stamps
    assert len(imu) > 64 and imu[0] - held["released"] < 0.4 + 0.5
    assert r.sidecar["sensors"]["imu"]["port_state"]["state"] == "open"


def test_config_may_give_up_on_an_unopenable_device(tmp_path):
    held = {}

    def before(em):
        held["fd"] = _lock(em.imu.pty.link)

    try:
        r = run_rig(tmp_path, seconds=2.5, before=before, during=lambda proc, em: proc.wait_for_state("imu", "gave_up"),
                    reconnect_extra="unopenable_retry_s = 0.2\ngive_up_after_s = 0.5")
    finally:
        os.close(held["fd"])
    assert r.returncode == 0, r.stderr
    assert r.sidecar["sensors"]["imu"]["port_state"]["state"] == "gave_up"
    assert len(lines_with(r.stderr, "giving up on")) == 1
    assert r.session.sensors["imu"].count == 0
    assert r.session.sensors["gps"].frames() == sent_ok(r.emulators.gps)  # the other sensor logs on


# --- framing at close, stamp order ------------------------------------------------------------------


def test_frame_pending_confirmation_is_kept_when_the_port_closes(tmp_path):
    """Garbage breaks the BP3010 lock; the intact frame after it waits for a confirming frame, which never comes
    because the device is unplugged. The finder is flushed at close, so the frame is recorded."""
    link = tmp_path / "imu"
    pty = PtyLink(link)
    session = Session(tmp_path / "s", {"imu": SensorInfo("bp3010", 1)})
    thread = SensorThread("imu", "bp3010", str(link), 38400, [], session, poll_interval_s=0.02)
    frames = bp_frames(12)
    try:
        thread.start()
        wait_until(lambda: session.port_state["imu"]["state"] == "open", "the port opened")
        data = b"".join(frames[:10]) + bytes(range(1, 21)) + frames[10]
        for k in range(0, len(data), 16):
            os.write(pty.master, data[k:k + 16])
            time.sleep(0.005)  # the line's pace: 16 bytes at a time
        wait_until(lambda: session.extra_counts["imu"]["bytes_read"] == len(data), f"all {len(data)} bytes read",
                   detail=lambda: f"read {session.extra_counts['imu']['bytes_read']}")
        pty.remove()  # unplug
        wait_until(lambda: session.port_state["imu"]["state"] == "absent", "the port seen absent")
    finally:
        thread.stop()
        thread.join(10)
        pty.remove()
        session.close()
    got = logs.read_record_file(tmp_path / "s" / "imu-000.bin", "bp3010").frames()
    assert got == frames[:11]
    assert session.extra_counts["imu"]["discarded_bytes"] == 20


def test_stamps_of_a_sensor_never_run_backwards_when_bytes_come_faster_than_the_line(tmp_path):
    # At 4x the line's pace under load the first-byte estimate used to run back by up to 16 ms (IMU) and 42 ms (GPS).
    r = run_rig(tmp_path, seconds=12.0, speed=4.0)
    assert r.returncode == 0, r.stderr
    for name in ("gps", "imu"):
        st = r.session.sensors[name].stamps
        assert len(st) > 50 and np.all(np.diff(st) > 0), f"{name}: {np.diff(st).min() * 1e3:.3f} ms back"
        assert r.session.sensors[name].frames() == sent_ok(getattr(r.emulators, name))


# --- the service unit --------------------------------------------------------------------------------

UNIT = Path(__file__).resolve().parents[1] / "logger" / "gpsins-logger.service"


def test_service_unit_keeps_the_daemon_working_and_confined():
    u = settings(UNIT)
    assert u["User"] != ["root"] and "dialout" in " ".join(u.get("SupplementaryGroups", []) + u.get("Group", []))
    assert u["StateDirectory"] == ["gpsins"] and u["ProtectSystem"] == ["strict"]
    root = tomllib.loads((UNIT.parent / "logger.example.toml").read_text())["session"]["root"]
    assert root.startswith("/var/lib/gpsins/"), "the example's session root must be inside the state directory"
    allowed = " ".join(u["DeviceAllow"])
    assert "/dev/gpsins-gps rw" in allowed and "/dev/gpsins-imu rw" in allowed and u["DevicePolicy"] == ["closed"]
    assert u["PrivateNetwork"] == ["yes"] and u["IPAddressDeny"] == ["any"]
    assert u["RestrictAddressFamilies"] == ["AF_UNIX"] and "@system-service" in u["SystemCallFilter"]
    assert u["CapabilityBoundingSet"] == [""] and u["NoNewPrivileges"] == ["yes"]
    assert u["Restart"] == ["on-failure"] and u["RestartPreventExitStatus"] == ["2"]


def test_service_unit_exposure_score():
    assert exposure(UNIT) <= 2.0

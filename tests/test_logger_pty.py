"""The real logger daemon against pty emulators of both devices (no mocks of the serial layer)."""

import os
import signal
import subprocess
import sys

import numpy as np
import pytest

from gpsins.session import layouts
from gpsins.devices.pty import Faults
from gpsins_logger import superstar2 as ss2
from ptyrig import faulted_bytes, file_size, run_rig, sent_ok, unplug


def test_frames_arrive_byte_for_byte_at_nominal_rates(tmp_path):
    r = run_rig(tmp_path, seconds=4.0)
    assert r.returncode == 0, r.stderr
    for name, em in (("gps", r.emulators.gps), ("imu", r.emulators.imu)):
        frames = r.session.sensors[name].frames()
        assert frames == sent_ok(em), name
        assert r.sidecar["counts"][name]["frames_written"] == len(frames)
        assert r.sidecar["counts"][name]["discarded_bytes"] == 0
    assert len(r.session.sensors["imu"].frames()) >= 64 * 3
    # The GPS thread asked for what the config says: link open, ID 23 at 10 Hz, the rest continuously.
    reqs = [ss2.decode_request(f) for f in r.emulators.gps.host_requests]
    assert reqs[0].msg_id == ss2.ID_LINK_OPEN
    assert any(q.msg_id == 23 and q.raw_rate_hz == 10 for q in reqs)
    assert {q.msg_id for q in reqs if q.continuous and q.msg_id != 23} == {20, 21, 22, 49, 75, 113}
    ids = layouts.message_ids(r.session.sensors["gps"].scans[0])
    assert np.count_nonzero(ids == 23) >= 30  # 10 Hz
    # Stamps: first-byte times, increasing, at the IMU's rate.
    imu = r.session.imu()
    dt = np.diff(imu.stamps)
    assert np.all(dt > 0) and abs(np.median(dt) - 1 / 64) < 1e-3
    sent_t = np.array([s.first_byte_realtime for s in r.emulators.imu.sent if s.fate == "ok"])
    lag = imu.stamps - sent_t
    assert np.median(lag) < 0.01 and lag.min() > -0.005


@pytest.mark.parametrize("fault", ["garbage", "bit_flip", "drop", "truncate"])
def test_every_intact_frame_survives_faults(tmp_path, fault):
    faults = dict(garbage=0.0, bit_flip=0.0, drop=0.0, truncate=0.0)
    faults[fault] = 0.15
    r = run_rig(tmp_path, seconds=4.0, gps_faults=Faults(**faults, seed=3), imu_faults=Faults(**faults, seed=4))
    assert r.returncode == 0, r.stderr
    for name, em in (("gps", r.emulators.gps), ("imu", r.emulators.imu)):
        assert any(s.fate != "ok" for s in em.sent) or fault == "garbage"
        assert r.session.sensors[name].frames() == sent_ok(em), name
        c = r.sidecar["counts"][name]
        assert c["discarded_bytes"] + c["unfinished_bytes"] == faulted_bytes(em), name
        if fault == "bit_flip" and name == "gps":
            assert c["checksum_failures"] >= sum(s.fate == "flipped" for s in em.sent)


def test_unplugged_port_is_reopened_while_the_other_keeps_logging(tmp_path):
    def during(proc, em):
        # Each unplug once the daemon is seen logging both (not at a fixed time a loaded daemon may not have reached).
        proc.wait_for_frames({"gps": 5, "imu": 32})
        unplug(em.imu, 0.6)
        proc.wait_for(lambda: proc.count("imu", "reconnects") == 1 and proc.port_state("imu").get("state") == "open",
                      "the IMU reopened after its unplug")
        unplug(em.gps, 0.4)
        proc.wait_for(lambda: proc.count("gps", "reconnects") == 1 and proc.port_state("gps").get("state") == "open",
                      "the GPS reopened after its unplug")
        assert not (em.gps.done.is_set() or em.imu.done.is_set()), "the streams ended before both ports were back"

    r = run_rig(tmp_path, seconds=5.0, during=during)
    assert r.returncode == 0, r.stderr
    for name, em in (("gps", r.emulators.gps), ("imu", r.emulators.imu)):
        assert em.disconnect_count == 1
        assert r.sidecar["counts"][name]["reconnects"] == 1
        assert r.session.sensors[name].frames() == sent_ok(em), name
        assert any(s.fate == "offline" for s in em.sent) or name == "gps"
    # The GPS was re-initialised after the reconnect: its requests came twice.
    opens = [f for f in r.emulators.gps.host_requests if ss2.decode_request(f).msg_id == ss2.ID_LINK_OPEN]
    assert len(opens) == 2
    # The IMU kept logging while the GPS was away, and vice versa.
    gps_t = r.session.sensors["gps"].stamps
    imu_t = r.session.imu().stamps
    gap = (gps_t[np.argmax(np.diff(gps_t))], gps_t[np.argmax(np.diff(gps_t)) + 1])
    assert np.count_nonzero((imu_t > gap[0]) & (imu_t < gap[1])) > 10


@pytest.mark.parametrize("sig", [signal.SIGINT, signal.SIGTERM, signal.SIGTSTP])
def test_clean_stop_on_each_signal(tmp_path, sig):
    r = run_rig(tmp_path, seconds=1.5, stop_signal=sig)
    assert r.returncode == 0, r.stderr
    assert r.sidecar["state"] == "stopped" and r.sidecar["stop"]["realtime"] > r.sidecar["start"]["realtime"]
    for name in ("gps", "imu"):
        assert r.sidecar["counts"][name]["frames_written"] == r.session.sensors[name].count > 0
    assert os.path.getsize(r.session.directory / "imu-000.raw") > 0  # raw capture on by default for the IMU
    lines = (r.session.directory / "clock.csv").read_text().splitlines()
    assert lines[0] == "realtime,monotonic" and len(lines) >= 3


def test_sighup_starts_a_new_part(tmp_path):
    record = 1 + 8 + 15  # a BP3010 record: header byte, stamp, the rest of the 16-byte frame

    def hup(proc, em):
        proc.wait_for_frames({"imu": 21})
        proc.send_signal(signal.SIGHUP)
        second = proc.session_dir / "imu-001.bin"
        proc.wait_for(lambda: file_size(second) > 20 * record or em.imu.done.is_set(), "21 IMU records in part 1")
        assert file_size(second) > 20 * record, "the IMU stream ended before part 1 had 21 records"

    r = run_rig(tmp_path, seconds=3.0, during=hup)
    assert r.returncode == 0, r.stderr
    assert r.sidecar["sensors"]["imu"]["files"] == ["imu-000.bin", "imu-001.bin"]
    scans = r.session.sensors["imu"].scans
    assert all(s.count > 20 for s in scans)
    assert r.session.sensors["imu"].frames() == sent_ok(r.emulators.imu)


def test_sigkill_leaves_files_the_reader_accepts(tmp_path):
    def kill(proc, em):
        proc.wait_for_frames({"gps": 10, "imu": 32})  # mid-stream, with records in both files
        proc.kill()

    r = run_rig(tmp_path, seconds=2.5, during=kill)
    assert r.returncode == -signal.SIGKILL
    assert r.sidecar["state"] == "running"
    for name in ("gps", "imu"):
        st = r.session.sensors[name].stats()
        assert r.session.sensors[name].count > 0 and st["discarded_bytes"] == 0
        # What was written is a prefix of what was sent.
        frames = r.session.sensors[name].frames()
        assert frames == sent_ok(getattr(r.emulators, name))[:len(frames)]


def test_imu_rate_select(tmp_path):
    r = run_rig(tmp_path, seconds=2.0, imu_rate_hz=16)
    assert b"\x7b\x8a" in r.emulators.imu.host_requests
    imu = r.session.imu()
    assert abs(np.median(np.diff(imu.stamps)) - 1 / 16) < 2e-3
    # At 16 Hz the LSB is 4x coarser and gravity's increment 4x larger: still about -g dt.
    assert np.median(imu.dv_mps[:, 2]) == pytest.approx(-9.8186 / 16, abs=0.01)


@pytest.mark.parametrize("edit,message", [
    ('[gps]\nport = "{gps}"\nbaud = 12345\n', "gps.baud"),
    ('[gps]\nport = "{gps}"\nspeed = 3\n', "unknown key 'gps.speed'"),
    ('[imu]\nport = "/nonexistent/imu"\n', "'imu.port' = '/nonexistent/imu' does not exist"),
    ('[imu]\nport = "{gps}"\nrate_hz = 100\n', "imu.rate_hz"),
    ('[gpss]\nport = "x"\n', "unknown section [gpss]"),
    ('[session]\nroot = "x"\n', "at least one sensor"),
])
def test_config_errors_stop_before_anything_is_opened(tmp_path, edit, message):
    (tmp_path / "gpsdev").write_text("")
    cfg = tmp_path / "bad.toml"
    cfg.write_text(edit.format(gps=tmp_path / "gpsdev"))
    p = subprocess.run([sys.executable, "-m", "gpsins_logger.daemon", "--config", str(cfg), "--session-dir",
                        str(tmp_path / "s")], capture_output=True, text=True, timeout=30)
    assert p.returncode == 2
    assert message in p.stderr and str(cfg) in p.stderr
    assert len(p.stderr.strip().splitlines()) == 1
    assert not (tmp_path / "s").exists()

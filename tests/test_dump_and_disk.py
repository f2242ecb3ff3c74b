"""`gpsins dump` on sessions written directly by the recorder, and the recorder on a full disk."""

import csv
import io
import json
import logging
import os
import time

import numpy as np

from gpsins.session import dump
from gpsins.cli import main as cli_main
from gpsins.devices.sources import StaticSource
from gpsins_logger import bp3010
from gpsins_logger import superstar2 as ss2
from gpsins_logger.files import DiskHealth
from gpsins_logger.recorder import SensorInfo, Session

T0 = time.time()  # the stamps must lie inside the session the recorder opens now


def _write_session(path, seconds=5.0, damage_gps_at=None):
    src = StaticSource(seconds, seed=2)
    s = Session(path, {"gps": SensorInfo("superstar2", ss2.HEADER_LEN),
                       "imu": SensorInfo("bp3010", 1, settings={"rate_hz": 64})})
    gps = list(src.gps_messages())
    imu = list(src.imu_samples(64))
    for m in gps:
        s.record("gps", m.frame, T0 + m.t)
    for k, smp in enumerate(imu):
        smp.sample.counter = (k + 1) & 0xFF
        s.record("imu", smp.sample.encode(), T0 + smp.t)
    s.close()
    # The records were written at once: let the sidecar span the time they claim.
    side = json.loads((path / "session.json").read_text())
    side["start"]["realtime"] = min(T0, side["start"]["realtime"])
    side["stop"]["realtime"] = max(T0 + seconds, side["stop"]["realtime"])
    (path / "session.json").write_text(json.dumps(side))
    if damage_gps_at is not None:
        f = path / "gps-000.bin"
        data = bytearray(f.read_bytes())
        data[damage_gps_at:damage_gps_at] = b"\x55" * 7  # garbage between records
        f.write_bytes(bytes(data))
    return gps, imu


def test_summary_counts_match_what_was_written(tmp_path):
    gps, imu = _write_session(tmp_path / "s")
    out = dump.session_summary(tmp_path / "s")
    g, i = out["sensors"]["gps"], out["sensors"]["imu"]
    assert g["records"] == len(gps) and i["records"] == len(imu)
    by_id = {int(k): v["records"] for k, v in g["messages"].items()}
    assert by_id == {mid: sum(m.msg_id == mid for m in gps) for mid in {m.msg_id for m in gps}}
    assert abs(g["messages"]["23"]["rate_hz"] - 10.0) < 1e-6
    assert i["rate_hz"] == 64 and i["missing_by_counter"] == 0 and i["invalid"] == 0
    assert abs(i["duration_s"] - (imu[-1].t - imu[0].t)) < 1e-9


def test_damage_is_reported_with_its_offset(tmp_path):
    gps, _ = _write_session(tmp_path / "s")
    first_len = len(gps[0].frame) + 8
    _write_session(tmp_path / "d", damage_gps_at=first_len)
    out = dump.session_summary(tmp_path / "d")
    g = out["sensors"]["gps"]
    assert g["records"] == len(gps)  # nothing good lost
    assert g["discarded_bytes"] == 7
    assert g["damage"][0]["first_discarded_offset"] == first_len


def test_cli_json_and_csv(tmp_path, capsys):
    gps, imu = _write_session(tmp_path / "s")
    assert cli_main(["dump", str(tmp_path / "s"), "--format", "json"]) == 0
    js = json.loads(capsys.readouterr().out)
    assert js["sensors"]["imu"]["records"] == len(imu)
    assert cli_main(["dump", str(tmp_path / "s"), "--csv"]) == 0
    rows = list(csv.DictReader(io.StringIO(capsys.readouterr().out)))
    imu_rows = [r for r in rows if r["sensor"] == "imu"]
    assert len(rows) == len(gps) + len(imu)
    # The CSV's increments are the frame's quantised values, decoded independently here.
    dec = bp3010.ImuSample.decode(imu[10].sample.encode())
    assert np.allclose([float(imu_rows[10][f"dtheta_{a}_rad"]) for a in "xyz"], dec.dtheta_rad, rtol=0, atol=0)
    assert float(imu_rows[10]["stamp_s"]) == T0 + imu[10].t


def test_cli_raw_superstar2_capture(tmp_path, shared_data, capsys):
    assert cli_main(["dump", "--raw", "superstar2", str(shared_data / "superstar2_gpsd_sample.bin"),
                     "--format", "json"]) == 0
    js = json.loads(capsys.readouterr().out)
    # The data README: 30 whole frames, 8/8/7/7 by message, a truncated ID 23 at offset 2099.
    assert js["frames"] == 30 and sorted(js["messages"].values()) == [7, 7, 8, 8]
    assert js["truncated_tail_offset"] == 2099


def test_dump_names_a_missing_session(tmp_path, capsys):
    assert cli_main(["dump", str(tmp_path / "nope")]) == 2
    assert "nope: no such directory" in capsys.readouterr().err


def test_full_disk_is_counted_not_raised(tmp_path, caplog, monkeypatch):
    caplog.set_level(logging.INFO, logger="gpsins_logger")
    monkeypatch.setattr(DiskHealth, "QUIET_S", 0.0)  # recovery at the first good write, not 1 s later
    t0 = time.time()
    s = Session(tmp_path / "s", {"imu": SensorInfo("bp3010", 1)})
    frame = bp3010.ImuSample((0.0, 0.0, 0.0), (0.0, 0.0, -0.15)).encode()
    assert s.record("imu", frame, t0)
    full = os.open("/dev/full", os.O_WRONLY)
    saved = os.dup(s._records["imu"]._fd)
    try:
        os.dup2(full, s._records["imu"]._fd)  # every write now fails with ENOSPC
        assert not s.record("imu", frame, t0 + 0.1)
        assert not s.record("imu", frame, t0 + 0.2)
        saved_clock = os.dup(s._clock._fd)
        os.dup2(full, s._clock._fd)
        assert not s.clock_pair()  # counted, not raised
        s.sync()
        os.dup2(saved_clock, s._clock._fd)
        os.close(saved_clock)
        assert s.sidecar()["disk"]["state"] == "failing"
    finally:
        os.dup2(saved, s._records["imu"]._fd)
        os.close(saved)
        os.close(full)
    assert s.record("imu", frame, t0 + 0.3)  # the disk came back: logging goes on
    s.close()
    side = s.sidecar()
    c = side["counts"]["imu"]
    assert c["frames_written"] == 2 and c["frames_lost_to_disk_errors"] == 2 and c["write_errors"] >= 2
    assert side["disk"]["state"] == "ok" and side["disk"]["failing_episodes"] == 1
    assert side["disk"]["clock_write_errors"] >= 1
    # One line when failing starts, one when it ends with what was lost; nothing in between.
    lines = [r.getMessage() for r in caplog.records if "disk writes" in r.getMessage()]
    assert len(lines) == 2 and "failing" in lines[0] and "work again" in lines[1] and "imu 2 frames" in lines[1]
    stamps = dump.logs.read_session(tmp_path / "s").sensors["imu"].stamps
    assert stamps.tolist() == [t0, t0 + 0.3]

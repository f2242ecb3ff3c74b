"""A u-blox receiver as a logger device: UBX protocol, set-up handshake, records, emulator, replay.

Real ptys and the real logger daemon; pyubx2 is the independent reference for
the configuration keys and for what a UBX stream holds."""

import io
import json
import math
import signal
import struct
from collections import Counter
from pathlib import Path

import numpy as np
import pytest
from pyubx2 import NMEA_PROTOCOL, UBX_PROTOCOL, UBXReader
from pyubx2.ubxtypes_configdb import UBX_CONFIG_DATABASE

from gpsins.session import logs, measurements_ubx
from gpsins.session import scan as log_scan
from gpsins.session import layouts
from gpsins import mainjob, sim
from gpsins.timing import envelope
from gpsins.replay import run
from gpsins.devices.pty import Faults
from gpsins.devices.ublox import UbloxEmulators
from gpsins.sim import ublox as sim_ublox
from gpsins.sim.scenario import parse
from gpsins.formats.truth import write_truth
from gpsins.sim.ublox import UbloxSimSource
from gpsins.devices.sources import UbxCaptureSource
from gpsins_logger import config as logger_config
from gpsins_logger import ubx
from gpsins_logger.framing import FrameFinder
from ptyrig import host_wrote, start_daemon, wait_until_quiet

START = {"gps_week": 1590, "gps_tow_s": 419400.0, "lat_deg": 59.37, "lon_deg": 17.95, "height_m": 30.0,
         "heading_deg": 160.0}
DRIVE = [{"label": "stand", "duration_s": 8, "speed_mps": 0},
         {"label": "go", "duration_s": 6, "speed_mps": 8},
         {"label": "curve", "duration_s": 10, "turn_deg": 70},
         {"label": "on", "duration_s": 8, "speed_mps": 11}]
STAND = [{"label": "stand", "duration_s": 6, "speed_mps": 0}]
WALK = "walk_0827/gnss_1730.ubx"


def _sim(segments, seed=7):
    return sim.simulate(parse({"name": "short", "start": START, "segment": segments}), seed=seed)


def _pyubx2_frames(data: bytes) -> tuple[list[bytes], int]:
    """UBX frames and the number of NMEA sentences pyubx2 finds in a stream."""
    frames, nmea = [], 0
    for raw, _ in UBXReader(io.BytesIO(data), protfilter=UBX_PROTOCOL | NMEA_PROTOCOL, quitonerror=0):
        if raw[:2] == b"\xb5\x62":
            frames.append(raw)
        else:
            nmea += 1
    return frames, nmea


# --- protocol, without ports -----------------------------------------------------------------


def test_configuration_key_ids_are_u_bloxs():
    for key, name in ubx.KEY_NAMES.items():
        want, typ = UBX_CONFIG_DATABASE[name.replace("-", "_")]
        assert key == want, name
        assert ubx.value_bytes(key) == {"U": int(typ[1:]), "E": int(typ[1:]), "L": 1}[typ[0]], name


def test_frames_and_valset_agree_with_pyubx2():
    steps = ubx.setup_steps(9, "uart1", 5.0, ["RXM-RAWX", "NAV-PVT", "ESF-RAW"])
    (_, msg), = UBXReader(io.BytesIO(steps[0].frame), msgmode=1)  # a SET message, as the receiver sees it
    assert msg.identity == "CFG-VALSET" and (msg.ram, msg.bbr, msg.flash) == (1, 0, 0)
    assert msg.CFG_RATE_MEAS == 200 and msg.CFG_MSGOUT_UBX_RXM_RAWX_UART1 == 1
    assert msg.CFG_MSGOUT_UBX_ESF_RAW_UART1 == 1 and msg.CFG_MSGOUT_UBX_NAV_PVT_UART1 == 1
    layers, items = ubx.parse_valset(ubx.decode_frame(steps[0].frame)[1])
    assert layers == ubx.LAYER_RAM and (ubx.CFG_RATE_MEAS, 200) in items
    gen8 = ubx.setup_steps(8, "uart1", 10.0, ["RXM-RAWX"])
    (_, rate), = UBXReader(io.BytesIO(gen8[0].frame), msgmode=1)
    assert rate.identity == "CFG-RATE" and rate.measRate == 100 and rate.timeRef == 1
    (_, m), = UBXReader(io.BytesIO(gen8[1].frame), msgmode=1)
    # The short form (class, id, rate on this port); pyubx2 reads its one rate as the first port's.
    assert m.identity == "CFG-MSG" and ubx.decode_frame(gen8[1].frame)[1] == bytes((0x02, 0x15, 1))
    assert m.rateDDC == 1 and m.rateUART1 == 0


def test_simulated_messages_decode_in_pyubx2_as_the_simulation_says():
    s = _sim(STAND)
    msgs = sim_ublox.messages(s)
    stream = b"".join(m.frame for m in msgs)
    frames, nmea = _pyubx2_frames(stream)
    assert len(frames) == sum(m.msg_id != "NMEA" for m in msgs) and nmea == sum(m.msg_id == "NMEA" for m in msgs)
    parsed = [p for _, p in UBXReader(io.BytesIO(stream), protfilter=UBX_PROTOCOL)]
    raw = [p for p in parsed if p.identity == "RXM-RAWX"]
    g = s.gnss
    k = 5
    j = np.flatnonzero(g.tracked[k])
    assert math.isclose(raw[k].rcvTow, g.tow_rx[k]) and raw[k].numMeas == len(j)
    assert math.isclose(raw[k].prMes_01, g.pseudorange_m[k, j[0]]) and raw[k].svId_01 == j[0] + 1
    pvt = [p for p in parsed if p.identity == "NAV-PVT"]
    f = g.fixes[2]
    assert pvt[2].iTOW == round(f.tow_s * 1000)
    assert abs(pvt[2].lat - math.degrees(f.llh[0])) < 1e-7 and abs(pvt[2].hAcc - 3000 * f.hdop) < 1.0
    esf = [p for p in parsed if p.identity == "ESF-RAW"]
    # First sample's z gyro (type 5), deg/s * 2^-12, against the simulated increment over its period.
    period = np.median(np.diff(s.imu_t))
    words = [int.from_bytes(getattr(esf[0], f"data_{i:02d}"), "little") for i in range(1, 7)]
    assert [w >> 24 for w in words] == [14, 13, 5, 16, 17, 18]  # gyro x y z, accel x y z
    z = words[2] & 0xFFFFFF
    z = z - (1 << 24) if z >> 23 else z
    assert abs(z * 2.0 ** -12 - math.degrees(s.imu_dtheta[0, 2] / period)) <= 2.0 ** -12
    # The LNAV subframes decode (parity, IODE sets) to the simulator's ephemerides and Klobuchar.
    u = measurements_ubx.ubx_reader.parse(stream)
    assert {e.prn for e in u.navigation.ephemerides} == set(g.fixes[0].prns)
    assert np.allclose(u.navigation.alpha, g.ion_alpha, rtol=1e-2, atol=1e-9)


def _stream_with_everything(rng, n=300):
    """UBX frames with NMEA, garbage and damaged frames between them; returns (stream, intact frames, sentences)."""
    out, good, sentences = bytearray(), [], 0
    for k in range(n):
        payload = rng.integers(0, 256, int(rng.integers(0, 120)), dtype=np.uint8).tobytes()
        frame = ubx.encode_frame((int(rng.integers(1, 16)), int(rng.integers(0, 256))), payload)
        u = rng.random()
        if u < 0.1:  # bit flip
            b = bytearray(frame)
            bit = int(rng.integers(0, 8 * len(b)))
            b[bit // 8] ^= 1 << bit % 8
            out += b
        elif u < 0.2:  # truncated
            out += frame[:int(rng.integers(1, len(frame) - 1))]
        else:
            out += frame
            good.append(frame)
        if rng.random() < 0.3:
            out += rng.integers(0, 256, int(rng.integers(1, 40)), dtype=np.uint8).tobytes()
        if rng.random() < 0.3:
            body = f"GPGSV,3,{k % 3 + 1},11,{k % 32:02d},45,123,40"
            cs = 0
            for ch in body.encode():
                cs ^= ch
            out += f"${body}*{cs:02X}\r\n".encode()
            sentences += 1
    return bytes(out), good, sentences


def test_streaming_finder_resyncs_and_counts_nmea_in_any_chunking():
    rng = np.random.default_rng(5)
    stream, good, sentences = _stream_with_everything(rng)
    for _trial in range(3):
        finder, nmea = FrameFinder(ubx.FRAMING), ubx.NmeaCounter()
        got, i = [], 0
        while i < len(stream):
            n = int(rng.integers(1, 300))
            nmea.feed(stream[i:i + n])
            got += [f.data for f in finder.feed(stream[i:i + n])]
            i += n
        got += [f.data for f in finder.flush()]
        assert got == good
        assert nmea.sentences == sentences
    # The file reader (a second implementation, NumPy checksums) finds the same frames and sentences.
    counts = Counter()
    found, _ = measurements_ubx.ubx_reader.split_frames(stream, counts)
    assert [stream[p:start + n + 2] for p, _, _, start, n in found] == good
    assert counts["NMEA sentences"] == sentences


def test_record_file_reader_takes_ubx_records_and_reports_damage():
    rng = np.random.default_rng(9)
    frames = [ubx.encode_frame((2, 0x15), rng.integers(0, 256, int(rng.integers(0, 300)), dtype=np.uint8).tobytes())
              for _ in range(200)]
    recs = [f[:6] + struct.pack("<d", 1.7e9 + 0.1 * k) + f[6:] for k, f in enumerate(frames)]
    data = bytearray(b"".join(recs))
    s = log_scan.scan(bytes(data), layouts.UBX_RECORDS)
    assert s.frames() == frames and np.allclose(s.stamps, 1.7e9 + 0.1 * np.arange(200))
    # Damage record 50 (its checksum fails), garbage before record 120, a truncated last record.
    at = sum(map(len, recs[:50])) + 20
    data[at] ^= 0x10
    cut = sum(map(len, recs[:120]))
    damaged = bytes(data[:cut]) + b"\xb5\x62\x00garbage" + bytes(data[cut:-5])
    s = log_scan.scan(damaged, layouts.UBX_RECORDS)
    assert s.frames() == frames[:50] + frames[51:199]
    assert s.stats["truncated_tail_bytes"] == len(recs[-1]) - 5
    assert s.stats["discarded_bytes"] == len(recs[50]) + 10


def test_esf_time_tags_give_sample_indices_with_gaps():
    tags = np.round(np.arange(0, 400) * 1e6 / 64).astype(np.int64) % (1 << 32)
    keep = np.r_[0:100, 130:400]  # a lost ESF-RAW: 30 samples
    e = measurements_ubx.EsfSamples(tags[keep] + (1 << 32) - 3000, 1000.0 + keep / 64.0, np.zeros((len(keep), 3)),
                                    np.ones((len(keep), 3)))
    e.tags %= 1 << 32  # the tags wrap in the middle
    imu = measurements_ubx.esf_imu_log(e)
    assert imu.rate_hz == 64
    steps = np.diff(imu.counter.astype(int)) % 256
    assert steps[99] == 31 and np.all(np.delete(steps, 99) == 1)
    assert np.allclose(imu.dv_mps, 1 / 64)


def test_config_validation_names_the_key(tmp_path):
    base = {"gps": {"device": "ublox", "port": "/dev/null"}}
    cfg = logger_config.from_dict(base, check_ports=False)
    assert isinstance(cfg.gps, logger_config.UbloxConfig) and cfg.gps.measurement_rate_hz == 10.0
    for key, value, message in (("messages", ["NAV-SAT"], "gps.messages"), ("generation", 7, "gps.generation"),
                                ("interface", "spi", "gps.interface"), ("device", "trimble", "gps.device"),
                                ("link_open", True, "gps.link_open")):
        with pytest.raises(logger_config.ConfigError, match=message.replace(".", r"\.")):
            logger_config.from_dict({"gps": {**base["gps"], key: value}}, check_ports=False)


# --- through ptys, with the real daemon ------------------------------------------------------


def _config(path: Path, devdir: Path, root: Path, baud: int, extra: str = "", bp3010: bool = False) -> Path:
    imu = f'[imu]\nport = "{devdir / "imu"}"\n' if bp3010 else ""
    path.write_text(f"""
[session]
root = "{root}"
fsync_interval_s = 0.2
clock_pair_interval_s = 0.5
[gps]
device = "ublox"
port = "{devdir / 'gps'}"
baud = {baud}
ack_timeout_s = 1.0
{extra}
{imu}""")
    return path


def _record(tmp: Path, source, *, speed=1.0, baud=460800, faults=None, config_fault=None, serve_all=False,
            bp3010=False, extra='messages = ["RXM-RAWX", "RXM-SFRBX", "NAV-PVT", "NAV-TIMEGPS", "ESF-RAW"]'):
    em = UbloxEmulators(tmp / "dev", source, speed=speed, gps_faults=faults, gps_baud=baud, bp3010=bp3010,
                        config_fault=config_fault, serve_all=serve_all)
    cfg = _config(tmp / "logger.toml", tmp / "dev", tmp / "sessions", baud, extra, bp3010)
    session = tmp / "session"
    proc = None
    try:
        proc = start_daemon(cfg, session)
        # The receiver sends NMEA from its start whether or not anyone listens (the first GGA 30 ms in at
        # speed 2): it starts once the daemon has opened its ports and written to them (the open flushes
        # what came before), not at once, where a loaded daemon's late open lost the first sentence.
        proc.wait_for(lambda: all(host_wrote(d) for d in em.devices), "the daemon's first request on every port")
        em.start()
        assert em.wait(source.duration_s / speed + 60), "emulators did not finish"
        # The last frames through the logger: the set-up handshake answered (or timed out), then everything read
        # (the receiver's NMEA does not wait for the host, so the bytes sent are not all the daemon can read).
        proc.wait_for(lambda: _handshake_done(proc.sidecar()), "the receiver set-up to finish")
        wait_until_quiet(proc, {"gps": em.gps, **({"imu": em.imu} if em.imu else {})})
        proc.send_signal(signal.SIGINT)
        err = proc.finish(timeout=30)
    finally:
        if proc is not None and proc.poll() is None:
            proc.kill()
            proc.wait()
        em.stop()
    assert proc.returncode == 0, err
    return em, logs.read_session(session), json.loads((session / "session.json").read_text()), err


def _handshake_done(sidecar: dict) -> bool:
    rec = sidecar.get("sensors", {}).get("gps", {}).get("receiver")
    return bool(rec) and all(step["result"] != "pending" for step in rec["configuration"])


def _sent(em, kind="ubx"):
    return [s for s in em.gps.sent if (s.frame[0] == ubx.SYNC1) == (kind == "ubx")]


@pytest.mark.parametrize("fault", [None, "nak", "silent"])
def test_configuration_handshake(tmp_path, fault):
    em, session, side, err = _record(tmp_path, UbloxSimSource(_sim(STAND)), speed=2.0, config_fault=fault)
    rec = side["sensors"]["gps"]["receiver"]
    (step,) = rec["configuration"]
    assert step["message"] == "CFG-VALSET" and step["settings"]["CFG-MSGOUT-UBX_RXM_RAWX_UART1"] == 1
    # What the daemon sent is what the sidecar says it sent.
    assert bytes.fromhex(step["frame_hex"]) in em.gps.host_requests
    frames = session.sensors["gps"].frames()
    assert frames == [s.frame for s in _sent(em) if s.fate == "ok"]
    nmea_sent = sum(s.fate == "ok" for s in _sent(em, "nmea"))
    assert nmea_sent >= 4 and side["counts"]["gps"]["nmea_sentences"] == nmea_sent
    names = [ubx.name_of((f[2], f[3])) for f in frames]
    if fault is None:
        assert step["result"] == "ack" and rec["version"]["software"] == em.gps.SOFTWARE
        assert names.count("RXM-RAWX") >= 30 and "ESF-RAW" in names and "NAV-PVT" in names
        assert em.gps.meas_rate_hz == 10.0
    elif fault == "nak":
        assert step["result"] == "nak" and "refused (ACK-NAK) CFG-VALSET" in err
        assert set(names) == {"MON-VER", "ACK-NAK"}  # unconfigured: NMEA only, still logged
    else:
        assert step["result"] == "no answer" and rec["version"] is None and "no ACK for CFG-VALSET" in err
        assert names == []


def test_frames_byte_for_byte_under_garbage_bit_flips_and_truncation(tmp_path):
    faults = Faults(garbage=0.15, bit_flip=0.08, truncate=0.08, seed=11)
    em, session, side, _ = _record(tmp_path, UbloxSimSource(_sim(STAND, seed=3)), speed=2.0, faults=faults)
    ubx_sent = _sent(em)
    assert {"flipped", "truncated"} <= {s.fate for s in ubx_sent} and em.gps.garbage_bytes > 0
    assert session.sensors["gps"].frames() == [s.frame for s in ubx_sent if s.fate == "ok"]
    c = side["counts"]["gps"]
    assert c["checksum_failures"] >= sum(s.fate == "flipped" for s in ubx_sent)
    assert c["nmea_sentences"] == sum(s.fate == "ok" for s in _sent(em, "nmea"))


def test_walk_capture_served_and_recorded_gives_pyubx2s_frames(tmp_path, shared_data):
    path = shared_data / WALK
    src = UbxCaptureSource(path)
    want, nmea = _pyubx2_frames(path.read_bytes())
    assert src.ubx_frames == want  # the emulator serves the file as it is
    speed = 20.0
    em, session, side, _ = _record(tmp_path, src, speed=speed, serve_all=True)
    got = session.sensors["gps"].frames()
    replies = {ubx.ACK_ACK, ubx.MON_VER}
    assert [f for f in got if (f[2], f[3]) not in replies] == want
    assert side["counts"]["gps"]["nmea_sentences"] == nmea
    assert side["sensors"]["gps"]["receiver"]["configuration"][0]["result"] == "ack"
    # At its own timing: the recorded RAWX stamps follow the receiver's clock (at the served speed).
    st = session.sensors["gps"].stamps
    raw = [k for k, f in enumerate(got) if (f[2], f[3]) == ubx.RXM_RAWX]
    tow = np.array([struct.unpack_from("<d", got[k], 6)[0] for k in raw])
    # Along the lower envelope (timing's, as the alignment does it): a loaded host stamps a frame late,
    # never early, so a least-squares line through stalls is no measure of the serving rate (it failed
    # 2 runs of 8 under load with 0.25). Served at once the slope would be 0; at its timing 1 / speed.
    _, slope = envelope.lower_envelope(tow - tow[0], st[raw] - st[raw][0])
    print(f"RAWX stamps against their time of week: slope x speed {slope * speed:.4f}")
    assert abs(slope * speed - 1.0) < 0.05


@pytest.mark.parametrize("imu", ["esf", "bp3010"])
def test_simulated_drive_replays_loose_and_tight_inside_3_sigma(tmp_path, imu):
    # Over 30 s: the receiver repeats the ephemerides every 30 s (as GPS broadcasts them), and the
    # first set may go out before the logger has set the receiver up.
    s = _sim(DRIVE)
    write_truth(s, tmp_path / "truth.npz")
    speed = 2.0
    if imu == "esf":  # the main job's own path: gpsins run --device ublox
        session = logs.read_session(mainjob.record_drive(s, tmp_path, speed, device="ublox"))
    else:
        messages = '["RXM-RAWX", "RXM-SFRBX", "NAV-PVT", "NAV-TIMEGPS"]'
        em, session, _, _ = _record(tmp_path, UbloxSimSource(s, sensors=False), speed=speed, bp3010=True,
                                    extra=f"messages = {messages}")
    assert set(session.sensors) == ({"gps"} if imu == "esf" else {"gps", "imu"})
    lat = mainjob.replay_latencies("ublox", speed)
    if imu == "bp3010":
        lat = mainjob.replay_latencies("superstar2", speed) | {"gps_latency_s": lat["gps_latency_s"]}
    for mode in ("loose", "tight"):
        res = run.replay(session.directory, tmp_path / mode, mode=mode, **lat)
        sm = res.summary
        # Every IMU sample sent is replayed, without gaps. The receiver sends ESF-RAW only once the
        # logger has set it up (and the BP3010 once asked for its rate): a loaded host starts later.
        assert sm["alignment"]["imu_frames_missing"] == 0
        if imu == "bp3010":
            assert sm["imu_samples"] == sum(x.fate == "ok" for x in em.imu.sent)
        else:
            assert len(s.imu_t) - 5 * s.imu_rate_hz < sm["imu_samples"] <= len(s.imu_t)
        e = sm["errors"]
        assert e["inside_3_sigma"] >= 0.95, (mode, e)
        assert e["horizontal_rms_m"] < 5.0 and e["vertical_rms_m"] < 5.0, (mode, e)
        if mode == "tight":
            assert sm["counters"]["pseudoranges_used"] > 0
        else:
            assert sm["counters"]["fixes_accepted"] >= s.scenario.duration_s / 2


def test_example_config_loads():
    root = Path(__file__).resolve().parents[1]
    cfg = logger_config.load(root / "logger" / "logger.ublox.example.toml", check_ports=False)
    assert cfg.gps.device == "ublox" and cfg.gps.baud == 460800 and "ESF-RAW" in cfg.gps.messages
    (step,) = cfg.gps.setup().steps
    assert step.settings["CFG-RATE-MEAS"] == 100


def test_receiver_is_set_up_again_after_a_replug(tmp_path):
    faults = Faults(disconnects=[(2.5, 0.5)])
    em, session, side, err = _record(tmp_path, UbloxSimSource(_sim(STAND)), speed=1.0, faults=faults)
    assert side["counts"]["gps"]["reconnects"] == 1
    # The replug lost the receiver's RAM configuration; the logger sent it again and it was acknowledged.
    assert em.gps.config_log == [("CFG-VALSET", "ack"), ("CFG-VALSET", "ack")]
    assert side["sensors"]["gps"]["receiver"]["configuration"][0]["result"] == "ack"
    st, frames = session.sensors["gps"].stamps, session.sensors["gps"].frames()
    raw_t = np.array([t for t, f in zip(st, frames) if (f[2], f[3]) == ubx.RXM_RAWX])
    back = em.gps.replugged_realtime[0]
    assert np.sum(raw_t > back) >= 10 and np.sum(raw_t < back) >= 5


def test_command_line_offers_the_device():
    from gpsins.cli import build_parser

    a = build_parser().parse_args(["run", "--device", "ublox", "--speed", "4"])
    assert a.device == "ublox" and a.speed == 4.0
    a = build_parser().parse_args(["emulate", "--device", "ublox", "--ubx", "x.ubx", "--config-fault", "nak"])
    assert (a.device, a.ubx, a.config_fault, a.baud) == ("ublox", "x.ubx", "nak", 460800)
    assert build_parser().parse_args(["run"]).device == "superstar2"


# --- sessions written directly (no ptys): the decoding against the simulation -----------------


def _write_session(directory: Path, s, names: set[str], t0: float = 1.7e9) -> Path:
    """A u-blox session as the logger writes it, each message stamped at its emission time."""
    from gpsins_logger.recorder import SensorInfo, Session

    info = SensorInfo("ublox", ubx.HEADER_LEN, False, {"port": "sim", "baud": 460800})
    session = Session(directory, {"gps": info})
    session.start = {"realtime": t0 - 1.0, "monotonic": 0.0}
    for m in sim_ublox.messages(s):
        if m.msg_id in names:
            session.record("gps", m.frame, t0 + m.t)
    session.close()
    side = json.loads((directory / "session.json").read_text())
    side["start"]["realtime"], side["stop"]["realtime"] = t0 - 1.0, t0 + s.scenario.duration_s + 1.0
    (directory / "session.json").write_text(json.dumps(side))
    (directory / "clock.csv").write_text("realtime,monotonic\n")
    return directory


def test_decoded_ublox_session_equals_the_simulation(tmp_path):
    s = _sim(DRIVE[:2])
    d = _write_session(tmp_path / "session", s, {"RXM-RAWX", "RXM-SFRBX", "NAV-PVT", "ESF-RAW"})
    dec = measurements_ubx.decode_session(d)
    g = s.gnss
    assert np.allclose(dec.gps.tow, g.tow_rx) and dec.gps.week == g.week
    # IMU: every sample, increments within the ESF quantisation, indices consecutive.
    period = np.median(np.diff(s.imu_t))
    assert len(dec.imu) == len(s.imu_t) and dec.imu.rate_hz == s.imu_rate_hz
    assert np.all(np.diff(dec.imu.counter.astype(int)) % 256 == 1)
    assert np.max(np.abs(dec.imu.dtheta_rad - s.imu_dtheta * (1 / s.imu_rate_hz) / period)) \
        <= np.radians(2.0 ** -12) / s.imu_rate_hz
    # Fixes: the receiver's own, positions to the NAV-PVT resolution, sigmas its hAcc / vAcc.
    good = [f for f in g.fixes if f.mode]
    assert len(dec.gps.fixes) == len(good)
    r = np.array([f.r_ecef for f in good])
    assert np.max(np.abs(dec.gps.fixes[:, 1:4] - r)) < 0.02
    assert np.allclose(dec.gps.fixes[:, 7] * 3.0, [sim_ublox.UERE_M * f.hdop for f in good], atol=2e-3)
    # Tight inputs: pseudoranges of every tracked satellite, ephemerides of all of them, Klobuchar.
    pr = dec.gps.pseudorange_table()
    assert len(pr) == int(g.tracked.sum())
    k = np.flatnonzero(g.tracked[3])[0]
    row = pr[(np.isclose(pr[:, 0], g.tow_rx[3])) & (pr[:, 1] == k + 1)]
    assert np.isclose(row[0, 2], g.pseudorange_m[3, k])
    assert {e.prn for e in dec.gps.ephemerides} == set(good[0].prns)
    assert np.allclose(dec.gps.iono.alpha, g.ion_alpha, rtol=1e-2, atol=1e-9)


def test_session_without_rawx_replays_loose_on_nav_pvt_time(tmp_path):
    s = _sim(DRIVE)
    d = _write_session(tmp_path / "session", s, {"NAV-PVT", "ESF-RAW"})
    write_truth(s, tmp_path / "truth.npz")
    res = run.replay(d, tmp_path / "loose", mode="loose", gps_latency_s=sim_ublox.FIX_DELAY_S,
                     imu_latency_s=sim_ublox.ESF_DELAY_S)
    sm = res.summary
    assert any("no RXM-RAWX" in k for k in sm["skipped"])
    assert sm["alignment"]["imu_frames_missing"] == 0
    assert sm["errors"]["inside_3_sigma"] >= 0.95 and sm["errors"]["horizontal_rms_m"] < 5.0


def test_generation_8_set_up_with_cfg_rate_and_cfg_msg(tmp_path):
    extra = 'generation = 8\nmeasurement_rate_hz = 5.0\nmessages = ["RXM-RAWX", "NAV-PVT"]'
    em, session, side, _ = _record(tmp_path, UbloxSimSource(_sim(STAND)), speed=2.0, extra=extra)
    steps = side["sensors"]["gps"]["receiver"]["configuration"]
    assert [(x["message"], x["result"]) for x in steps] == [("CFG-RATE", "ack"), ("CFG-MSG", "ack"), ("CFG-MSG", "ack")]
    assert em.gps.meas_rate_hz == 5.0 and em.gps.enabled == {"RXM-RAWX", "NAV-PVT"}
    names = [ubx.name_of((f[2], f[3])) for f in session.sensors["gps"].frames()]
    assert set(names) - {"ACK-ACK", "MON-VER"} == {"RXM-RAWX", "NAV-PVT"}
    # RAWX at the set 5 Hz: the 6 s stand (served from the first configured epoch on).
    assert 20 <= names.count("RXM-RAWX") <= 31

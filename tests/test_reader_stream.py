"""The block-by-block record reader gives exactly what the whole-buffer scan gives, for every input and every
block size (records cut by a block boundary, damage across one, 64-byte blocks); the IMU decoded as it is read
equals the frames decoded one by one; replay's lean decode path keeps the same samples as the frame path."""

import io
import json
import struct

import numpy as np
import pytest

from corpora import STAMP_T0, Corpus, bp_frames, faulted_stream, mutate, record_file, ss2_frames
from gpsins.session import logs, measurements
from gpsins.session import layouts
from gpsins.session import stamps as stamps_mod
from gpsins.session import stream as log_stream
from gpsins.session import scan as log_scan
from gpsins import sim
from gpsins.sim.scenario import parse
from gpsins.sim.session import write_session
from gpsins_logger import bp3010, ubx
from gpsins_logger import superstar2 as ss2
from gpsins_logger.recorder import CLOCK_STEP_THRESHOLD_S

CORPORA = [Corpus("superstar2", ss2_frames(6.0), ss2.HEADER_LEN, 0.05), Corpus("bp3010", bp_frames(300), 1, 1 / 64)]
# 64: records of every kind span several blocks; 97 and 1009 cut records at changing places; 1 << 16: one block.
BLOCKS = (64, 97, 1009, 1 << 16)
CASES = 40  # mutated files per corpus


def assert_same_scan(got: layouts.Scan, want: layouts.Scan) -> None:
    backwards = ("stamps_backwards", "first_backwards_offset")  # read_record_file's own
    assert {k: v for k, v in got.stats.items() if k not in backwards} == want.stats
    np.testing.assert_array_equal(got.starts, want.starts)
    np.testing.assert_array_equal(got.lengths, want.lengths)
    np.testing.assert_array_equal(got.stamps.view(np.uint64), want.stamps.view(np.uint64))  # NaNs bit for bit
    np.testing.assert_array_equal(got.frame_data, want.frame_data)


def streamed(data: bytes, layout: layouts.Layout, limits, block: int) -> layouts.Scan:
    return log_stream.scan_stream(io.BytesIO(data), layout, "<bytes>", limits, block)


def corpus_limits(c: Corpus) -> stamps_mod.StampLimits:
    return stamps_mod.StampLimits(STAMP_T0 - 2.0, STAMP_T0 + len(c.frames) * c.dt + 2.0, CLOCK_STEP_THRESHOLD_S)


@pytest.mark.parametrize("corpus", CORPORA, ids=lambda c: c.device)
def test_streaming_equals_whole_buffer_scan_on_mutated_record_files(corpus):
    rng = np.random.default_rng([17, len(corpus.frames)])
    limits = corpus_limits(corpus)
    layout = layouts.LAYOUTS[corpus.device]
    damaged = 0
    for case in range(CASES):
        data, _, _ = mutate(corpus.records_bytes, rng)
        want = log_scan.scan(data, layout, limits=limits)
        damaged += bool(want.stats["discarded_bytes"] or want.stats["bad_stamps"] or want.stats["truncated_tail_bytes"])
        for block in BLOCKS:
            assert_same_scan(streamed(data, layout, limits, block), want)
        if case % 4 == 0:  # without session limits: random bytes pass as records with any stamp
            assert_same_scan(streamed(data, layout, None, 97), log_scan.scan(data, layout))
    assert damaged > CASES // 2  # the corpus exercises the damage paths


def test_streaming_equals_whole_buffer_scan_on_ubx_records_and_raw_streams():
    rng = np.random.default_rng(23)
    frames = [ubx.encode_frame((2, 0x15), rng.integers(0, 256, int(rng.integers(0, 300)), dtype=np.uint8).tobytes())
              for _ in range(120)]
    records, _ = record_file(frames, ubx.HEADER_LEN, 0.1)
    limits = stamps_mod.StampLimits(STAMP_T0 - 2, STAMP_T0 + 14)
    for _ in range(12):
        data, _, _ = mutate(records, rng)
        want = log_scan.scan(data, layouts.UBX_RECORDS, limits=limits)
        for block in BLOCKS:
            assert_same_scan(streamed(data, layouts.UBX_RECORDS, limits, block), want)
    for layout, frames_ in ((layouts.SS2_RAW, CORPORA[0].frames), (layouts.UBX_RAW, frames)):
        for _ in range(6):
            data, _ = faulted_stream(frames_, rng, p_flip=0.1, p_garbage=0.1)
            data = data[:len(data) - int(rng.integers(0, 100))]
            want = log_scan.scan(data, layout)
            for block in BLOCKS:
                assert_same_scan(streamed(data, layout, None, block), want)


def test_every_block_size_finds_each_record_once():
    """A clean file read with every block size from 1 to two records: each boundary cuts the records at
    another place, and the reader still finds each record exactly once with nothing discarded."""
    data, recs = record_file(bp_frames(40), 1, 1 / 64)
    for block in range(1, 2 * len(recs[0]) + 1):
        s = streamed(data, layouts.BP_RECORDS, None, block)
        assert [s.record(k) for k in range(s.count)] == recs
        assert s.stats["discarded_bytes"] == 0 and s.stats["resyncs"] == 0


def test_short_and_empty_inputs():
    data, _ = record_file(ss2_frames(1.0), ss2.HEADER_LEN, 0.05)
    for n in (0, 1, 3, 4, 13, 40):
        for layout in (layouts.SS2_RECORDS, layouts.BP_RECORDS, layouts.UBX_RECORDS):
            assert_same_scan(streamed(data[:n], layout, None, 5), log_scan.scan(data[:n], layout))


def _imu_file(tmp_path, n=3000):
    """A BP3010 record file with invalid and over-range frames, garbage, an impossible stamp and a torn tail."""
    rng = np.random.default_rng(4)
    frames = []
    for k in range(n):
        status = bp3010.STATUS_VALID if k % 97 else bp3010.STATUS_GYRO_OVERRANGE
        if k % 131 == 5:
            status = 0
        frames.append(bp3010.ImuSample(tuple(rng.normal(0, 2e-3, 3)), tuple(rng.normal(0, 0.1, 3)), status,
                                       k & 0xFF).encode())
    stamps = STAMP_T0 + 0.5 + np.arange(n) / 64
    stamps[1234] = -stamps[1234]
    data = bytearray(b"".join(f[:1] + struct.pack("<d", t) + f[1:] for f, t in zip(frames, stamps)))
    data[777 * 24:777 * 24] = b"\xa5\x00\x13garbage"
    path = tmp_path / "imu-000.bin"
    path.write_bytes(bytes(data[:-7]))
    return path, frames


def test_imu_decoded_while_reading_equals_the_frames_decoded_one_by_one(tmp_path):
    path, _ = _imu_file(tmp_path)
    limits = stamps_mod.StampLimits(STAMP_T0, STAMP_T0 + 60)
    framed = logs.read_record_file(path, "bp3010", limits)
    # The whole-buffer scan of the same bytes, then the stamp test: the same records and counts.
    scanned = log_scan.scan(path.read_bytes(), layouts.BP_RECORDS, str(path), limits)
    whole = stamps_mod.reject_bad_stamps(scanned, limits)
    assert_same_scan(framed, whole)
    assert framed.stats["bad_stamps"] == 1 and framed.stats["truncated_tail_bytes"] == 17
    for block in (64, 1000):
        lean = logs.read_record_file(path, "bp3010", limits, block_bytes=block, imu_rate_hz=64)
        assert lean.frame_data is None and lean.stats == framed.stats
        np.testing.assert_array_equal(lean.starts, framed.starts)
        # Independent decoder: the logger's own frame decoder, one frame at a time.
        samples = [bp3010.ImuSample.decode(f, 64) for f in framed.frames()]
        imu = logs.imu_log(lean, 64)
        # Held as the frames' int16 counts (a quarter of the floats' memory on a day-long log).
        assert imu.dtheta.dtype == imu.dv.dtype == np.int16
        assert imu.lsb == (bp3010.dtheta_lsb_rad(64), bp3010.dv_lsb_mps(64))
        np.testing.assert_array_equal(imu.stamps, framed.stamps)
        np.testing.assert_array_equal(imu.dtheta_rad, [s.dtheta_rad for s in samples])
        np.testing.assert_array_equal(imu.dv_mps, [s.dv_mps for s in samples])
        np.testing.assert_array_equal(imu.status, [s.status for s in samples])
        np.testing.assert_array_equal(imu.counter, [s.counter for s in samples])
    from_frames = logs.imu_log(framed, 64)
    np.testing.assert_array_equal(from_frames.dtheta_rad, imu.dtheta_rad)
    np.testing.assert_array_equal(from_frames.dv_mps, imu.dv_mps)
    with pytest.raises(layouts.LogError, match="frames were not kept"):
        lean.frames()


def test_decode_session_keeps_the_valid_samples_of_the_frame_path(tmp_path):
    d = tmp_path / "s"
    start = {"gps_week": 1590, "gps_tow_s": 419400.0, "lat_deg": 59.37, "lon_deg": 17.95, "height_m": 30.0,
             "heading_deg": 160.0}
    write_session(sim.simulate(parse({"name": "stand", "start": start,
                                      "segment": [{"label": "s", "duration_s": 6}]}), seed=1), d)
    side = json.loads((d / "session.json").read_text())
    imu_file = d / side["sensors"]["imu"]["files"][0]
    # Mark some frames invalid or over range (re-encoded, so their checksums stay good) and add garbage.
    data = bytearray(imu_file.read_bytes())
    for k in range(3, len(data) // 24, 50):
        frame = data[k * 24:k * 24 + 1] + data[k * 24 + 9:k * 24 + 24]
        s = bp3010.ImuSample.decode(bytes(frame), 64)
        s.status = bp3010.STATUS_ACCEL_OVERRANGE | bp3010.STATUS_VALID if k % 100 == 3 else 0
        new = s.encode(64)
        data[k * 24:k * 24 + 24] = new[:1] + data[k * 24 + 1:k * 24 + 9] + new[1:]
    data[100 * 24:100 * 24] = b"\x00\xa5\x11"
    imu_file.write_bytes(bytes(data))

    dec = measurements.decode_session(d)
    framed = logs.read_session(d)  # frames kept, decoded one by one by the logger's decoder
    samples = [bp3010.ImuSample.decode(f, 64) for f in framed.sensors["imu"].frames()]
    stamps = framed.sensors["imu"].stamps
    valid = [k for k, s in enumerate(samples) if s.valid and not s.status & (
        bp3010.STATUS_GYRO_OVERRANGE | bp3010.STATUS_ACCEL_OVERRANGE | bp3010.STATUS_BIT_FAILURE)]
    assert 0 < len(valid) < len(samples) - 5
    np.testing.assert_array_equal(dec.imu.stamps, stamps[valid])
    np.testing.assert_array_equal(dec.imu.dtheta_rad, [samples[k].dtheta_rad for k in valid])
    np.testing.assert_array_equal(dec.imu.dv_mps, [samples[k].dv_mps for k in valid])
    np.testing.assert_array_equal(dec.imu.counter, [samples[k].counter for k in valid])
    assert dec.skipped["imu: frames flagged invalid, over range or test failure"] == len(samples) - len(valid)
    assert dec.skipped["imu: bytes between frames (garbage or damaged frames)"] == 3
    # GPS: the pseudorange table, made while decoding, is what every ID 23 frame says.
    rows, k = [], 0
    for frame in framed.sensors["gps"].frames():
        msg_id, payload = ss2.decode_frame(frame)
        if msg_id == ss2.ID_MEASUREMENTS:
            m = ss2.Measurements.decode(payload)
            assert dec.gps.tow[k] == m.tow_s
            rows += [(m.tow_s, o.prn, m.pseudorange_m(o), o.cn0_dbhz, o.lock_count) for o in m.observations
                     if not o.sbas]
            k += 1
    assert k == len(dec.gps.tow) > 50 and len(rows) > 5 * k
    np.testing.assert_array_equal(dec.gps.pseudorange_table(), np.array(rows))

"""RTKLIB time tags and IMU times from a sensor's own counter: the walk's raw IMU stream against the publisher's
own alignment of it, a simulated logger with known clock and latency, and damaged input."""

import struct
from pathlib import Path

import numpy as np
import pytest

from gpsins.dataset import load
from gpsins.timing import envelope
from gpsins.formats.common import ReaderError
from gpsins.formats import imu_csv, rtklib_tag
from gpsins.formats.gpstime import UNIX_TO_GPS_S

WALK = Path(__file__).parent / "data" / "walk_0827"
COLUMNS = ["ax", "ay", "az", "gx", "gy", "gz", "counter"]


@pytest.fixture(scope="module")
def raw_walk():
    rows = imu_csv.read_counter_rows(WALK / "imu_1730.csv", COLUMNS, "g", "deg/s")
    tags = rtklib_tag.read(WALK / "imu_1730.csv.tag")
    return rows, tags


def test_walk_tags_as_the_file_has_them(raw_walk):
    rows, tags = raw_walk
    size = (WALK / "imu_1730.csv.tag").stat().st_size
    assert len(tags.offset) == (size - rtklib_tag.HEADER_BYTES) // 8 == 9560
    # The publisher's time-aligned file starts at the tag file's start time (GPST counted like Unix time).
    first_sf = float((WALK / "imu_1730_sf.csv").read_text().split(",", 1)[0])
    assert tags.start_t_abs == pytest.approx(first_sf - UNIX_TO_GPS_S, abs=1e-6)
    assert np.all(np.diff(tags.tick_ms) >= 0) and np.median(np.diff(tags.tick_ms)[np.diff(tags.tick_ms) > 0]) == 16
    # The stream had CR LF line ends, the published CSV has LF: the last tag is one byte further per line.
    assert tags.offset[-1] == rows.file_bytes + rows.newlines
    # Every whole line is kept; the first and the unterminated last one are cut by the logger's start and stop.
    assert len(rows.counter) == 20455 == rows.newlines - 1
    assert sum(rows.skipped.values()) == 2
    assert set(np.diff(rows.counter)) == {6, 7, 8, 9}


def test_counter_times_agree_with_the_publishers_alignment(raw_walk):
    """The publisher aligned the same samples (imu_1730_sf.csv, the same rows in the same order) by its own
    method; ours, the lower envelope of arrival against counter, lands within 12 ms of it at every sample."""
    rows, tags = raw_walk
    arrival = tags.arrival_t_abs(tags.stream_offsets(rows.end_offset, rows.line_no, rows.file_bytes, rows.newlines))
    t, fit = envelope.counter_times(rows.counter * 1e-3, arrival)
    sf = np.loadtxt(WALK / "imu_1730_sf.csv", delimiter=",", usecols=(0, 1))
    d_ms = (sf[:, 0] - UNIX_TO_GPS_S - t) * 1e3
    print(f"\npublisher - ours: {d_ms[0]:.1f} ms at the start, {d_ms[-1]:.1f} ms at the end; counter rate "
          f"{fit['counter_rate_ppm']:+.1f} ppm; arrival above the envelope {fit['arrival_above_envelope_ms']}")
    assert fit["samples_with_arrival"] == len(t) and np.all(np.abs(d_ms) < 12.0)
    # Both follow the counter sample by sample; they differ only in the clock rate (ours 13.8 ppm, theirs 117).
    assert np.max(np.abs(np.diff(d_ms))) < 0.01
    late = fit["arrival_above_envelope_ms"]
    assert 0.0 < late["median"] < late["p95"] < 20.0 <= late["max"]  # Windows' 15.6 ms tick, one 100 ms stall
    assert abs(fit["counter_rate_ppm"]) < 100.0


def test_counter_times_recover_a_simulated_loggers_clock():
    """A 1 kHz counter 40 ppm slow, samples 6-9 ms apart, each arriving 2 ms plus an exponential 3 ms late,
    seen through a 15.625 ms host tick (rounded down): the rate comes back to a ppm and the times to within
    the tick, all late by one constant."""
    rng = np.random.default_rng(11)
    counter = np.cumsum(rng.integers(6, 10, 30000))
    t_true = 1.4e9 + counter * 1e-3 * (1.0 + 40e-6)
    arrival = t_true + 0.002 + rng.exponential(0.003, len(counter))
    tick = 0.015625
    arrival = 1.4e9 + np.floor((arrival - 1.4e9) / tick) * tick
    t, fit = envelope.counter_times(counter * 1e-3, arrival)
    err = t - t_true
    assert fit["counter_rate_ppm"] == pytest.approx(40.0, abs=1.0)
    assert np.ptp(err) < 0.5e-3  # one constant along 200 s
    assert -tick < err.mean() < 0.003


def _write_tag(path: Path, pairs, magic=b"TIMETAG RTKLIB EX 2.4.3"):
    head = magic.ljust(rtklib_tag.TEXT_BYTES, b"\0") + struct.pack("<IId", 123, 1756402240, 0.5)
    path.write_bytes(head + b"".join(struct.pack("<II", *p) for p in pairs))


def test_damaged_tags_and_streams_are_named(tmp_path):
    csv = tmp_path / "imu.csv"
    csv.write_text("0,0,1,0,0,0,100\n0,0,1,0,0,0,106\n0,0,1,0,0,0,112\n0,0,1,0,0,0,118\n")
    tag = tmp_path / "imu.csv.tag"
    _write_tag(tag, [(10, 16), (20, 64)])
    rows = imu_csv.read_counter_rows(csv, COLUMNS)
    tags = rtklib_tag.read(tag)
    assert tags.start_t_abs == pytest.approx(1756402240.5 - UNIX_TO_GPS_S)
    assert rows.counter.tolist() == [106, 112, 118]  # the first line may have been cut by the logger's start
    assert tags.arrival_t_abs(tags.stream_offsets(rows.end_offset, rows.line_no, rows.file_bytes,
                                                  rows.newlines)).tolist()[0] == pytest.approx(tags.start_t_abs + 0.02)
    _write_tag(tag, [(10, 16), (20, 50)])
    with pytest.raises(ReaderError, match="matches neither"):
        rtklib_tag.read(tag).stream_offsets(rows.end_offset, rows.line_no, rows.file_bytes, rows.newlines)
    _write_tag(tag, [(10, 30), (20, 16)])
    with pytest.raises(ReaderError, match=r"offset \d+\): offset: stream offset goes back"):
        rtklib_tag.read(tag)
    csv.write_text("x\n0,0,1,0,0,0,100\n0,0,1,0,0,0,90\n0,0,1,0,0,0,96\n")
    with pytest.raises(ReaderError, match=r"imu.csv:3: counter: the counter does not increase"):
        imu_csv.read_counter_rows(csv, COLUMNS)
    csv.write_text("x\n0,0,1,0,0,0,100\n0,zero,1,0,0,0,106\n0,0,1,0,0,0,112\n")
    with pytest.raises(ReaderError, match=r"imu.csv:3: ay: not a number"):
        imu_csv.read_counter_rows(csv, COLUMNS)


def test_raw_walk_data_set_reads_the_counter_times():
    ds = load.load(WALK / "walk_0827_raw.toml")
    a = ds.imu.alignment
    assert a["tag"] == "imu_1730.csv.tag" and abs(a["counter_rate_ppm"]) < 100.0
    assert len(ds.imu) == 20454 and any("ppm" in n for n in ds.notes)  # 20455 rate samples, 20454 increments
    sf = load.load(WALK / "walk_0827.toml").imu
    # Not low-pass filtered: the publisher's filter cut the vertical specific force at about 7.6 Hz (body z is
    # the IMU's -z), so sample to sample the raw one moves about twice as much (0.21 against 0.09 m/s^2).
    jitter = [np.std(np.diff(x.dv_mps / np.diff(x.t_abs, prepend=x.t_abs[0] - 0.006)[:, None], axis=0), axis=0)
              for x in (ds.imu, sf)]
    print("specific force change per sample, raw / filtered (m/s^2):", jitter[0].round(3), jitter[1].round(3))
    assert jitter[0][2] > 1.8 * jitter[1][2] and np.all(jitter[0] > jitter[1])


# --- the layout from the file's structure, whatever its label -------------------------------------------------

def _walk_tags_as(layout: rtklib_tag.Layout, label: bytes) -> bytes:
    """The walk's tag file rewritten in another layout (and label), the same start time, ticks and offsets."""
    data = (WALK / "imu_1730.csv.tag").read_bytes()
    tick_f, seconds, fraction = struct.unpack_from("<IId", data, rtklib_tag.TEXT_BYTES)
    pairs = np.frombuffer(data, rtklib_tag.PAIR, offset=rtklib_tag.HEADER_BYTES).astype(layout.pair)
    time = struct.pack("<Id", seconds, fraction) if layout.time_bytes == 12 else struct.pack("<qd", seconds, fraction)
    return label.ljust(rtklib_tag.TEXT_BYTES, b"\0") + struct.pack("<I", tick_f) + time + pairs.tobytes()


@pytest.fixture(scope="module")
def walk_tags():
    return rtklib_tag.read(WALK / "imu_1730.csv.tag")


def _same_tags(a, b):
    assert a.start_t_abs == b.start_t_abs
    np.testing.assert_array_equal(a.tick_ms, b.tick_ms)
    np.testing.assert_array_equal(a.offset, b.offset)


@pytest.mark.parametrize("label", [b"TIMETAG RTKLIB demo5 b34k", b"TIMETAG RTKLIB 2.4.3 b34", b"imu logger, run 7",
                                   b""], ids=["demo5", "2.4.3", "arbitrary", "empty"])
def test_a_relabelled_tag_file_reads_as_the_original(tmp_path, walk_tags, label):
    data = (WALK / "imu_1730.csv.tag").read_bytes()
    tag = tmp_path / "imu_1730.csv.tag"
    tag.write_bytes(label.ljust(rtklib_tag.TEXT_BYTES, b"\0") + data[rtklib_tag.TEXT_BYTES:])
    got = rtklib_tag.read(tag)
    _same_tags(got, walk_tags)
    assert got.label == label.decode() and got.layout == walk_tags.layout == rtklib_tag.LAYOUTS[0].name
    assert walk_tags.label == "TIMETAG RTKLIB EX"


@pytest.mark.parametrize("layout", rtklib_tag.LAYOUTS[1:], ids=lambda x: x.name.split(" (")[0])
def test_the_other_layouts_give_the_same_tags(tmp_path, walk_tags, layout):
    """16-byte start times (gtime_t as it lies in memory) and 8-byte offsets (::P=8), each labelled as the walk's
    EX file is: the label does not choose, the structure does."""
    tag = tmp_path / "imu.tag"
    tag.write_bytes(_walk_tags_as(layout, b"TIMETAG RTKLIB EX"))
    got = rtklib_tag.read(tag)
    assert got.layout == layout.name
    _same_tags(got, walk_tags)


def test_a_handful_of_tags_that_fill_two_layouts_read_as_the_one_with_a_streams_offsets(tmp_path):
    """Three tags with 4-byte offsets after a 16-byte start time fill the file as two with 8-byte offsets too, and
    both read monotonic: (5, 20 + 9 * 2^32), (40, 30 + 64 * 2^32). The stream's own offsets are the small ones."""
    lay = rtklib_tag.LAYOUTS[3]
    data = b"x".ljust(60, b"\0") + struct.pack("<Iqd", 7, 1756402240, 0.25) + \
        np.array([(5, 20), (9, 40), (30, 64)], lay.pair).tobytes()
    assert len(data) - rtklib_tag.LAYOUTS[1].header_bytes == 2 * rtklib_tag.LAYOUTS[1].pair.itemsize
    path = tmp_path / "s.tag"
    path.write_bytes(data)
    got = rtklib_tag.read(path)
    assert got.layout == lay.name and got.tick_ms.tolist() == [5, 9, 30] and got.offset.tolist() == [20, 40, 64]
    assert got.start_t_abs == 1756402240.25 - UNIX_TO_GPS_S


def test_a_tag_file_cut_mid_pair_reads_without_its_last_pair(tmp_path, walk_tags):
    tag = tmp_path / "cut.tag"
    tag.write_bytes((WALK / "imu_1730.csv.tag").read_bytes()[:-3])
    got = rtklib_tag.read(tag)
    assert got.cut_bytes == 5 and got.layout == walk_tags.layout and walk_tags.cut_bytes == 0
    np.testing.assert_array_equal(got.offset, walk_tags.offset[:-1])
    np.testing.assert_array_equal(got.tick_ms, walk_tags.tick_ms[:-1])


def _refusal(tmp_path, data: bytes, stream: bytes | None = None) -> str:
    tag, beside = tmp_path / "bad.csv.tag", tmp_path / "bad.csv"
    tag.write_bytes(data)
    beside.unlink(missing_ok=True)
    if stream is not None:
        beside.write_bytes(stream)
    with pytest.raises(ReaderError) as e:
        rtklib_tag.read(tag)
    msg = str(e.value)
    assert msg.startswith(str(tag)) and "\n" not in msg and e.value.offset is not None and e.value.field
    return msg


def test_a_file_that_fits_no_layout_is_refused_saying_why(tmp_path):
    walk = (WALK / "imu_1730.csv.tag").read_bytes()
    csv = (WALK / "imu_1730.csv").read_bytes()[:20000]
    head = walk[:rtklib_tag.HEADER_BYTES]
    assert "shorter than the 76-byte header" in _refusal(tmp_path, walk[:70])
    # The IMU's own CSV given as its tag file: its text label passes, its "start fraction" (ASCII digits read as
    # a double, 1e-100 or so) does not, and no layout's does.
    msg = _refusal(tmp_path, csv[:76 + 8 * 100])
    assert "start time: start fraction 1.1" in msg and "is not a clock's fraction of a second" in msg
    assert "no text label (byte 0x01)" in _refusal(tmp_path, b"\x01" + walk[1:])
    bad_fraction = head[:68] + struct.pack("<d", 1.5) + walk[76:]
    assert "start time: start fraction 1.5 is not a clock's fraction of a second" in _refusal(tmp_path, bad_fraction)
    # Offsets beyond the stream file beside the tag (a tag file of another, longer stream).
    assert "beyond the stream file's 1000 bytes" in _refusal(tmp_path, walk, stream=bytes(1000))
    # Ticks that go back at every other tag: no host clock.
    pairs = np.frombuffer(walk, rtklib_tag.PAIR, offset=76).copy()
    pairs["tick_ms"][1::2] = 3
    assert "tick: host ticks go back at" in _refusal(tmp_path, head + pairs.tobytes())

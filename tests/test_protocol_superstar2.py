"""Superstar II codec against the spec's byte examples and the real gpsd sample."""

import datetime as dt
import math
import struct
from collections import Counter

import pytest

from gpsins_logger import superstar2 as ss2
from gpsins_logger.framing import FrameFinder


def test_request_bytes_match_the_spec():
    assert ss2.request_message(20) == bytes.fromhex("01946b000001")
    assert ss2.request_raw_rate(1) == bytes.fromhex("0197680100" "0101")
    assert ss2.request_link_open()[4:12] == b"UGPS-000"
    # Stop ID 23: bit 7 clear.
    assert ss2.request_raw_stop()[1] == 23
    req = ss2.decode_request(ss2.request_raw_rate(10))
    assert (req.msg_id, req.continuous, req.raw_rate_hz) == (23, True, 10)
    assert ss2.decode_request(ss2.request_message(49, continuous=False)).continuous is False


def test_checksum_includes_soh_low_byte_first():
    frame = ss2.encode_frame(20, b"")
    assert frame == bytes([1, 20, 0xEB, 0, (1 + 20 + 0xEB) & 0xFF, (1 + 20 + 0xEB) >> 8])


def test_real_gpsd_sample_decodes_as_documented(shared_data):
    data = (shared_data / "superstar2_gpsd_sample.bin").read_bytes()
    finder = FrameFinder(ss2.FRAMING)
    frames = finder.feed(data) + finder.flush()
    assert Counter(f.data[1] for f in frames) == {113: 8, 33: 8, 23: 7, 20: 7}
    assert finder.stats.discarded_bytes == 0
    assert finder.stats.checksum_failures == 0
    assert (finder.stats.tail_offset, finder.stats.tail_bytes) == (2099, 34)
    assert data[2099 + 1] == 23 and data[2099 + 3] + 6 == 72  # the truncated frame is an ID 23 of 72 bytes
    first20 = next(ss2.decode_message(f.data) for f in frames if f.data[1] == 20)
    t = dt.datetime(first20.year, first20.month, first20.day, first20.hour, first20.minute) + dt.timedelta(
        seconds=first20.second)
    assert abs((t - dt.datetime(2009, 7, 4, 5, 50, 54, 999997)).total_seconds()) < 1e-6
    assert math.degrees(first20.lat_rad) == pytest.approx(53.563112, abs=1e-6)
    assert math.degrees(first20.lon_rad) == pytest.approx(-113.439572, abs=1e-6)
    assert first20.height_m == pytest.approx(631.80, abs=0.01)
    assert (first20.sats_used, first20.hdop, first20.nav_mode) == (5, 3.1, 2)
    leap = next(ss2.decode_message(f.data) for f in frames if f.data[1] == 113)
    assert leap.leap_s == 15
    meas = [ss2.decode_message(f.data) for f in frames if f.data[1] == 23]
    assert all(len(m.observations) == 5 for m in meas)
    # Pseudoranges of a real receiver lie between 19,000 and 26,000 km.
    assert all(19e6 < m.pseudorange_m(o) < 26e6 for m in meas for o in m.observations)


def test_pseudorange_follows_the_spec_rounding():
    tow, c = 516865.99999996, 123456789
    expected = 299792458 * ((516866.0 - 516866.0) - c / 2.095104e9 + 1.0)  # TOW rounds up to .000
    assert ss2.pseudorange_m(tow, c) == pytest.approx(expected, abs=1e-6)
    for pr in (20.1e6, 22_345_678.9, 25.9e6):
        code = ss2.code_phase_from_pseudorange(345600.1, pr)
        assert abs(ss2.pseudorange_m(345600.1, code) - pr) < 299792458 / 2.095104e9


def test_every_message_round_trips():
    nav = ss2.NavUser(5, 50, 54.25, 4, 7, 2009, 0.93, -1.97, 631.8, 1.5, 0.3, 1.0, -0.5, 0.1, 3.0, 4.0, 3.1, 3.3,
                      2, 5, 3)
    frame = nav.encode()
    assert len(frame) == 77 and frame[3] == 71
    back = ss2.decode_message(frame)
    assert back.lat_rad == nav.lat_rad and back.hdop == 3.1 and back.sats_used == 5
    assert back.height_m == pytest.approx(631.8, abs=1e-4)
    ecef = ss2.NavEcef(345600.5, 1590, 3.1e6, 1.0e6, 5.4e6, 0.5, -0.25, 0.125)
    assert len(ecef.encode()) == 85 and ss2.decode_message(ecef.encode()) == ecef
    eph = ss2.EphemerisWords(31, [[(k * 77777 + s) & 0xFFFFFF for k in range(8)] for s in range(3)])
    assert len(eph.encode()) == 79 and ss2.decode_message(eph.encode()) == eph
    obs = [ss2.Observation(p, 44.25, 10_000 * p, ss2.carrier_raw(1234.5 + p, half_cycle=True), p) for p in (1, 7, 32)]
    meas = ss2.Measurements(345600.1, obs, clock_slew_s=-1.75e-7)
    frame = meas.encode()
    assert len(frame) == 17 + 11 * 3
    back = ss2.decode_message(frame)
    assert back.observations == obs and back.clock_slew_s == pytest.approx(-1.75e-7)
    assert back.observations[0].carrier_cycles == pytest.approx(1235.5) and back.observations[0].half_cycle
    assert ss2.decode_message(ss2.ReceiverStatus(1479).encode()).week == 1479
    assert ss2.decode_message(ss2.LeapSeconds(15).encode()).leap_s == 15
    iono = ss2.IonoUtc((1e-8, 2e-8, -3e-8, -4e-8), (9e4, 1e5, -6e4, -5e5), 15)
    assert ss2.decode_message(iono.encode()) == iono and iono.encode()[3] == 65


def test_bad_frames_raise_with_the_reason():
    frame = bytearray(ss2.request_message(20))
    frame[-1] ^= 1
    with pytest.raises(ss2.ProtocolError, match="checksum"):
        ss2.decode_frame(bytes(frame))
    with pytest.raises(ss2.ProtocolError, match="needs"):
        ss2.NavUser.decode(b"\x00" * 10)
    with pytest.raises(ss2.ProtocolError, match="rate"):
        ss2.request_raw_rate(3)
    # The manual's 'unsigned' clock slew is signed on real receivers.
    assert struct.unpack_from("<b", ss2.Measurements(1.0, [], clock_slew_s=-3.5e-7).encode(), 4)[0] == -2

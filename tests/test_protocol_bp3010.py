"""BP3010 assumed frame: layout constants, quantisation, saturation, rate commands."""

import pytest

from gpsins_logger import bp3010


def test_frame_layout_and_checksum():
    s = bp3010.ImuSample((0.001, -0.002, 0.0), (0.0, 0.0, -0.1533), bp3010.STATUS_VALID, 200)
    f = s.encode(64)
    assert len(f) == 16 and f[0] == 0xA5 and f[14] == 200
    assert f[15] == sum(f[1:15]) & 0xFF
    assert int.from_bytes(f[1:3], "little", signed=True) == round(0.001 * 2 ** 18)
    assert int.from_bytes(f[11:13], "little", signed=True) == round(-0.1533 * 2 ** 14)


def test_lsb_scales_with_rate_so_the_range_is_rate_independent():
    assert bp3010.dtheta_lsb_rad(64) == 2 ** -18
    assert bp3010.dtheta_lsb_rad(8) == 8 * 2 ** -18
    # +-458 deg/s at every rate: 32767 LSB per frame interval.
    for rate in bp3010.RATES_HZ:
        assert 32767 * bp3010.dtheta_lsb_rad(rate) * rate == pytest.approx(8.0, rel=1e-4)


def test_round_trip_within_half_an_lsb():
    s = bp3010.ImuSample((0.0123, -0.045, 0.1), (0.5, -1.2, 1.9), bp3010.STATUS_VALID, 7)
    for rate in bp3010.RATES_HZ:
        back = bp3010.ImuSample.decode(s.encode(rate), rate)
        for a, b in zip(s.dtheta_rad, back.dtheta_rad):
            assert abs(a - b) <= bp3010.dtheta_lsb_rad(rate) / 2
        assert back.counter == 7 and back.valid


def test_over_range_saturates_and_flags():
    f = bp3010.ImuSample((0.2, 0.0, 0.0), (0.0, -3.0, 0.0)).encode(64)
    back = bp3010.ImuSample.decode(f, 64)
    assert back.status & bp3010.STATUS_GYRO_OVERRANGE and back.status & bp3010.STATUS_ACCEL_OVERRANGE
    assert back.dtheta_rad[0] == pytest.approx(32767 * 2 ** -18)
    assert back.dv_mps[1] == pytest.approx(-32768 * 2 ** -14)


def test_rate_commands():
    assert bp3010.rate_command(64) == bytes.fromhex("7b88")
    assert bp3010.rate_command(8) == bytes.fromhex("7b8b")
    assert bp3010.rate_from_command(bytes.fromhex("7b8a")) == 16
    with pytest.raises(bp3010.ProtocolError):
        bp3010.rate_command(100)
    with pytest.raises(bp3010.ProtocolError, match="checksum"):
        bp3010.ImuSample.decode(bytes([0xA5] + [0] * 14 + [1]))

"""BEC MICRO-ISU BP3010 IMU: the project's assumed 16-byte frame (spec/bp3010.md).

Every constant of the layout lives here, so a unit's real layout can replace
it without touching the logger or the decoders.
"""

from __future__ import annotations

import math
import struct
from dataclasses import dataclass

SYNC = 0xA5
FRAME_LEN = 16
COUNTER_OFFSET = 14
CHECKSUM_OFFSET = 15
NOMINAL_RATE_HZ = 64
RATES_HZ = (64, 32, 16, 8)
RATE_COMMANDS = {64: b"\x7b\x88", 32: b"\x7b\x89", 16: b"\x7b\x8a", 8: b"\x7b\x8b"}

# LSBs at 64 Hz; at other rates they scale by 64 / rate_hz (spec).
DTHETA_LSB_RAD_64HZ = 2.0 ** -18
DV_LSB_MPS_64HZ = 2.0 ** -14

STATUS_VALID = 0x01
STATUS_GYRO_OVERRANGE = 0x02
STATUS_ACCEL_OVERRANGE = 0x04
STATUS_BIT_FAILURE = 0x08

_BODY = struct.Struct("<6hBB")  # bytes 1..14


class ProtocolError(ValueError):
    """A frame that does not follow the assumed layout."""


def dtheta_lsb_rad(rate_hz: int) -> float:
    return DTHETA_LSB_RAD_64HZ * NOMINAL_RATE_HZ / rate_hz


def dv_lsb_mps(rate_hz: int) -> float:
    return DV_LSB_MPS_64HZ * NOMINAL_RATE_HZ / rate_hz


def checksum(body: bytes | bytearray) -> int:
    return sum(body) & 0xFF


@dataclass
class ImuSample:
    dtheta_rad: tuple[float, float, float]  # rotation vector over the interval, body axes
    dv_mps: tuple[float, float, float]  # velocity increment in the start-of-interval body frame
    status: int = STATUS_VALID
    counter: int = 0

    @property
    def valid(self) -> bool:
        return bool(self.status & STATUS_VALID)

    def encode(self, rate_hz: int = NOMINAL_RATE_HZ) -> bytes:
        """Quantise to the frame's LSBs (round to nearest), saturating and
        flagging over-range as the device does."""
        status = self.status
        counts = []
        for values, lsb, flag in ((self.dtheta_rad, dtheta_lsb_rad(rate_hz), STATUS_GYRO_OVERRANGE),
                                  (self.dv_mps, dv_lsb_mps(rate_hz), STATUS_ACCEL_OVERRANGE)):
            for v in values:
                c = round(v / lsb) if math.isfinite(v) else 0
                if not -32768 <= c <= 32767:
                    c = max(-32768, min(32767, c))
                    status |= flag
                counts.append(c)
        body = _BODY.pack(*counts, status & 0xFF, self.counter & 0xFF)
        return bytes([SYNC]) + body + bytes([checksum(body)])

    @classmethod
    def decode(cls, frame: bytes, rate_hz: int = NOMINAL_RATE_HZ) -> "ImuSample":
        if len(frame) != FRAME_LEN or frame[0] != SYNC:
            raise ProtocolError("not a BP3010 frame")
        if checksum(frame[1:CHECKSUM_OFFSET]) != frame[CHECKSUM_OFFSET]:
            raise ProtocolError("BP3010 checksum mismatch")
        v = _BODY.unpack_from(frame, 1)
        a, b = dtheta_lsb_rad(rate_hz), dv_lsb_mps(rate_hz)
        return cls((v[0] * a, v[1] * a, v[2] * a), (v[3] * b, v[4] * b, v[5] * b), v[6], v[7])


def rate_command(rate_hz: int) -> bytes:
    if rate_hz not in RATE_COMMANDS:
        raise ProtocolError(f"BP3010 rate {rate_hz} Hz not one of {RATES_HZ}")
    return RATE_COMMANDS[rate_hz]


def rate_from_command(cmd: bytes) -> int | None:
    for hz, c in RATE_COMMANDS.items():
        if c == cmd:
            return hz
    return None


class FramingRule:
    """BP3010 framing for :class:`gpsins_logger.framing.FrameFinder`."""

    name = "bp3010"
    sync = SYNC
    header_len = 1
    has_counter = True
    fixed_len = FRAME_LEN

    @staticmethod
    def header_ok(buf: bytearray, i: int) -> bool:
        return buf[i] == SYNC

    @staticmethod
    def frame_len(buf: bytearray, i: int) -> int:
        return FRAME_LEN

    @staticmethod
    def checksum_ok(buf: bytearray, i: int, n: int) -> bool:
        return sum(buf[i + 1:i + CHECKSUM_OFFSET]) & 0xFF == buf[i + CHECKSUM_OFFSET]

    @staticmethod
    def counter_gap(prev: bytes, buf: bytearray, j: int) -> int:
        return (buf[j + COUNTER_OFFSET] - prev[COUNTER_OFFSET]) & 0xFF

    @staticmethod
    def counter_end(j: int) -> int:
        return j + COUNTER_OFFSET + 1


FRAMING = FramingRule()

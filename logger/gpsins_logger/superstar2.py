"""NovAtel Superstar II binary protocol: framing, messages, requests.

Frame: SOH, ID, ID ^ 0xFF, N, payload (N bytes, little-endian), 16-bit sum of
every byte from SOH through the payload, low byte first. In a request, bit 7
of the ID means "send continuously". Layouts: spec/superstar2.md.
"""

from __future__ import annotations

import math
import struct
from dataclasses import dataclass, field

SOH = 0x01
HEADER_LEN = 4
MAX_FRAME_LEN = 255 + 6
CONTINUOUS = 0x80

SPEED_OF_LIGHT = 299792458.0
CODE_PHASE_UNITS_PER_S = 2.095104e9  # ID 23 code phase counts per second
CLOCK_SLEW_UNIT_S = 1.75e-7

ID_LINK_OPEN = 63
ID_NAV_USER = 20
ID_NAV_ECEF = 21
ID_EPHEMERIS = 22
ID_MEASUREMENTS = 23
ID_SAT_STATUS = 33
ID_RECEIVER_STATUS = 49
ID_IONO_UTC = 75
ID_LEAP = 113

# ID 23 rate byte: the documented 0..2 plus the project's assumed 10 Hz.
RAW_RATE_CODES = {1: 0, 2: 1, 5: 2, 10: 3}


class ProtocolError(ValueError):
    """A frame or payload that does not follow the protocol."""


def checksum(data: bytes | bytearray) -> int:
    return sum(data) & 0xFFFF


def encode_frame(msg_id: int, payload: bytes = b"") -> bytes:
    if not 0 <= msg_id <= 0xFF:
        raise ProtocolError(f"message ID {msg_id} out of range")
    if len(payload) > 255:
        raise ProtocolError(f"payload of ID {msg_id & 0x7F} is {len(payload)} bytes, at most 255")
    head = bytes((SOH, msg_id, msg_id ^ 0xFF, len(payload))) + payload
    return head + struct.pack("<H", checksum(head))


def decode_frame(frame: bytes) -> tuple[int, bytes]:
    """Check a whole frame; return (ID with bit 7, payload)."""
    if len(frame) < 6 or frame[0] != SOH or frame[2] != frame[1] ^ 0xFF:
        raise ProtocolError("not a Superstar II frame header")
    n = frame[3]
    if len(frame) != n + 6:
        raise ProtocolError(f"frame length {len(frame)} does not match N = {n}")
    if checksum(frame[:n + 4]) != frame[n + 4] | frame[n + 5] << 8:
        raise ProtocolError(f"checksum mismatch in ID {frame[1] & 0x7F}")
    return frame[1], frame[4:4 + n]


class FramingRule:
    """Superstar II framing for :class:`gpsins_logger.framing.FrameFinder`."""

    name = "superstar2"
    sync = SOH
    header_len = HEADER_LEN
    has_counter = False
    fixed_len = 0

    @staticmethod
    def header_ok(buf: bytearray, i: int) -> bool:
        return buf[i + 2] == buf[i + 1] ^ 0xFF

    @staticmethod
    def frame_len(buf: bytearray, i: int) -> int:
        return buf[i + 3] + 6

    @staticmethod
    def checksum_ok(buf: bytearray, i: int, n: int) -> bool:
        return sum(buf[i:i + n - 2]) & 0xFFFF == buf[i + n - 2] | buf[i + n - 1] << 8

    @staticmethod
    def counter_gap(prev: bytes, buf: bytearray, j: int) -> int:  # pragma: no cover
        raise NotImplementedError("Superstar II frames carry no counter")

    @staticmethod
    def counter_end(j: int) -> int:  # pragma: no cover
        raise NotImplementedError("Superstar II frames carry no counter")


FRAMING = FramingRule()


def _need(payload: bytes, n: int, msg_id: int) -> None:
    if len(payload) < n:
        raise ProtocolError(f"ID {msg_id} payload has {len(payload)} bytes, needs {n}")


# --- ID 20: navigation data, user coordinates --------------------------------

_NAV_USER = struct.Struct("<BBdBBHddffffffffHHBBB")
assert _NAV_USER.size == 69


@dataclass
class NavUser:
    hour: int
    minute: int
    second: float
    day: int
    month: int
    year: int
    lat_rad: float
    lon_rad: float
    height_m: float  # treated as WGS-84 ellipsoidal height (an assumption, spec)
    ground_speed_mps: float
    track_rad: float
    vel_north_mps: float
    vel_east_mps: float
    vel_up_mps: float
    hfom_m: float
    vfom_m: float
    hdop: float
    vdop: float
    nav_mode: int  # 2 = 3D, 3 = 2D, 4/5 = differential 3D/2D
    sats_used: int
    system_mode: int  # low nibble 3 = navigating

    def encode(self) -> bytes:
        body = _NAV_USER.pack(
            self.hour & 0x1F, self.minute, self.second, self.day, self.month, self.year, self.lat_rad,
            self.lon_rad, self.height_m, self.ground_speed_mps, self.track_rad, self.vel_north_mps,
            self.vel_east_mps, self.vel_up_mps, self.hfom_m, self.vfom_m, round(self.hdop * 10),
            round(self.vdop * 10), self.nav_mode & 0x1F, self.sats_used & 0x0F, self.system_mode)
        return encode_frame(ID_NAV_USER, body + b"\x00\x00")  # N = 71: two reserved bytes

    @classmethod
    def decode(cls, payload: bytes) -> "NavUser":
        _need(payload, _NAV_USER.size, ID_NAV_USER)
        v = _NAV_USER.unpack_from(payload)
        return cls(v[0] & 0x1F, v[1], v[2], v[3], v[4], v[5], v[6], v[7], v[8], v[9], v[10], v[11], v[12],
                   v[13], v[14], v[15], v[16] / 10.0, v[17] / 10.0, v[18] & 0x1F, v[19] & 0x0F, v[20])

    @property
    def has_fix(self) -> bool:
        return self.nav_mode in (2, 3, 4, 5)

    @property
    def is_3d(self) -> bool:
        return self.nav_mode in (2, 4)


# --- ID 21: navigation data, ECEF (position fields are project-defined) --------

_NAV_ECEF = struct.Struct("<dHdddfff")
assert _NAV_ECEF.size == 46


@dataclass
class NavEcef:
    tow_s: float
    week: int
    x_m: float
    y_m: float
    z_m: float
    vx_mps: float
    vy_mps: float
    vz_mps: float

    def encode(self) -> bytes:
        body = _NAV_ECEF.pack(self.tow_s, self.week, self.x_m, self.y_m, self.z_m, self.vx_mps, self.vy_mps,
                              self.vz_mps)
        return encode_frame(ID_NAV_ECEF, body + bytes(79 - len(body)))

    @classmethod
    def decode(cls, payload: bytes) -> "NavEcef":
        _need(payload, _NAV_ECEF.size, ID_NAV_ECEF)
        return cls(*_NAV_ECEF.unpack_from(payload))


# --- ID 22: ephemeris as raw subframe words ------------------------------------


@dataclass
class EphemerisWords:
    prn: int
    # subframes 1, 2, 3; each words 3..10 as 24-bit integers (parity removed)
    subframes: list[list[int]] = field(default_factory=list)

    def encode(self) -> bytes:
        if len(self.subframes) != 3 or any(len(sf) != 8 for sf in self.subframes):
            raise ProtocolError("ephemeris needs 3 subframes of 8 words")
        body = bytearray([(self.prn - 1) & 0x1F])
        for sf in self.subframes:
            for w in sf:
                if not 0 <= w < 1 << 24:
                    raise ProtocolError(f"subframe word {w:#x} is not 24 bits")
                body += w.to_bytes(3, "big")
        return encode_frame(ID_EPHEMERIS, bytes(body))

    @classmethod
    def decode(cls, payload: bytes) -> "EphemerisWords":
        _need(payload, 73, ID_EPHEMERIS)
        words = [int.from_bytes(payload[1 + 3 * k:4 + 3 * k], "big") for k in range(24)]
        return cls((payload[0] & 0x1F) + 1, [words[0:8], words[8:16], words[16:24]])


# --- ID 23: measurement block ---------------------------------------------------

_MEAS_HEAD = struct.Struct("<bBBd")
_MEAS_OBS = struct.Struct("<BBIIB")


@dataclass
class Observation:
    prn: int
    cn0_dbhz: float
    code_phase: int  # U4 counts, see pseudorange()
    carrier_raw: int  # U4: bit 0 half-cycle flag, bits 2..31 phase in 1/1024 cycle
    lock_count: int
    sbas: bool = False
    flag7: bool = False

    @property
    def carrier_cycles(self) -> float:
        return (self.carrier_raw >> 2) / 1024.0

    @property
    def half_cycle(self) -> bool:
        return bool(self.carrier_raw & 1)


@dataclass
class Measurements:
    tow_s: float  # receiver measurement time, GPS seconds of week
    observations: list[Observation]
    clock_slew_s: float = 0.0
    unknown: int = 3

    def encode(self) -> bytes:
        body = bytearray(_MEAS_HEAD.pack(round(self.clock_slew_s / CLOCK_SLEW_UNIT_S), self.unknown,
                                         len(self.observations), self.tow_s))
        for o in self.observations:
            body += _MEAS_OBS.pack((o.prn - 1) & 0x1F | (0x20 if o.sbas else 0) | (0x80 if o.flag7 else 0),
                                   min(255, max(0, round(o.cn0_dbhz * 4))), o.code_phase, o.carrier_raw,
                                   o.lock_count & 0xFF)
        return encode_frame(ID_MEASUREMENTS, bytes(body))

    @classmethod
    def decode(cls, payload: bytes) -> "Measurements":
        _need(payload, 11, ID_MEASUREMENTS)
        slew, unknown, n, tow = _MEAS_HEAD.unpack_from(payload)
        _need(payload, 11 + 11 * n, ID_MEASUREMENTS)
        obs = []
        for k in range(n):
            prn_byte, cn0, code, carrier, lock = _MEAS_OBS.unpack_from(payload, 11 + 11 * k)
            obs.append(Observation((prn_byte & 0x1F) + 1, cn0 / 4.0, code, carrier, lock, bool(prn_byte & 0x20),
                                   bool(prn_byte & 0x80)))
        return cls(tow, obs, slew * CLOCK_SLEW_UNIT_S, unknown)

    @property
    def epoch_tow_s(self) -> float:
        """The measurement epoch: TOW rounded to 1 ms (as RTKLIB does)."""
        return math.floor(self.tow_s * 1000.0 + 0.5) / 1000.0

    def pseudorange_m(self, obs: Observation) -> float:
        return pseudorange_m(self.tow_s, obs.code_phase)


def pseudorange_m(tow_s: float, code_phase: int) -> float:
    """Pseudorange from an ID 23 code phase, exactly as the spec (and RTKLIB) do."""
    tow = math.floor(tow_s * 1000.0 + 0.5) / 1000.0
    code = (tow - math.floor(tow)) - code_phase / CODE_PHASE_UNITS_PER_S
    if code < 0.0:
        code += 1.0
    return SPEED_OF_LIGHT * code


def code_phase_from_pseudorange(tow_s: float, pseudorange: float) -> int:
    """Inverse of :func:`pseudorange_m` (to the code phase's 0.14 m resolution)."""
    tow = math.floor(tow_s * 1000.0 + 0.5) / 1000.0
    frac = (tow - math.floor(tow)) - pseudorange / SPEED_OF_LIGHT
    if frac < 0.0:
        frac += 1.0
    c = round(frac * CODE_PHASE_UNITS_PER_S)
    return c % (1 << 32)


def carrier_raw(cycles: float, half_cycle: bool = False) -> int:
    """Encode carrier phase cycles in the ID 23 field (wraps at 2^20 cycles)."""
    units = round(cycles * 1024.0) % (1 << 30)
    return units << 2 | int(half_cycle)


# --- ID 49, 113, 75 --------------------------------------------------------------


@dataclass
class ReceiverStatus:
    week: int
    payload: bytes = b""

    def encode(self) -> bytes:
        body = bytearray(self.payload.ljust(40, b"\x00"))
        struct.pack_into("<H", body, 4, self.week)
        return encode_frame(ID_RECEIVER_STATUS, bytes(body))

    @classmethod
    def decode(cls, payload: bytes) -> "ReceiverStatus":
        _need(payload, 6, ID_RECEIVER_STATUS)
        return cls(struct.unpack_from("<H", payload, 4)[0], bytes(payload))


@dataclass
class LeapSeconds:
    leap_s: int
    payload: bytes = b""

    def encode(self) -> bytes:
        body = bytearray(self.payload.ljust(59, b"\x00"))
        body[16] = self.leap_s & 0xFF
        return encode_frame(ID_LEAP, bytes(body))

    @classmethod
    def decode(cls, payload: bytes) -> "LeapSeconds":
        _need(payload, 17, ID_LEAP)
        return cls(payload[16], bytes(payload))


_IONO = struct.Struct("<8db")


@dataclass
class IonoUtc:
    """Klobuchar coefficients and leap seconds (project-defined layout, spec)."""

    alpha: tuple[float, float, float, float]
    beta: tuple[float, float, float, float]
    leap_s: int

    def encode(self) -> bytes:
        return encode_frame(ID_IONO_UTC, _IONO.pack(*self.alpha, *self.beta, self.leap_s))

    @classmethod
    def decode(cls, payload: bytes) -> "IonoUtc":
        _need(payload, _IONO.size, ID_IONO_UTC)
        v = _IONO.unpack_from(payload)
        return cls(tuple(v[0:4]), tuple(v[4:8]), v[8])


MESSAGE_NAMES = {
    ID_NAV_USER: "navigation (user)",
    ID_NAV_ECEF: "navigation (ECEF)",
    ID_EPHEMERIS: "ephemeris",
    ID_MEASUREMENTS: "measurements",
    ID_SAT_STATUS: "satellite status",
    ID_RECEIVER_STATUS: "receiver status",
    ID_IONO_UTC: "ionosphere and UTC",
    ID_LEAP: "leap seconds",
}

DECODERS = {
    ID_NAV_USER: NavUser.decode,
    ID_NAV_ECEF: NavEcef.decode,
    ID_EPHEMERIS: EphemerisWords.decode,
    ID_MEASUREMENTS: Measurements.decode,
    ID_RECEIVER_STATUS: ReceiverStatus.decode,
    ID_IONO_UTC: IonoUtc.decode,
    ID_LEAP: LeapSeconds.decode,
}


def decode_message(frame: bytes):
    """Decode a whole frame into its message object (or (ID, payload) when not decoded)."""
    msg_id, payload = decode_frame(frame)
    decoder = DECODERS.get(msg_id & 0x7F)
    return decoder(payload) if decoder else (msg_id & 0x7F, payload)


# --- requests (host to receiver) -------------------------------------------------


def request_link_open() -> bytes:
    return encode_frame(ID_LINK_OPEN, b"UGPS-000")


def request_message(msg_id: int, continuous: bool = True) -> bytes:
    if msg_id == ID_MEASUREMENTS:
        raise ProtocolError("ID 23 is requested with request_raw_rate() and stopped with request_raw_stop()")
    return encode_frame(msg_id | (CONTINUOUS if continuous else 0))


def request_raw_rate(rate_hz: int) -> bytes:
    if rate_hz not in RAW_RATE_CODES:
        raise ProtocolError(f"ID 23 rate {rate_hz} Hz not one of {sorted(RAW_RATE_CODES)}")
    return encode_frame(ID_MEASUREMENTS | CONTINUOUS, bytes([RAW_RATE_CODES[rate_hz]]))


def request_raw_stop() -> bytes:
    return encode_frame(ID_MEASUREMENTS, b"\x00")


@dataclass
class Request:
    """A decoded host request, as the receiver (or its emulator) sees it."""

    msg_id: int
    continuous: bool
    data: bytes

    @property
    def raw_rate_hz(self) -> int | None:
        if self.msg_id != ID_MEASUREMENTS or not self.continuous or not self.data:
            return None
        for hz, code in RAW_RATE_CODES.items():
            if code == self.data[0]:
                return hz
        return None


def decode_request(frame: bytes) -> Request:
    msg_id, payload = decode_frame(frame)
    return Request(msg_id & 0x7F, bool(msg_id & CONTINUOUS), payload)

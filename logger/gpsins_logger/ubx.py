"""u-blox UBX protocol for the logger: framing, NMEA on the same port, receiver set-up.

Frame: sync B5 62, class, id, payload length (U2, little-endian), payload,
CK_A CK_B: the 8-bit Fletcher checksum over class, id, length and payload.
The record keeps the 6-byte header (sync, class, id, length) before the stamp.

Set-up after every (re)open (:class:`Setup`): MON-VER is polled (the sidecar
keeps the answer), then each configuration message is sent alone and must be
answered by ACK-ACK within a timeout. A NAK or silence is logged and noted,
and the set-up goes on with the next message; the port logs whatever comes
throughout. What was not acknowledged is sent again after a back-off (1 s,
doubling up to `retry_max_s`) for as long as the port is open: a receiver
still booting, or one that was busy, is configured when it comes round,
not left silent for the drive. While unconfigured, a warning every minute.
Generation 9 receivers (F9P, F9R) are set with CFG-VALSET in the RAM layer
(lost at power-off, so the receiver's stored configuration is never
changed); generation 8 (M8T, NEO-M8L) with CFG-RATE and CFG-MSG.
"""

from __future__ import annotations

import logging
import re
import struct
import time
from dataclasses import dataclass, field
from itertools import accumulate

log = logging.getLogger(__name__)

SYNC1, SYNC2 = 0xB5, 0x62
HEADER_LEN = 6  # sync, sync, class, id, length (2)
MAX_PAYLOAD = 8192  # a longer declared length is a false sync

# (class, id) of the messages this project uses.
NAV_PVT = (0x01, 0x07)
NAV_TIMEGPS = (0x01, 0x20)
RXM_SFRBX = (0x02, 0x13)
RXM_RAWX = (0x02, 0x15)
ACK_NAK = (0x05, 0x00)
ACK_ACK = (0x05, 0x01)
CFG_MSG = (0x06, 0x01)
CFG_RATE = (0x06, 0x08)
CFG_VALSET = (0x06, 0x8A)
MON_VER = (0x0A, 0x04)
ESF_MEAS = (0x10, 0x02)
ESF_RAW = (0x10, 0x03)

NAMES = {NAV_PVT: "NAV-PVT", NAV_TIMEGPS: "NAV-TIMEGPS", RXM_SFRBX: "RXM-SFRBX", RXM_RAWX: "RXM-RAWX",
         ACK_NAK: "ACK-NAK", ACK_ACK: "ACK-ACK", CFG_MSG: "CFG-MSG", CFG_RATE: "CFG-RATE", CFG_VALSET: "CFG-VALSET",
         MON_VER: "MON-VER", ESF_MEAS: "ESF-MEAS", ESF_RAW: "ESF-RAW"}
BY_NAME = {v: k for k, v in NAMES.items()}
# The messages a logger may enable (output messages).
OUTPUT_MESSAGES = ("RXM-RAWX", "RXM-SFRBX", "NAV-PVT", "NAV-TIMEGPS", "ESF-RAW", "ESF-MEAS")

# Configuration keys (u-blox F9 interface description; checked against pyubx2's
# database in the tests). The key's bits 28..30 give the value's size.
CFG_RATE_MEAS = 0x30210001  # U2, ms between measurements
CFG_RATE_NAV = 0x30210002  # U2, measurements per navigation solution
CFG_RATE_TIMEREF = 0x20210003  # E1, 0 = UTC, 1 = GPS
# CFG-MSGOUT-UBX_<msg>_<interface>: output rate per navigation epoch, U1.
MSGOUT_KEYS = {
    "RXM-RAWX": {"uart1": 0x209102A5, "uart2": 0x209102A6, "usb": 0x209102A7},
    "RXM-SFRBX": {"uart1": 0x20910232, "uart2": 0x20910233, "usb": 0x20910234},
    "NAV-PVT": {"uart1": 0x20910007, "uart2": 0x20910008, "usb": 0x20910009},
    "NAV-TIMEGPS": {"uart1": 0x20910048, "uart2": 0x20910049, "usb": 0x2091004A},
    "ESF-RAW": {"uart1": 0x209102A0, "uart2": 0x209102A1, "usb": 0x209102A2},
    "ESF-MEAS": {"uart1": 0x20910278, "uart2": 0x20910279, "usb": 0x2091027A},
}
INTERFACES = ("uart1", "uart2", "usb")
KEY_NAMES = {CFG_RATE_MEAS: "CFG-RATE-MEAS", CFG_RATE_NAV: "CFG-RATE-NAV", CFG_RATE_TIMEREF: "CFG-RATE-TIMEREF"}
for _msg, _ports in MSGOUT_KEYS.items():
    for _port, _key in _ports.items():
        KEY_NAMES[_key] = f"CFG-MSGOUT-UBX_{_msg.replace('-', '_')}_{_port.upper()}"
LAYER_RAM = 0x01
_VALUE_BYTES = {1: 1, 2: 1, 3: 2, 4: 4, 5: 8}


class ProtocolError(ValueError):
    """A frame or payload that does not follow the UBX protocol."""


def checksum(body: bytes | bytearray | memoryview) -> tuple[int, int]:
    """Fletcher-8 over class, id, length and payload: CK_A is the byte sum, CK_B the
    sum of its running sums (both modulo 256; summed in C, not byte by byte)."""
    return sum(body) & 0xFF, sum(accumulate(body)) & 0xFF


def encode_frame(cls_id: tuple[int, int], payload: bytes = b"") -> bytes:
    if len(payload) > 0xFFFF:
        raise ProtocolError(f"payload of {len(payload)} bytes does not fit a UBX frame")
    body = bytes(cls_id) + struct.pack("<H", len(payload)) + payload
    return bytes((SYNC1, SYNC2)) + body + bytes(checksum(body))


def decode_frame(frame: bytes) -> tuple[tuple[int, int], bytes]:
    """Check a whole frame; return ((class, id), payload)."""
    if len(frame) < 8 or frame[0] != SYNC1 or frame[1] != SYNC2:
        raise ProtocolError("not a UBX frame (no B5 62 sync)")
    n = frame[4] | frame[5] << 8
    if len(frame) != n + 8:
        raise ProtocolError(f"UBX frame of {len(frame)} bytes, its length field says {n + 8}")
    if bytes(checksum(frame[2:6 + n])) != frame[6 + n:8 + n]:
        raise ProtocolError(f"checksum mismatch in {name_of((frame[2], frame[3]))}")
    return (frame[2], frame[3]), frame[6:6 + n]


def name_of(cls_id: tuple[int, int]) -> str:
    return NAMES.get(tuple(cls_id), f"{cls_id[0]:02X}-{cls_id[1]:02X}")


class FramingRule:
    """UBX framing for :class:`gpsins_logger.framing.FrameFinder`: a two-byte
    sync and a 16-bit checksum, so no counter is needed to reject false syncs."""

    name = "ublox"
    sync = SYNC1
    header_len = HEADER_LEN
    has_counter = False
    fixed_len = 0

    @staticmethod
    def header_ok(buf: bytearray, i: int) -> bool:
        return buf[i + 1] == SYNC2 and (buf[i + 4] | buf[i + 5] << 8) <= MAX_PAYLOAD

    @staticmethod
    def frame_len(buf: bytearray, i: int) -> int:
        return (buf[i + 4] | buf[i + 5] << 8) + 8

    @staticmethod
    def checksum_ok(buf: bytearray, i: int, n: int) -> bool:
        a, b = checksum(memoryview(buf)[i + 2:i + n - 2])
        return a == buf[i + n - 2] and b == buf[i + n - 1]

    @staticmethod
    def counter_gap(prev: bytes, buf: bytearray, j: int) -> int:  # pragma: no cover
        raise NotImplementedError("UBX frames carry no counter")

    @staticmethod
    def counter_end(j: int) -> int:  # pragma: no cover
        raise NotImplementedError("UBX frames carry no counter")


FRAMING = FramingRule()


class NmeaCounter:
    """Counts the NMEA sentences ($...*hh CR LF, printable, with a good checksum)
    in a byte stream fed in any chunking. u-blox receivers interleave them with
    UBX on one port; the frame finder discards them as foreign bytes. Searches
    with bytes.find: no Python loop over every byte of a busy port."""

    MAX_SENTENCE = 100
    _SENTENCE = re.compile(rb"\$([\x20-\x7e]*)\*([0-9A-Fa-f]{2})\r\n")

    def __init__(self):
        self.sentences = 0
        self.bytes = 0
        self._tail: bytes | None = None  # an unfinished sentence from the last feed

    def feed(self, data: bytes) -> None:
        buf = self._tail + data if self._tail is not None else data
        start = 0 if self._tail is not None else buf.find(b"$")
        self._tail = None
        while start >= 0:
            nxt = buf.find(b"$", start + 1)  # a '$' before the LF abandons the sentence
            end = buf.find(b"\n", start, nxt if nxt >= 0 else len(buf))
            if end >= 0:
                self._check(buf[start:end + 1])
            elif nxt < 0 and len(buf) - start <= self.MAX_SENTENCE:
                self._tail = bytes(buf[start:])
            start = nxt

    def _check(self, s: bytes) -> None:
        m = self._SENTENCE.fullmatch(s)
        if m is None or len(s) > self.MAX_SENTENCE:
            return
        cs = 0
        for x in m.group(1):
            cs ^= x
        if int(m.group(2), 16) == cs:
            self.sentences += 1
            self.bytes += len(s)


# --- configuration messages -----------------------------------------------------------------


def value_bytes(key: int) -> int:
    size = (key >> 28) & 7
    if size not in _VALUE_BYTES:
        raise ProtocolError(f"configuration key {key:#010x} has no valid size field ({size})")
    return _VALUE_BYTES[size]


def valset(items: list[tuple[int, int]], layers: int = LAYER_RAM) -> bytes:
    """UBX-CFG-VALSET (version 0) setting (key, value) pairs in the given layers."""
    if not 1 <= len(items) <= 64:
        raise ProtocolError(f"CFG-VALSET takes 1..64 keys, got {len(items)}")
    body = bytearray((0, layers, 0, 0))
    for key, value in items:
        body += struct.pack("<I", key) + int(value).to_bytes(value_bytes(key), "little")
    return encode_frame(CFG_VALSET, bytes(body))


def parse_valset(payload: bytes) -> tuple[int, list[tuple[int, int]]]:
    """(layers, [(key, value)]) of a CFG-VALSET payload (the emulator's side)."""
    if len(payload) < 4 or payload[0] not in (0, 1):
        raise ProtocolError("CFG-VALSET payload too short or of an unknown version")
    layers, i, out = payload[1], 4, []
    while i < len(payload):
        if i + 4 > len(payload):
            raise ProtocolError(f"CFG-VALSET key truncated at byte {i}")
        key = struct.unpack_from("<I", payload, i)[0]
        n = value_bytes(key)
        if i + 4 + n > len(payload):
            raise ProtocolError(f"CFG-VALSET value of key {key:#010x} truncated")
        out.append((key, int.from_bytes(payload[i + 4:i + 4 + n], "little")))
        i += 4 + n
    return layers, out


def cfg_rate(meas_ms: int, nav_ratio: int = 1, time_ref: int = 1) -> bytes:
    """Generation 8 UBX-CFG-RATE."""
    return encode_frame(CFG_RATE, struct.pack("<HHH", meas_ms, nav_ratio, time_ref))


def cfg_msg(cls_id: tuple[int, int], rate: int) -> bytes:
    """Generation 8 UBX-CFG-MSG, short form: the rate on the port it is sent on."""
    return encode_frame(CFG_MSG, bytes((*cls_id, rate)))


def poll(cls_id: tuple[int, int]) -> bytes:
    return encode_frame(cls_id)


def parse_mon_ver(payload: bytes) -> dict:
    text = lambda b: b.split(b"\0", 1)[0].decode("ascii", "replace").strip()  # noqa: E731
    if len(payload) < 40:
        raise ProtocolError(f"MON-VER payload of {len(payload)} bytes, needs 40")
    ext = [text(payload[k:k + 30]) for k in range(40, len(payload) - 29, 30)]
    return {"software": text(payload[:30]), "hardware": text(payload[30:40]), "extensions": [e for e in ext if e]}


@dataclass
class ConfigStep:
    """One configuration message and what the receiver said to it."""

    what: str  # e.g. "CFG-VALSET"
    frame: bytes
    settings: dict  # readable: key name or message -> value
    result: str = "pending"  # ack, nak, no answer

    @property
    def label(self) -> str:
        """The message, and for CFG-MSG the message it enables."""
        return f"{self.what} {next(iter(self.settings))}" if self.what == "CFG-MSG" else self.what

    def record(self) -> dict:
        return {"message": self.what, "settings": self.settings, "frame_hex": self.frame.hex(), "result": self.result}


def setup_steps(generation: int, interface: str, measurement_rate_hz: float, messages: list[str]) -> list[ConfigStep]:
    """The configuration messages for a receiver, in the order they are sent."""
    meas_ms = int(round(1000.0 / measurement_rate_hz))
    if generation == 9:
        items = [(CFG_RATE_MEAS, meas_ms), (CFG_RATE_NAV, 1), (CFG_RATE_TIMEREF, 1)]
        items += [(MSGOUT_KEYS[m][interface], 1) for m in messages]
        return [ConfigStep("CFG-VALSET", valset(items), {KEY_NAMES[k]: v for k, v in items} | {"layers": "RAM"})]
    steps = [ConfigStep("CFG-RATE", cfg_rate(meas_ms), {"measRate_ms": meas_ms, "navRate": 1, "timeRef": "GPS"})]
    steps += [ConfigStep("CFG-MSG", cfg_msg(BY_NAME[m], 1), {m: 1}) for m in messages]
    return steps


@dataclass
class Setup:
    """The set-up handshake, driven by the port thread: start() after the
    open, on_frame() for every frame read, tick() when the line is quiet
    (both return True when the record changed). Each step waits for its
    ACK/NAK up to ack_timeout_s; MON-VER too. Unacknowledged steps are
    retried with back-off; `done` is True once all are acknowledged."""

    steps: list[ConfigStep]
    ack_timeout_s: float = 1.0
    poll_version: bool = True
    sensor: str = "gps"
    version: dict | None = None
    retry_max_s: float = 10.0  # longest wait between set-up attempts
    REMINDER_S = 60.0  # while unconfigured, one warning this often
    attempts: int = 0
    _queue: list = field(default_factory=list)
    _waiting: object = None  # the step (or "MON-VER") awaiting an answer
    _deadline: float = 0.0
    _retry_at: float | None = None  # when the unacknowledged steps go again
    _backoff: float = 1.0
    _since: float = 0.0  # when this open's set-up began
    _began: float = 0.0  # when this attempt began
    _reminded: float = 0.0

    def start(self, write) -> None:
        self._write = write
        for s in self.steps:
            s.result = "pending"
        self.attempts = 0
        self._backoff = min(1.0, self.retry_max_s)
        self._retry_at = None
        self._since = self._reminded = time.monotonic()
        self._begin(["MON-VER"] if self.poll_version else [])

    def _begin(self, first: list) -> None:
        self.attempts += 1
        self._began = time.monotonic()
        self._queue = first + [s for s in self.steps if s.result != "ack"]
        self._waiting = None
        self._next()

    @property
    def done(self) -> bool:
        return self._waiting is None and not self._queue and self._retry_at is None

    def unconfigured(self) -> str:
        """What the receiver last said to the steps not acknowledged ("NAK
        CFG-VALSET"), or "" when all are acknowledged or still first asked."""
        return ", ".join(f"{'NAK' if s.result == 'nak' else s.result} {s.label}" for s in self.steps
                         if s.result not in ("ack", "pending"))

    def _next(self) -> None:
        if not self._queue:
            self._waiting = None
            if self.steps:
                self._attempt_over()
            return
        item = self._queue.pop(0)
        self._waiting = item
        self._deadline = time.monotonic() + self.ack_timeout_s
        self._write(poll(MON_VER) if item == "MON-VER" else item.frame)

    def _attempt_over(self) -> None:
        bad = [s for s in self.steps if s.result != "ack"]
        now = time.monotonic()
        if not bad:
            self._retry_at = None
            log.info("%s: receiver set-up acknowledged (%d message(s))%s", self.sensor, len(self.steps),
                     f" at attempt {self.attempts}, {now - self._since:.0f} s after the open"
                     if self.attempts > 1 else "")
            return
        # Attempts start back-off seconds apart (1, 2, 4, ... retry_max_s), never overlapping.
        self._retry_at = max(now, self._began + self._backoff)
        self._backoff = min(2 * self._backoff, self.retry_max_s)
        if self.attempts == 1:
            log.error("%s: receiver set-up incomplete: %s; logging what the receiver sends, trying again every "
                      "%g s at most", self.sensor, ", ".join(f"{s.what} {s.result}" for s in bad), self.retry_max_s)
        elif now - self._reminded >= self.REMINDER_S:
            self._reminded = now
            log.warning("%s: receiver still unconfigured after %d attempts in %.0f s (%s); trying again every %g s",
                        self.sensor, self.attempts, now - self._since, self.unconfigured(), self.retry_max_s)

    def on_frame(self, frame: bytes) -> bool:
        if self._waiting is None or len(frame) < 8:
            return False
        cls_id = (frame[2], frame[3])
        if self._waiting == "MON-VER":
            if cls_id == MON_VER:
                try:
                    self.version = parse_mon_ver(frame[6:-2])
                    log.info("%s: receiver %s, hardware %s", self.sensor, self.version["software"],
                             self.version["hardware"])
                except ProtocolError:
                    pass
                self._next()
                return True
            return False
        step = self._waiting
        if cls_id in (ACK_ACK, ACK_NAK) and len(frame) >= 10 and tuple(frame[6:8]) == BY_NAME[step.what]:
            step.result = "ack" if cls_id == ACK_ACK else "nak"
            if step.result == "nak" and self.attempts == 1:  # retries are summed up by the reminder
                log.error("%s: the receiver refused (ACK-NAK) %s %s", self.sensor, step.what, step.settings)
            self._next()
            return True
        return False

    def tick(self) -> bool:
        now = time.monotonic()
        if self._waiting is None:
            if self._retry_at is None or now < self._retry_at:
                return False
            self._retry_at = None
            self._begin(["MON-VER"] if self.poll_version and self.version is None else [])
            return True
        if now < self._deadline:
            return False
        if self._waiting == "MON-VER":
            if self.attempts == 1:
                log.warning("%s: no MON-VER answer within %.1f s (version unknown)", self.sensor, self.ack_timeout_s)
        else:
            self._waiting.result = "no answer"
            if self.attempts == 1:
                log.error("%s: no ACK for %s within %.1f s: is the baud rate right, is it a u-blox receiver?",
                          self.sensor, self._waiting.what, self.ack_timeout_s)
        self._next()
        return True

    def record(self) -> dict:
        return {"version": self.version, "configured": all(s.result == "ack" for s in self.steps),
                "attempts": self.attempts, "configuration": [s.record() for s in self.steps]}

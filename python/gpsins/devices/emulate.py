"""Pty device emulators: a Superstar II receiver and a BP3010 IMU on virtual serial ports.

Each device is a pty pair in raw mode behind a stable symlink (a reopened
pty gets a new /dev/pts path; the symlink is re-pointed). Bytes are paced as
the real line would deliver them (ptys ignore the baud rate): a frame is
written in chunks, each when its last byte would have arrived on the wire.

The GPS emulator sends nothing until asked and honours continuous, once and
stop requests and the ID 23 rate; the IMU emulator streams once the host is
there (its first rate-select command) and honours rate changes. Faults can be
injected with exact bookkeeping: every frame's fate is in ``sent``.
"""

from __future__ import annotations

import errno
import fcntl
import os
import select
import struct
import termios
import threading
import time
import tty
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from gpsins_logger import bp3010
from gpsins_logger import superstar2 as ss2
from gpsins_logger import ubx
from gpsins_logger.framing import FrameFinder

from ..formats.messages import MessageSource

BITS_PER_BYTE = 10
DRAIN_WAIT_S = 0.25  # longest wait for the host to read a frame before an overlapping one follows
DRAIN_POLL_S = 0.0002


@dataclass
class Faults:
    """Per-frame fault probabilities and scheduled disconnects (all seeded)."""

    garbage: float = 0.0  # insert 1..garbage_max random bytes before the frame
    garbage_max: int = 40
    bit_flip: float = 0.0  # flip one random bit of the frame
    drop: float = 0.0  # do not send the frame
    truncate: float = 0.0  # send only a random prefix of the frame (at least 2 bytes short)
    disconnects: list[tuple[float, float]] = field(default_factory=list)  # (run time s, seconds down)
    seed: int = 0


@dataclass
class SentFrame:
    frame: bytes  # the frame as the device produced it
    fate: str  # "ok", "flipped", "dropped", "truncated", "offline", "interrupted",
    # or "unread": still in the host's input buffer, unread, when the device was unplugged
    first_byte_realtime: float  # when its first byte was on the line (time.time())
    garbage_before: int = 0
    wire_bytes: int = 0  # bytes of the frame put on the line (less when truncated)


class PtyLink:
    """A pty pair in raw mode behind a symlink; reopen() emulates unplug/replug."""

    def __init__(self, link: Path):
        self.link = Path(link)
        self.master = -1
        self.slave = -1
        self.generation = 0
        self.open()

    def open(self) -> None:
        self.master, self.slave = os.openpty()
        tty.setraw(self.master)
        tty.setraw(self.slave)  # a fresh pty is cooked and would eat bytes like 0x03
        os.set_blocking(self.master, False)
        tmp = self.link.with_name(self.link.name + ".tmp")
        if tmp.is_symlink() or tmp.exists():
            tmp.unlink()
        tmp.symlink_to(os.ttyname(self.slave))
        os.replace(tmp, self.link)  # atomic re-point
        self.generation += 1

    def close(self) -> None:
        for fd in (self.master, self.slave):
            if fd >= 0:
                os.close(fd)
        self.master = self.slave = -1

    def unread_bytes(self) -> int:
        """Bytes written that the host has not read yet (its tty input queue)."""
        if self.slave < 0:
            return 0
        try:
            return struct.unpack("i", fcntl.ioctl(self.slave, termios.FIONREAD, b"\0\0\0\0"))[0]
        except OSError:
            return 0

    def host_has_unread(self) -> bool:
        """Whether the host has bytes to read. Written bytes reach its queue through a kernel work
        item, milliseconds later on a loaded machine; polling the queue's end (select) finishes
        that first, so the answer holds for everything written."""
        if self.slave < 0:
            return False
        try:
            return bool(select.select([self.slave], [], [], 0)[0])
        except (OSError, ValueError):
            return False

    def remove(self) -> None:
        self.close()
        if self.link.is_symlink():
            self.link.unlink()

    def write_all(self, data: bytes, deadline: float) -> bool:
        """Write everything unless the host stops reading until the deadline."""
        view = memoryview(data)
        while view:
            try:
                n = os.write(self.master, view)
                view = view[n:]
            except BlockingIOError:
                if time.monotonic() > deadline:
                    return False
                select.select([], [self.master], [], 0.01)
            except OSError as e:
                if e.errno in (errno.EIO, errno.EBADF):
                    return False
                raise
        return True

    def read_available(self) -> bytes:
        try:
            return os.read(self.master, 4096)
        except (BlockingIOError, InterruptedError):
            return b""
        except OSError as e:
            if e.errno == errno.EIO:  # nobody has the slave open
                return b""
            raise


def _tight_timers() -> None:
    """This thread's sleeps end on time (Linux: timer slack 1 us instead of 50 us). A device that
    wakes late delays its bytes, which a drive served S times faster shows S times larger."""
    try:
        import ctypes

        ctypes.CDLL(None, use_errno=True).prctl(29, 1000, 0, 0, 0)  # PR_SET_TIMERSLACK, ns
    except (OSError, AttributeError):
        pass


class DeviceEmulator(threading.Thread):
    """Common machinery: pacing, faults, disconnects, host input."""

    device = "?"

    def __init__(self, link: Path, source: MessageSource, baud: int, speed: float = 1.0,
                 faults: Faults | None = None, chunk_bytes: int = 16):
        super().__init__(name=f"emulate-{self.device}", daemon=True)
        self.pty = PtyLink(link)
        self.source = source
        self.speed = speed
        self.byte_time_s = BITS_PER_BYTE / baud / speed
        self.line_byte_s = BITS_PER_BYTE / baud  # the configured line's byte time, as the host counts it
        self.faults = faults or Faults()
        self.chunk_bytes = chunk_bytes
        self.rng = np.random.default_rng([self.faults.seed, 1 if self.device == "superstar2" else 2])
        self.sent: list[SentFrame] = []
        self.garbage_bytes = 0
        self.disconnect_count = 0
        self.replugged_realtime: list[float] = []  # when the device came back after each disconnect
        self._inflight: tuple[SentFrame, int] | None = None  # the frame being written, bytes written so far
        self._stop_event = threading.Event()
        self._line_free = 0.0
        self._line_done = -np.inf  # when the configured line would have carried the last frame's bytes
        self._start_mono = 0.0
        self.start_mono: float | None = None  # a run start shared with other devices (set before start())
        self._mono_to_real = 0.0
        self._online = True
        self._pending_disconnects = sorted(self.faults.disconnects)
        self.host_requests: list[bytes] = []
        self.done = threading.Event()

    # -- time -------------------------------------------------------------------
    def run_time(self) -> float:
        return (time.monotonic() - self._start_mono) * self.speed

    def _mono_at(self, t: float) -> float:
        return self._start_mono + t / self.speed

    def stop(self) -> None:
        self._stop_event.set()

    def _wait_until(self, mono: float) -> bool:
        """Sleep until `mono`, serving host input; False when stopping."""
        while True:
            if self._stop_event.is_set():
                return False
            now = time.monotonic()
            if now >= mono:
                return True
            self._service(min(mono - now, 0.05))

    def _service(self, timeout: float) -> None:
        """Wait up to timeout for host bytes and handle them; handle disconnects."""
        if self._pending_disconnects and self.run_time() >= self._pending_disconnects[0][0]:
            _, down = self._pending_disconnects.pop(0)
            self._disconnect(down)
            return
        if self._online:
            r, _, _ = select.select([self.pty.master], [], [], max(timeout, 0.0))
            if r:
                data = self.pty.read_available()
                if data:
                    self.on_host_bytes(data)
        else:
            time.sleep(max(timeout, 0.0))

    def _disconnect(self, down_s: float) -> None:
        # An unplug as udev shows it: the device node and its stable name vanish.
        self.disconnect_count += 1
        self._online = False
        # Bytes written a moment ago may still be on their way through the
        # kernel (a busy CPU delays it): let them land before counting what
        # the host has not read.
        self._stop_event.wait(0.1)
        self._mark_unread(self.pty.unread_bytes())
        self.pty.remove()
        self.on_disconnect()
        self._stop_event.wait(down_s / self.speed)
        self.pty.open()
        self.replugged_realtime.append(time.time())
        self._online = True

    def _mark_unread(self, pending: int) -> None:
        """Frames whose bytes the host had not read when the cable was pulled
        are lost with the device (a busy host reads late); they are not 'ok'."""
        inflight = self._inflight
        for sent in reversed(self.sent):
            if pending <= 0:
                break
            on_line = sent.wire_bytes + sent.garbage_before
            if inflight is not None and sent is inflight[0]:
                on_line = inflight[1]  # a frame being sent: only its bytes written so far
            if on_line and sent.fate == "ok":
                sent.fate = "unread"
            pending -= on_line

    # -- sending ------------------------------------------------------------------
    def send_frame(self, frame: bytes, t: float) -> None:
        """Put a frame on the line at run time t (or when the line is free)."""
        if not self._online or not self.host_present():
            self.sent.append(SentFrame(frame, "offline", float("nan")))
            return
        f = self.faults
        fate, wire = "ok", frame
        u = self.rng.random(4)
        if u[0] < f.drop:
            self.sent.append(SentFrame(frame, "dropped", float("nan")))
            return
        if u[1] < f.bit_flip:
            bit = int(self.rng.integers(0, 8 * len(frame)))
            b = bytearray(frame)
            b[bit // 8] ^= 1 << (bit % 8)
            wire, fate = bytes(b), "flipped"
        elif u[2] < f.truncate:
            # At least two bytes go: a frame cut by its last byte alone is completed
            # by the next frame's first byte whenever that equals the lost checksum,
            # and is then the intact frame, byte for byte.
            wire, fate = frame[:int(self.rng.integers(1, len(frame) - 1))], "truncated"
        garbage = b""
        if u[3] < f.garbage:
            garbage = self.rng.integers(0, 256, int(self.rng.integers(1, f.garbage_max + 1)), dtype=np.uint8).tobytes()
            self.garbage_bytes += len(garbage)
        data = garbage + wire
        start = max(self._mono_at(t), self._line_free)
        # The host dates a frame's first byte back from when it read the frame, at its configured
        # byte time. Served S times faster, bytes on the sped-up line would make that date early by
        # (length - 1) byte times (1 - 1/S), a length-dependent error the alignment cannot see. So
        # the first byte takes the sped-up byte time and the rest of the frame follows at the
        # line's own: the host's date is then the first byte's end at every speed.
        first_byte = start + len(garbage) * self.line_byte_s
        record = SentFrame(frame, fate, first_byte + self._mono_to_real, len(garbage), len(wire))
        self.sent.append(record)
        generation = self.pty.generation
        self._inflight = (record, 0)
        # Faster than the line can carry, this frame starts before the last one would have left it;
        # read together, the last one would be dated back over this one's bytes too (early). So the
        # host reads it first (waited for ahead of the write, which then goes out on time).
        if start < self._line_done and not self._wait_for_host_read(time.monotonic() + DRAIN_WAIT_S):
            return
        for k in range(0, len(data), self.chunk_bytes):
            chunk = data[k:k + self.chunk_bytes]
            if not self._wait_until(start + self.byte_time_s + (k + len(chunk) - 1) * self.line_byte_s):
                return
            if self.pty.generation != generation or not self._online or not self.pty.write_all(
                    chunk, time.monotonic() + 1.0):
                record.fate = "interrupted"  # the cable was pulled mid-frame
                return
            self._inflight = (record, k + len(chunk))
        self._inflight = None
        self._line_free = start + len(data) * self.byte_time_s
        self._line_done = start + len(data) * self.line_byte_s

    def _wait_for_host_read(self, deadline: float) -> bool:
        """Serve host input until the host has read every byte written (or the deadline); False when stopping."""
        while self._online and time.monotonic() < deadline and self.pty.host_has_unread():
            if self._stop_event.is_set():
                return False
            self._service(DRAIN_POLL_S)
        return not self._stop_event.is_set()

    # -- hooks --------------------------------------------------------------------
    def host_present(self) -> bool:
        return True

    def on_host_bytes(self, data: bytes) -> None:
        pass

    def on_disconnect(self) -> None:
        pass

    def run(self) -> None:
        _tight_timers()
        self._start_mono = time.monotonic() if self.start_mono is None else self.start_mono
        self._mono_to_real = time.time() - time.monotonic()
        self._line_free = self._start_mono
        try:
            self.stream()
        finally:
            self.done.set()

    def stream(self) -> None:
        raise NotImplementedError


class GpsEmulator(DeviceEmulator):
    device = "superstar2"

    def __init__(self, link: Path, source: MessageSource, baud: int = 115200, **kw):
        super().__init__(link, source, baud, **kw)
        self._finder = FrameFinder(ss2.FRAMING)
        self.continuous: set[int] = set()
        self.once: set[int] = set()
        self.raw_rate_hz: int | None = None

    def on_host_bytes(self, data: bytes) -> None:
        for frame in self._finder.feed(data):
            self.host_requests.append(frame.data)
            req = ss2.decode_request(frame.data)
            if req.msg_id == ss2.ID_LINK_OPEN:
                continue
            if req.msg_id == ss2.ID_MEASUREMENTS:
                self.raw_rate_hz = req.raw_rate_hz  # bit 7 clear (stop) gives None
            elif req.continuous:
                self.continuous.add(req.msg_id)
            else:
                self.once.add(req.msg_id)

    def on_disconnect(self) -> None:
        # Replugging resets the link: nothing is sent until the host asks again.
        self.continuous.clear()
        self.once.clear()
        self.raw_rate_hz = None
        self._finder = FrameFinder(ss2.FRAMING)

    def _wanted(self, m) -> bool:
        if m.msg_id == ss2.ID_MEASUREMENTS:
            if not self.raw_rate_hz:
                return False
            x = m.tow_s * self.raw_rate_hz
            return abs(x - round(x)) < 1e-6
        if m.msg_id in self.continuous:
            return True
        if m.msg_id in self.once:
            self.once.discard(m.msg_id)
            return True
        return False

    def stream(self) -> None:
        for m in self.source.gps_messages():
            if not self._wait_until(self._mono_at(m.t)):
                return
            if self._wanted(m):
                self.send_frame(m.frame, m.t)


class ImuEmulator(DeviceEmulator):
    device = "bp3010"

    def __init__(self, link: Path, source: MessageSource, baud: int = 38400, wait_for_host: bool = True, **kw):
        super().__init__(link, source, baud, **kw)
        self.rate_hz = bp3010.NOMINAL_RATE_HZ
        self._rate_changed = False
        self.wait_for_host = wait_for_host
        self._host_seen = not wait_for_host
        self._pending = b""
        self.counter = 0

    def host_present(self) -> bool:
        return self._host_seen

    def on_host_bytes(self, data: bytes) -> None:
        self._pending = (self._pending + data)[-64:]
        while len(self._pending) >= 2:
            i = self._pending.find(b"\x7b")
            if i < 0 or i + 1 >= len(self._pending):
                self._pending = self._pending[i:] if i >= 0 else b""
                break
            cmd = self._pending[i:i + 2]
            self._pending = self._pending[i + 2:]
            self.host_requests.append(cmd)
            rate = bp3010.rate_from_command(cmd)
            if rate:
                self._host_seen = True
                if rate != self.rate_hz:
                    self.rate_hz = rate
                    self._rate_changed = True

    def on_disconnect(self) -> None:
        self._host_seen = not self.wait_for_host

    def stream(self) -> None:
        t0 = 0.0
        while not self._stop_event.is_set():
            self._rate_changed = False
            rate = self.rate_hz
            for s in self.source.imu_samples(rate, t0):
                if not self._wait_until(self._mono_at(s.t)):
                    return
                sample = s.sample
                sample.counter = self.counter
                self.counter = (self.counter + 1) & 0xFF
                self.send_frame(sample.encode(rate), s.t)
                if self._rate_changed:
                    t0 = s.t + 1e-9
                    break
            else:
                return


class Emulators:
    """Both devices under one directory: <dir>/gps and <dir>/imu."""

    def __init__(self, directory: Path, source: MessageSource, speed: float = 1.0, gps_faults: Faults | None = None,
                 imu_faults: Faults | None = None, gps_baud: int = 115200, imu_baud: int = 38400,
                 imu_wait_for_host: bool = True):
        directory = Path(directory)
        directory.mkdir(parents=True, exist_ok=True)
        self.gps = GpsEmulator(directory / "gps", source, gps_baud, speed=speed, faults=gps_faults)
        self.imu = ImuEmulator(directory / "imu", source, imu_baud, wait_for_host=imu_wait_for_host, speed=speed,
                               faults=imu_faults)

    @property
    def devices(self) -> list[DeviceEmulator]:
        return [self.gps, self.imu]

    def start(self) -> None:
        # One run start for all devices: threads start a fraction of a millisecond apart, which a
        # drive served S times faster would turn into S times that offset between the streams.
        t0 = time.monotonic() + 0.01
        for d in self.devices:
            d.start_mono = t0
        for d in self.devices:
            d.start()

    def wait(self, timeout: float | None = None) -> bool:
        deadline = None if timeout is None else time.monotonic() + timeout
        for d in self.devices:
            left = None if deadline is None else max(0.0, deadline - time.monotonic())
            if not d.done.wait(left):
                return False
        return True

    def stop(self) -> None:
        for d in self.devices:
            d.stop()
        for d in self.devices:
            if d.is_alive():
                d.join(timeout=5.0)
        for d in self.devices:
            d.pty.remove()


class UbloxEmulator(DeviceEmulator):
    """A u-blox receiver on a pty: answers CFG-VALSET (and generation 8's
    CFG-RATE / CFG-MSG) with ACK-ACK and MON-VER polls with its version, then
    sends the UBX messages the host enabled (RXM-RAWX decimated to the set
    measurement rate), and NMEA GGA throughout as a receiver does by default.
    ``config_fault``: "nak" refuses every configuration message, "silent"
    answers nothing (both leave the receiver unconfigured). With a recorded
    capture as the source (``serve_all``), every frame and sentence of the
    capture is served as recorded, whatever the host configured."""

    device = "ublox"
    SOFTWARE = "EXT CORE 1.00 (emulated)"
    HARDWARE = "00190000"

    def __init__(self, link: Path, source, baud: int = 115200, config_fault: str | None = None,
                 serve_all: bool = False, **kw):
        super().__init__(link, source, baud, **kw)
        if config_fault not in (None, "nak", "silent"):
            raise ValueError(f"config_fault must be None, 'nak' or 'silent', got {config_fault!r}")
        self.config_fault = config_fault
        self.serve_all = serve_all
        self._finder = FrameFinder(ubx.FRAMING)
        self._replies: list[bytes] = []
        self.enabled: set[str] = set()
        self.meas_rate_hz: float | None = None
        self.config_log: list[tuple[str, str]] = []  # (message, answer)

    def on_host_bytes(self, data: bytes) -> None:
        for frame in self._finder.feed(data):
            self.host_requests.append(frame.data)
            try:
                cls_id, payload = ubx.decode_frame(frame.data)
            except ubx.ProtocolError:
                continue
            if cls_id == ubx.MON_VER and not payload:
                if self.config_fault != "silent":
                    ver = self.SOFTWARE.encode().ljust(30, b"\0") + self.HARDWARE.encode().ljust(10, b"\0")
                    ver += b"PROTVER=27.11".ljust(30, b"\0")
                    self._replies.append(ubx.encode_frame(ubx.MON_VER, ver))
                continue
            if cls_id not in (ubx.CFG_VALSET, ubx.CFG_RATE, ubx.CFG_MSG):
                continue
            answer = self._configure(cls_id, payload) if self.config_fault is None else self.config_fault
            self.config_log.append((ubx.name_of(cls_id), answer))
            if answer != "silent":
                self._replies.append(ubx.encode_frame(ubx.ACK_ACK if answer == "ack" else ubx.ACK_NAK,
                                                      bytes(cls_id)))

    def _configure(self, cls_id, payload: bytes) -> str:
        try:
            if cls_id == ubx.CFG_VALSET:
                _, items = ubx.parse_valset(payload)
                msgout = {k: m for m, ports in ubx.MSGOUT_KEYS.items() for k in ports.values()}
                for key, value in items:
                    if key == ubx.CFG_RATE_MEAS:
                        self.meas_rate_hz = 1000.0 / value
                    elif key in msgout:
                        (self.enabled.add if value else self.enabled.discard)(msgout[key])
                    elif key not in ubx.KEY_NAMES:
                        return "nak"  # a key this receiver does not know: the whole set is refused
            elif cls_id == ubx.CFG_RATE:
                self.meas_rate_hz = 1000.0 / struct.unpack_from("<H", payload)[0]
            else:
                name = ubx.name_of((payload[0], payload[1]))
                (self.enabled.add if payload[2] else self.enabled.discard)(name)
        except (ubx.ProtocolError, struct.error, IndexError, ZeroDivisionError):
            return "nak"
        return "ack"

    def on_disconnect(self) -> None:
        # A replug powers the receiver down: the RAM configuration is gone.
        self.enabled.clear()
        self.meas_rate_hz = None
        self._replies.clear()
        self._finder = FrameFinder(ubx.FRAMING)

    def _wanted(self, m) -> bool:
        if self.serve_all or m.msg_id == "NMEA":
            return True
        if m.msg_id not in self.enabled:
            return False
        if m.msg_id == "RXM-RAWX" and self.meas_rate_hz:
            x = m.tow_s * self.meas_rate_hz
            return abs(x - round(x)) < 1e-6
        return True

    def _flush_replies(self) -> None:
        while self._replies:
            self.send_frame(self._replies.pop(0), self.run_time())

    def _wait_until(self, mono: float) -> bool:
        # Answers go out as soon as the line is free, between the messages.
        while True:
            if not super()._wait_until(min(mono, time.monotonic() + 0.02)):
                return False
            if self._replies and self._inflight is None:
                self._flush_replies()
            if time.monotonic() >= mono:
                return True

    def stream(self) -> None:
        if self.serve_all:
            # A capture is served from its start once the host listens (its first poll or
            # configuration message), so nothing of it is lost to a late open.
            while not self.host_requests:
                if not self._wait_until(time.monotonic() + 0.02):
                    return
            self._start_mono = self._line_free = time.monotonic()
        for m in self.source.gps_messages():
            if not self._wait_until(self._mono_at(m.t)):
                return
            if self._wanted(m):
                self.send_frame(m.frame, m.t)
        # Keep answering the host until stopped, as a powered receiver does.
        self.done.set()
        while self._wait_until(time.monotonic() + 0.05):
            pass


class UbloxEmulators(Emulators):
    """A u-blox receiver at <dir>/gps; with ``bp3010`` also a BP3010 at <dir>/imu
    (for a receiver without sensors), else the receiver's own ESF-RAW is the IMU."""

    def __init__(self, directory: Path, source: MessageSource, speed: float = 1.0, gps_faults: Faults | None = None,
                 imu_faults: Faults | None = None, gps_baud: int = 460800, imu_baud: int = 38400,
                 bp3010: bool = False, config_fault: str | None = None, serve_all: bool = False):
        directory = Path(directory)
        directory.mkdir(parents=True, exist_ok=True)
        # A capture goes out in bigger chunks: it is dense, and served faster than real time.
        self.gps = UbloxEmulator(directory / "gps", source, gps_baud, config_fault=config_fault, serve_all=serve_all,
                                 speed=speed, faults=gps_faults, chunk_bytes=256 if serve_all else 16)
        self.imu = ImuEmulator(directory / "imu", source, imu_baud, speed=speed, faults=imu_faults) if bp3010 else None

    @property
    def devices(self) -> list[DeviceEmulator]:
        return [d for d in (self.gps, self.imu) if d is not None]


def serve_until_signalled(em, banner: str) -> int:
    """Start the emulators, say what they serve, and serve until the source ends or SIGINT/SIGTERM."""
    import signal

    stop = {"now": False}
    for sig in (signal.SIGINT, signal.SIGTERM):
        signal.signal(sig, lambda *_: stop.update(now=True))
    em.start()
    print(banner, flush=True)
    try:
        while not stop["now"] and not em.wait(0.2):
            pass
    finally:
        em.stop()
    return 0


def run_ublox(args) -> int:
    """`gpsins emulate --device ublox`: a simulated F9R-like receiver, or a recorded UBX capture (--ubx)."""
    import sys

    if args.ubx:
        from .sources import UbxCaptureSource

        source, what = UbxCaptureSource(args.ubx), f"UBX capture {args.ubx}"
    elif args.session:
        print("gpsins emulate: --session serves a Superstar II session; give a UBX capture with --ubx",
              file=sys.stderr)
        return 2
    else:
        from ..sim.scenario import load
        from ..sim import simulate
        from ..sim.ublox import UbloxSimSource

        sc = load(args.scenario)
        source, what = UbloxSimSource(simulate(sc, args.seed), sensors=not args.bp3010), f"scenario {sc.name}"
    em = UbloxEmulators(Path(args.dir), source, speed=args.speed, gps_baud=args.baud, bp3010=args.bp3010,
                        config_fault=args.config_fault, serve_all=bool(args.ubx))
    imu = f" and a BP3010 on {Path(args.dir) / 'imu'}" if args.bp3010 else ""
    return serve_until_signalled(em, f"serving {what} ({source.duration_s:.0f} s at speed {args.speed:g}) as a u-blox "
                                     f"receiver on {Path(args.dir) / 'gps'} ({args.baud} Bd){imu}")

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

import select
import threading
import time
from pathlib import Path

import numpy as np

from gpsins_logger import bp3010
from gpsins_logger import superstar2 as ss2
from gpsins_logger.framing import FrameFinder

from ..formats.messages import MessageSource
from .pty import BITS_PER_BYTE, DRAIN_POLL_S, DRAIN_WAIT_S, Faults, PtyLink, SentFrame, tight_timers


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
        tight_timers()
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

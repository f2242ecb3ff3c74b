"""One sensor's thread: open, initialise, blocking read, stamp, record; reopen on loss.

The stamp of a frame is the system time (CLOCK_REALTIME) at which its first
byte arrived, estimated from the return time of a read that delivered bytes
of the frame minus the bytes after the first one at the line's byte time.
The earliest such read gives the tightest estimate (later reads may have
waited for more bytes).
"""

from __future__ import annotations

import collections
import logging
import threading
import time

import serial

from . import bp3010, superstar2
from .framing import FrameFinder
from .recorder import Session

log = logging.getLogger(__name__)

DEVICES = {
    "superstar2": (superstar2.FRAMING, superstar2.HEADER_LEN),
    "bp3010": (bp3010.FRAMING, 1),
}
BITS_PER_BYTE = 10  # 8N1: start bit, 8 data bits, stop bit


class SensorThread(threading.Thread):
    def __init__(self, name: str, device: str, port: str, baud: int, requests: list[bytes], session: Session,
                 raw_capture: bool = False, initial_backoff_s: float = 0.2, max_backoff_s: float = 5.0):
        super().__init__(name=f"sensor-{name}", daemon=True)
        self.sensor = name
        self.rule, self.header_len = DEVICES[device]
        self.port_name = port
        self.baud = baud
        self.byte_time_s = BITS_PER_BYTE / baud
        self.requests = requests
        self.session = session
        self.raw_capture = raw_capture
        self.initial_backoff_s = initial_backoff_s
        self.max_backoff_s = max_backoff_s
        self.counts = session.extra_counts[name]
        self.counts.update(reconnects=0, discarded_bytes=0, checksum_failures=0, lock_losses=0, unfinished_bytes=0,
                           bytes_read=0)
        self._stop_event = threading.Event()
        self._serial: serial.Serial | None = None
        self._lock = threading.Lock()

    def stop(self) -> None:
        self._stop_event.set()
        with self._lock:
            if self._serial is not None:
                try:
                    self._serial.cancel_read()  # wakes the blocking read
                except Exception:  # the port may be closing under us
                    pass

    def run(self) -> None:
        backoff = self.initial_backoff_s
        first = True
        while not self._stop_event.is_set():
            try:
                self._open()
                if not first:
                    self.counts["reconnects"] += 1
                    log.info("%s: reopened %s", self.sensor, self.port_name)
                first = False
                backoff = self.initial_backoff_s
                self._read_loop()
            except (serial.SerialException, OSError) as e:
                if self._stop_event.is_set():
                    break
                log.warning("%s: port %s lost (%s); retrying in %.1f s", self.sensor, self.port_name, e, backoff)
                first = False
                self._close()
                self._stop_event.wait(backoff)
                backoff = min(2 * backoff, self.max_backoff_s)
            finally:
                self._close()

    def _open(self) -> None:
        s = serial.Serial(self.port_name, self.baud, bytesize=8, parity="N", stopbits=1, timeout=None,
                          exclusive=True)
        with self._lock:
            self._serial = s
        if self._stop_event.is_set():  # stop() came while opening
            return
        # Bytes that arrived before we listened have no usable stamp.
        s.reset_input_buffer()
        for req in self.requests:
            s.write(req)
        s.flush()

    def _close(self) -> None:
        with self._lock:
            s, self._serial = self._serial, None
        if s is not None:
            try:
                s.close()
            except Exception:
                pass

    def _read_loop(self) -> None:
        s = self._serial
        finder = FrameFinder(self.rule)
        # (stream offset just past the read's last byte, realtime at its return)
        reads: collections.deque[tuple[int, float]] = collections.deque(maxlen=64)
        try:
            while s is not None and not self._stop_event.is_set():
                data = s.read(1)  # blocks until a byte arrives, or cancel_read()
                if not data:
                    continue
                waiting = s.in_waiting
                if waiting:
                    data += s.read(waiting)
                realtime, monotonic = time.time(), time.monotonic()
                self.counts["bytes_read"] += len(data)
                if self.raw_capture:
                    self.session.raw(self.sensor, data, monotonic, realtime)
                reads.append((finder.stats.bytes_in + len(data), realtime))
                for frame in finder.feed(data):
                    self.session.record(self.sensor, frame.data, self._stamp(frame.offset, reads))
        finally:
            for key in ("discarded_bytes", "checksum_failures", "lock_losses"):
                self.counts[key] += getattr(finder.stats, key)
            # Bytes of a frame still incomplete when the port closed.
            self.counts["unfinished_bytes"] += finder.pending

    def _stamp(self, offset: int, reads) -> float:
        best = float("inf")
        for end, t in reversed(reads):
            if end <= offset:
                break
            best = min(best, t - (end - offset - 1) * self.byte_time_s)
        return best

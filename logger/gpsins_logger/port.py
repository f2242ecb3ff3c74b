"""One sensor's thread: open, initialise, blocking read, stamp, record; reopen on loss.

Port states (in the log and the sidecar's `port_state`):

- ``open``: reading.
- ``unconfigured``: reading, but the receiver refused or did not answer its
  set-up (u-blox); the reason names the messages. The set-up is retried.
- ``absent``: the device path does not exist (unplugged). Its existence is
  polled every `poll_interval_s`, so a replugged device is reopened within
  about that time.
- ``unopenable``: the path exists but opening fails (permission, busy,
  locked by another program). The reason is named; opening is retried every
  `unopenable_retry_s`, or at once when the path changes (a new device node
  or new permissions); with `give_up_after_s` > 0 the thread stops after
  that long in this state (``gave_up``). A busy or locked device is tried
  every `busy_poll_s` instead: a lock going away changes nothing on the
  node, and a second logger taking over from a first should lose no more.

A u-blox receiver is set up by a handshake after every open (ubx.Setup: each
configuration message waits for its ACK, the read wakes every 0.1 s to time
out an unanswered one); the NMEA sentences on its port are counted.

The stamp of a frame is the system time (CLOCK_REALTIME) at which its first
byte arrived, estimated from the return time of a read that delivered bytes
of the frame minus the bytes after the first one at the line's byte time.
The earliest such read gives the tightest estimate (later reads may have
waited for more bytes). The estimate is made on CLOCK_MONOTONIC and kept in order there: an
estimate earlier than the previous frame's plus one byte time (a stamp from
a late read followed by one from a prompt read) is moved to that bound. So
stamps of one sensor strictly increase, except where the system's realtime
clock itself is stepped back (seen in clock.csv and counted as a clock step).
"""

from __future__ import annotations

import collections
import errno
import logging
import os
import threading
import time

import serial

from . import bp3010, superstar2, ubx
from .framing import FrameFinder
from .recorder import Session

log = logging.getLogger(__name__)

DEVICES = {
    "superstar2": (superstar2.FRAMING, superstar2.HEADER_LEN),
    "bp3010": (bp3010.FRAMING, 1),
    "ublox": (ubx.FRAMING, ubx.HEADER_LEN),
}
BITS_PER_BYTE = 10  # 8N1: start bit, 8 data bits, stop bit
# An open that fails with these means the device went away while opening.
_GONE = (errno.ENOENT, errno.ENODEV, errno.ENXIO)
# A port that fails within this long after opening is flapping: back off.
_FLAP_S = 1.0


class SensorThread(threading.Thread):
    def __init__(self, name: str, device: str, port: str, baud: int, requests: list[bytes], session: Session,
                 raw_capture: bool = False, initial_backoff_s: float = 0.2, max_backoff_s: float = 5.0,
                 poll_interval_s: float = 0.05, unopenable_retry_s: float = 5.0, give_up_after_s: float = 0.0,
                 setup: ubx.Setup | None = None, busy_poll_s: float = 0.1):
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
        self.poll_interval_s = poll_interval_s
        self.unopenable_retry_s = unopenable_retry_s
        self.give_up_after_s = give_up_after_s
        self.busy_poll_s = busy_poll_s
        self.ever_opened = False  # a daemon that never got a device leaves no session behind
        self.counts = session.extra_counts[name]
        self.counts.update(reconnects=0, discarded_bytes=0, checksum_failures=0, lock_losses=0, unfinished_bytes=0,
                           bytes_read=0, stamps_clamped=0)
        self._stop_event = threading.Event()
        self._serial: serial.Serial | None = None
        self._lock = threading.Lock()
        self._state = ""
        self._last_mono: float | None = None  # monotonic stamp of the last frame
        # u-blox: the set-up handshake after every open, and the NMEA sentences skipped.
        self.setup = setup
        self.nmea = ubx.NmeaCounter() if device == "ublox" else None
        if self.nmea is not None:
            self.counts.update(nmea_sentences=0, nmea_bytes=0)

    def stop(self) -> None:
        self._stop_event.set()
        with self._lock:
            if self._serial is not None:
                try:
                    self._serial.cancel_read()  # wakes the blocking read
                except Exception:  # the port may be closing under us
                    pass

    # -- state ------------------------------------------------------------------
    def _set_state(self, state: str, reason: str = "") -> None:
        if state == self._state and reason == self.session.port_state[self.sensor].get("reason", ""):
            return
        self._state = state
        self.session.port_state[self.sensor] = {"state": state, "reason": reason, "since": time.time()}
        if state == "absent":
            log.warning("%s: %s is absent%s; watching for it", self.sensor, self.port_name,
                        f" ({reason})" if reason else "")
        elif state == "unopenable":
            busy = reason.startswith("busy")
            log.error("%s: %s is present but cannot be opened: %s; retrying every %g s%s", self.sensor,
                      self.port_name, reason, self.busy_poll_s if busy else self.unopenable_retry_s,
                      " until it is free" if busy else "")
        elif state == "gave_up":
            log.error("%s: giving up on %s: %s", self.sensor, self.port_name, reason)

    def _path_id(self):
        try:
            st = os.stat(self.port_name)
        except OSError:
            return None
        return (st.st_dev, st.st_ino, st.st_rdev, st.st_mode, st.st_uid, st.st_gid)

    # -- main loop ----------------------------------------------------------------
    def run(self) -> None:
        first = True
        backoff = self.initial_backoff_s
        unopenable_since: float | None = None
        while not self._stop_event.is_set():
            if self._path_id() is None:
                self._set_state("absent", "" if first else "unplugged")
                unopenable_since = None
                self._wait_for_path()
                continue
            try:
                self._open()
            except (serial.SerialException, OSError) as e:
                code = e.errno if isinstance(e.errno, int) else None
                self._close()
                if code in _GONE or self._path_id() is None:
                    self._stop_event.wait(self.poll_interval_s)
                    continue
                now = time.monotonic()
                unopenable_since = unopenable_since or now
                reason = os.strerror(code) if code else str(e)
                busy = code in (errno.EAGAIN, errno.EWOULDBLOCK, errno.EBUSY) or "lock" in str(e).lower()
                if busy:
                    reason = "busy: locked by another program"
                if self.give_up_after_s > 0 and now - unopenable_since >= self.give_up_after_s:
                    self._set_state("gave_up", f"{reason} for {now - unopenable_since:.0f} s")
                    return
                self._set_state("unopenable", reason)
                # Busy: the holder may go at any moment, and only trying to open tells.
                self._wait_for_change(self.busy_poll_s if busy else self.unopenable_retry_s)
                continue
            unopenable_since = None
            self.ever_opened = True
            if not first:
                self.counts["reconnects"] += 1
                log.info("%s: reopened %s", self.sensor, self.port_name)
            first = False
            self._set_state("open")
            opened = time.monotonic()
            try:
                self._read_loop()
            except (serial.SerialException, OSError) as e:
                if self._stop_event.is_set():
                    break
                log.warning("%s: port %s lost (%s)", self.sensor, self.port_name, e)
            finally:
                self._close()
            if self._stop_event.is_set():
                break
            # A port that keeps failing right after opening is backed off; a
            # device that worked for a while is watched for at once.
            if time.monotonic() - opened < _FLAP_S:
                self._stop_event.wait(backoff)
                backoff = min(2 * backoff, self.max_backoff_s)
            else:
                backoff = self.initial_backoff_s
        self._close()

    def _wait_for_path(self) -> None:
        while not self._stop_event.wait(self.poll_interval_s):
            if self._path_id() is not None:
                return

    def _wait_for_change(self, period: float) -> None:
        """Wait out the slow retry period, or less when the device node changes."""
        before = self._path_id()
        end = time.monotonic() + period
        while not self._stop_event.wait(min(self.poll_interval_s * 4, max(0.0, end - time.monotonic()))):
            if time.monotonic() >= end or self._path_id() != before:
                return

    def _open(self) -> None:
        # With a set-up handshake the read wakes now and then to time out unanswered messages.
        s = serial.Serial(self.port_name, self.baud, bytesize=8, parity="N", stopbits=1,
                          timeout=0.1 if self.setup else None, exclusive=True)
        with self._lock:
            self._serial = s
        if self._stop_event.is_set():  # stop() came while opening
            return
        # Bytes that arrived before we listened have no usable stamp.
        s.reset_input_buffer()
        for req in self.requests:
            s.write(req)
        s.flush()
        if self.setup is not None:
            self.setup.start(lambda frame: (s.write(frame), s.flush()))
            self._note_setup()

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
        # (stream offset just past the read's last byte, realtime and monotonic at its return)
        reads: collections.deque[tuple[int, float, float]] = collections.deque(maxlen=64)
        try:
            while s is not None and not self._stop_event.is_set():
                data = s.read(1)  # blocks until a byte arrives, or cancel_read()
                if self.setup is not None and not self.setup.done and self.setup.tick():
                    self._note_setup()
                if not data:
                    continue
                lost = None
                try:
                    waiting = s.in_waiting
                    if waiting:
                        data += s.read(waiting)
                except (serial.SerialException, OSError) as e:
                    lost = e  # unplugged between the two reads: keep what came, then close
                realtime, monotonic = time.time(), time.monotonic()
                self.counts["bytes_read"] += len(data)
                if self.raw_capture:
                    self.session.raw(self.sensor, data, monotonic, realtime)
                reads.append((finder.stats.bytes_in + len(data), realtime, monotonic))
                if self.nmea is not None:
                    self.nmea.feed(data)
                    self.counts.update(nmea_sentences=self.nmea.sentences, nmea_bytes=self.nmea.bytes)
                for frame in finder.feed(data):
                    self.session.record(self.sensor, frame.data, self._stamp(frame.offset, reads))
                    if self.setup is not None and not self.setup.done and self.setup.on_frame(frame.data):
                        self._note_setup()
                if lost is not None:
                    raise lost
        finally:
            # The port closed: a frame the finder was still deciding on is
            # complete and may be intact; only a truncated tail is unfinished.
            for frame in finder.flush():
                self.session.record(self.sensor, frame.data, self._stamp(frame.offset, reads))
            for key in ("discarded_bytes", "checksum_failures", "lock_losses"):
                self.counts[key] += getattr(finder.stats, key)
            self.counts["unfinished_bytes"] += finder.stats.tail_bytes

    def _note_setup(self) -> None:
        """The receiver's version and the configuration's answers, for the sidecar;
        the port state says when the receiver is not configured."""
        self.session.sensors[self.sensor].settings["receiver"] = self.setup.record()
        bad = self.setup.unconfigured()
        if bad:
            self._set_state("unconfigured", bad)
        elif self._state == "unconfigured":
            self._set_state("open")

    def _stamp(self, offset: int, reads) -> float:
        best, offset_real = float("inf"), 0.0
        for end, real, mono in reversed(reads):
            if end <= offset:
                break
            est = mono - (end - offset - 1) * self.byte_time_s
            if est < best:
                best, offset_real = est, real - mono
        if best == float("inf"):  # the reads were forgotten (a frame longer than the deque spans)
            best, offset_real = time.monotonic(), time.time() - time.monotonic()
        if self._last_mono is not None and best < self._last_mono + self.byte_time_s:
            # Two first bytes are at least a byte time apart. (Not a whole frame:
            # an emulator may send faster than the configured line, and a floor
            # of a frame per frame would then drift ahead without bound.)
            best = self._last_mono + self.byte_time_s
            self.counts["stamps_clamped"] += 1
        self._last_mono = best
        return best + offset_real

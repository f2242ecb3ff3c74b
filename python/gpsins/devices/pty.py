"""A pty link as a serial line: bytes paced at the baud rate, drained by the host, with injected faults
(``Faults``) and a record of what was sent (``SentFrame``).
"""

from __future__ import annotations

import errno
import fcntl
import os
import select
import struct
import termios
import time
import tty
from dataclasses import dataclass, field
from pathlib import Path


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


def tight_timers() -> None:
    """This thread's sleeps end on time (Linux: timer slack 1 us instead of 50 us). A device that
    wakes late delays its bytes, which a drive served S times faster shows S times larger."""
    try:
        import ctypes

        ctypes.CDLL(None, use_errno=True).prctl(29, 1000, 0, 0, 0)  # PR_SET_TIMERSLACK, ns
    except (OSError, AttributeError):
        pass

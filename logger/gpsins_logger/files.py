"""A session's files on disk: the append-only record files, the atomically replaced sidecar, and the
disk-health account that turns write failures into counts and log lines instead of exceptions.

Every record is written whole with one write() on a file opened O_APPEND, so a crash can at worst
truncate the last record; a failed write is undone (a short write truncated away), counted, and the
next write tries again, so logging resumes by itself when space returns.
"""

from __future__ import annotations

import errno
import json
import logging
import os
import threading
import time
from dataclasses import dataclass
from pathlib import Path

log = logging.getLogger(__name__)

SIDECAR = "session.json"


@dataclass
class FileCounts:
    frames_written: int = 0
    bytes_written: int = 0
    write_errors: int = 0
    frames_lost_to_disk_errors: int = 0


class DiskHealth:
    """Whether the session's writes are failing, told to the operator once
    when they start failing, every REMINDER_S while they fail, and once when
    they succeed again (with what was lost meanwhile)."""

    REMINDER_S = 30.0
    # Failing ends only after this long without a failure: on a nearly full
    # disk small writes succeed between failures and would make it flap.
    QUIET_S = 1.0

    def __init__(self, directory: Path, lost_counts):
        self.directory = directory
        self._lost_counts = lost_counts  # () -> {sensor: frames lost so far}
        self._lock = threading.Lock()
        self.failing_since: float | None = None
        self.episodes = 0
        self.last_error = ""
        self._lost_at_start: dict[str, int] = {}
        self._last_reminder = 0.0
        self._last_failure = 0.0

    def failed(self, what: Path, err: OSError) -> None:
        now = time.monotonic()
        with self._lock:
            self.last_error = f"{what.name}: {err.strerror or err}"
            self._last_failure = now
            if self.failing_since is None:
                self.failing_since = now
                self._last_reminder = now
                self.episodes += 1
                self._lost_at_start = self._lost_counts()
                log.error("disk writes in %s are failing (%s: %s); frames are counted as lost until "
                          "writing works again", self.directory, what.name, err.strerror or err)
            elif now - self._last_reminder >= self.REMINDER_S:
                self._last_reminder = now
                log.error("disk writes still failing for %.0f s (%s); lost so far: %s", now - self.failing_since,
                          self.last_error, self._lost_text())

    def succeeded(self) -> None:
        if self.failing_since is None:  # the common case, without the lock
            return
        now = time.monotonic()
        with self._lock:
            if self.failing_since is None or now - self._last_failure < self.QUIET_S:
                return
            log.warning("disk writes in %s work again after failing for %.1f s; lost meanwhile: %s",
                        self.directory, self._last_failure - self.failing_since, self._lost_text())
            self.failing_since = None

    def _lost_text(self) -> str:
        now = self._lost_counts()
        return ", ".join(f"{k} {now[k] - self._lost_at_start.get(k, 0)} frames" for k in now)

    def as_dict(self) -> dict:
        return {"state": "failing" if self.failing_since is not None else "ok", "failing_episodes": self.episodes,
                "last_error": self.last_error}


class AppendFile:
    """An O_APPEND file written with one os.write per item. A write that
    fails is counted and undone (a short write is truncated away, so a full
    disk never leaves half a record); the next write simply tries again.
    Opened readable: if the file is deleted under us, what was written since
    it was last seen in place (`verified`) can still be read from its inode."""

    def __init__(self, path: Path, counts: FileCounts, health: DiskHealth | None = None):
        self.path = path
        self.counts = counts
        self.health = health
        self._fd = os.open(path, os.O_RDWR | os.O_CREAT | os.O_APPEND, 0o644)
        st = os.fstat(self._fd)
        self.ident = (st.st_dev, st.st_ino)
        self.size = self.verified = st.st_size  # bytes in the file; of those, seen in place

    def write(self, data: bytes) -> bool:
        try:
            n = os.write(self._fd, data)
            if n != len(data):  # a short write on a regular file means the disk is full
                self._undo(n)
                raise OSError(errno.ENOSPC, f"No space left on device (short write, {n} of {len(data)} bytes)")
        except OSError as e:
            if self.health is not None:  # first: it notes the counts before this loss
                self.health.failed(self.path, e)
            self.counts.write_errors += 1
            self.counts.frames_lost_to_disk_errors += 1
            return False
        self.counts.bytes_written += n
        self.size += n
        if self.health is not None:
            self.health.succeeded()
        return True

    def _undo(self, n: int) -> None:
        try:
            end = os.lseek(self._fd, 0, os.SEEK_END)
            os.ftruncate(self._fd, end - n)
        except OSError:
            pass  # the reader skips a torn record anyway

    def sync(self) -> None:
        try:
            os.fsync(self._fd)
        except OSError as e:
            self.counts.write_errors += 1
            if self.health is not None:
                self.health.failed(self.path, e)

    def close(self) -> None:
        self.sync()
        try:
            os.close(self._fd)
        except OSError:
            pass

    def moved_or_deleted(self) -> str | None:
        """Why self.path no longer names this file, or None."""
        try:
            st = os.stat(self.path)
        except FileNotFoundError:
            return "deleted"
        except OSError:
            return None  # cannot tell: assume it is still there
        return None if (st.st_dev, st.st_ino) == self.ident else "replaced"

    def unlinked_tail(self) -> bytes | None:
        """The bytes written since `verified` if the file has no name left
        anywhere (deleted), else None (it still exists, e.g. moved with its
        directory, and holds them itself)."""
        try:
            if os.fstat(self._fd).st_nlink > 0:
                return None
            out, off = bytearray(), self.verified
            while off < self.size:
                chunk = os.pread(self._fd, self.size - off, off)
                if not chunk:
                    break
                out += chunk
                off += len(chunk)
            return bytes(out)
        except OSError:
            return b""


class SidecarFile:
    """session.json, replaced atomically (write a temporary, fsync, rename it
    over) without needing free space once started: every version is padded
    to a reserved size and the version replaced is kept (hard link) as the
    next temporary, so its blocks are rewritten in place. On a full disk the
    sidecar stays current while the records may not. A write that fails
    leaves the last good sidecar; the next write carries the whole truth."""

    BLOCK = 4096

    def __init__(self, directory: Path):
        self.path = directory / SIDECAR
        self.tmp = directory / (SIDECAR + ".tmp")
        self._old = directory / (SIDECAR + ".old")
        self.reserved = 0  # bytes of each version, padding included

    def write(self, doc: dict) -> None:
        text = json.dumps(doc, indent=2).encode("utf-8")
        if len(text) + 1 > self.reserved:
            compact = json.dumps(doc, separators=(",", ":")).encode("utf-8")
            if self.reserved and len(compact) + 1 <= self.reserved:
                text = compact  # fits the blocks we have: better than growing on a full disk
            else:  # grow, with head room for more parts and longer counts
                need = len(text) + 1
                self.reserved = -(-(need + max(need // 4, 2048)) // self.BLOCK) * self.BLOCK
        data = text + b" " * (self.reserved - len(text) - 1) + b"\n"  # JSON allows trailing blanks
        fd = os.open(self.tmp, os.O_WRONLY | os.O_CREAT, 0o644)  # no O_TRUNC: reuse its blocks
        try:
            view, off = memoryview(data), 0
            while off < len(data):
                n = os.pwrite(fd, view[off:], off)
                if n <= 0:
                    raise OSError(errno.ENOSPC, "No space left on device (short write)", str(self.tmp))
                off += n
            if os.fstat(fd).st_size > len(data):
                os.ftruncate(fd, len(data))
            os.fsync(fd)
        finally:
            os.close(fd)
        kept = False
        try:
            if self._old.exists():
                self._old.unlink()
            os.link(self.path, self._old)
            kept = True
        except OSError:
            pass  # no sidecar yet, or no hard links here (FAT): the next temporary is new
        os.replace(self.tmp, self.path)
        if kept:
            os.replace(self._old, self.tmp)

    def names(self) -> list[Path]:
        return [self.path, self.tmp, self._old]


class DeadFile(AppendFile):
    """A part file that could not be opened: every write counts as lost."""

    def __init__(self, counts: FileCounts, health: DiskHealth, path: Path):
        self.path, self.counts, self.health, self._fd = path, counts, health, -1
        self.ident, self.size, self.verified = None, 0, 0

    def moved_or_deleted(self) -> str | None:
        return None

    def unlinked_tail(self) -> bytes | None:
        return None

    def write(self, data: bytes) -> bool:
        self.health.failed(self.path, OSError(errno.EBADF, "part file not open"))
        self.counts.write_errors += 1
        self.counts.frames_lost_to_disk_errors += 1
        return False

    def sync(self) -> None:
        pass

    def close(self) -> None:
        pass


def file_ident(path: Path) -> tuple[int, int]:
    st = os.stat(path)
    return st.st_dev, st.st_ino

"""The session directory: record files, raw captures, clock pairs, sidecar.

Layout of a session (spec/logfile.md):

    session.json         sidecar: format, clocks, sensors, parts, counts
    clock.csv            periodic (realtime, monotonic) clock pairs
    <sensor>-<part>.bin  records: header | f8 stamp (LE) | rest of the frame
    <sensor>-<part>.raw  optional raw capture: per read, <I length><d monotonic>
                         <d realtime> then the bytes as read from the port

Every record is written whole with one write() on a file opened O_APPEND,
so a crash can at worst truncate the last record; files are fsynced on a
bounded period and at close. Disk errors are counted and reported, never
raised into the caller's read loop: a failed write is undone (a short write
truncated away), counted, and the next write tries again, so logging resumes
by itself when space returns. Only starting a session raises (StartupError),
after removing what it created.
"""

from __future__ import annotations

import errno
import logging
import os
import re
import socket
import struct
import threading
import time
from dataclasses import dataclass, field
from pathlib import Path

from . import __version__
from .files import SIDECAR, AppendFile, DeadFile, DiskHealth, FileCounts, SidecarFile, file_ident

log = logging.getLogger(__name__)

CLOCK_FILE = "clock.csv"
FORMAT_NAME = "gpsins-session"
FORMAT_VERSION = 1
RAW_HEADER = struct.Struct("<Idd")
STAMP = struct.Struct("<d")
# A jump of (realtime - monotonic) beyond this between clock pairs is a step.
CLOCK_STEP_THRESHOLD_S = 0.05

STAMP_MEANING = ("CLOCK_REALTIME seconds (IEEE double, little-endian) at which the frame's first byte "
                 "arrived, estimated as the return time of the read that delivered it minus the bytes "
                 "after it at the line's byte time (10 bits per byte, 8N1); kept strictly increasing per sensor "
                 "on CLOCK_MONOTONIC (an estimate earlier than the previous stamp plus one byte time is moved "
                 "there), so stamps run backwards only where the realtime clock was stepped back (clock.csv)")


def clock_pair() -> dict[str, float]:
    return {"realtime": time.time(), "monotonic": time.monotonic()}


def part_name(sensor: str, part: int, ext: str) -> str:
    return f"{sensor}-{part:03d}.{ext}"


class StartupError(RuntimeError):
    """The session cannot be started (unwritable, read-only or full disk)."""


@dataclass
class SensorInfo:
    """What the sidecar says about one sensor."""

    device: str  # "superstar2", "ublox" or "bp3010"
    header_len: int  # bytes of the device header before the stamp
    raw_capture: bool = False
    settings: dict = field(default_factory=dict)  # port, baud, requests, rate...


class Session:
    def __init__(self, directory: Path, sensors: dict[str, SensorInfo], config: dict | None = None,
                 fsync_interval_s: float = 1.0, raw_reserve_bytes: int = 0):
        self.directory = Path(directory)
        self.sensors = sensors
        self.config = config or {}
        self.fsync_interval_s = fsync_interval_s
        # Below this much free space the raw capture pauses, so the records last longer.
        self.raw_reserve_bytes = raw_reserve_bytes
        self.raw_paused = False
        self.part = 0
        self.counts = {name: FileCounts() for name in sensors}
        self.raw_counts = {name: FileCounts() for name in sensors}
        self.raw_bytes_skipped = {name: 0 for name in sensors}
        self.extra_counts: dict[str, dict[str, int]] = {name: {} for name in sensors}
        # Each sensor thread's port state: open, absent, unopenable (with the reason), gave_up.
        self.port_state: dict[str, dict] = {name: {"state": "starting", "reason": "", "since": None}
                                            for name in sensors}
        self.health = DiskHealth(self.directory, self._lost)
        self.clock_counts = FileCounts()
        self.sidecar_write_errors = 0
        self._sidecar = SidecarFile(self.directory)
        self.clock_steps = 0
        self._locks = {name: threading.Lock() for name in sensors}
        self._records: dict[str, AppendFile] = {}
        self._raws: dict[str, AppendFile] = {}
        self._parts: list[dict] = []
        self.start = clock_pair()
        self.stop: dict[str, float] | None = None
        self._last_offset: float | None = None
        # A session whose directory went away goes on in a continuation (continue_elsewhere).
        self.continues: dict | None = None  # what this directory continues, for the sidecar
        self._seen = clock_pair()  # when the directory and files were last seen in place
        self._seen_frames = {name: 0 for name in sensors}  # frames_written then
        self._continue_failed = False
        self._closed = False
        created = _make_dirs(self.directory)
        self._dir_id = file_ident(self.directory)
        try:
            self._clock = AppendFile(self.directory / CLOCK_FILE, self.clock_counts)
            self._must(self._clock.write(b"realtime,monotonic\n"), CLOCK_FILE)
            self._must(self.clock_pair(), CLOCK_FILE)
            # The sidecar lists a part before its files exist: a crash at any moment
            # leaves no record file the sidecar does not name.
            self._parts.append({"index": self.part, "start": clock_pair()})
            self.write_sidecar(strict=True)
            self.write_sidecar(strict=True)  # the second version reserves the next temporary's blocks
            self._open_part()
            self.sync()
            self._must(self.clock_counts.write_errors == 0, CLOCK_FILE)
        except OSError as e:
            self._abandon(created)
            raise StartupError(f"cannot write the session in {self.directory}: "
                               f"{e.strerror or e}{' (' + e.filename + ')' if e.filename else ''}") from None
        self._clock.health = self.health

    def _must(self, ok: bool, what: str) -> None:
        if not ok:
            raise OSError(errno.ENOSPC, "No space left on device", str(self.directory / what))

    def _abandon(self, created: list[Path]) -> None:
        """Undo a failed start: close and remove what this session created."""
        for f in (getattr(self, "_clock", None), *self._records.values(), *self._raws.values()):
            if f is not None:
                try:
                    os.close(f._fd)
                except OSError:
                    pass
        for p in sorted(self.directory.glob("*")):
            try:
                p.unlink()
            except OSError:
                pass
        for d in reversed(created):
            try:
                d.rmdir()
            except OSError:
                pass

    def _lost(self) -> dict[str, int]:
        return {name: c.frames_lost_to_disk_errors for name, c in self.counts.items()}

    def _open_part(self) -> None:
        """Open the files of part self.part (already listed in the sidecar)."""
        self._records, self._raws = self._part_files(self.directory)

    def _part_files(self, directory: Path) -> tuple[dict, dict]:
        records, raws = {}, {}
        try:
            for name, info in self.sensors.items():
                records[name] = AppendFile(directory / part_name(name, self.part, "bin"), self.counts[name],
                                            self.health)
                if info.raw_capture:
                    raws[name] = AppendFile(directory / part_name(name, self.part, "raw"), self.raw_counts[name],
                                             self.health)
        except OSError:
            for f in (*records.values(), *raws.values()):
                os.close(f._fd)
            raise
        return records, raws

    def record(self, sensor: str, frame: bytes, stamp: float) -> bool:
        h = self.sensors[sensor].header_len
        rec = frame[:h] + STAMP.pack(stamp) + frame[h:]
        with self._locks[sensor]:
            ok = self._records[sensor].write(rec)
            if ok:  # under the lock: a continuation counts what it carries over
                self.counts[sensor].frames_written += 1
        return ok

    def raw(self, sensor: str, data: bytes, monotonic: float, realtime: float) -> None:
        with self._locks[sensor]:
            f = self._raws.get(sensor)
            if f is None:
                return
            if self.raw_paused:
                self.raw_bytes_skipped[sensor] += len(data)
                return
            f.write(RAW_HEADER.pack(len(data), monotonic, realtime) + data)

    def check_free_space(self) -> None:
        """Pause the raw capture while free space is below the reserve."""
        if not self.raw_reserve_bytes:
            return
        try:
            st = os.statvfs(self.directory)
        except OSError:
            return
        free = st.f_bavail * st.f_frsize
        paused = free < self.raw_reserve_bytes
        if paused != self.raw_paused:
            self.raw_paused = paused
            if paused:
                log.warning("free space %.1f MB is below the reserve of %.1f MB: raw capture paused, records go on",
                            free / 1e6, self.raw_reserve_bytes / 1e6)
            else:
                log.info("free space %.1f MB is above the reserve again: raw capture resumed", free / 1e6)

    def clock_pair(self) -> bool:
        pair = clock_pair()
        offset = pair["realtime"] - pair["monotonic"]
        if self._last_offset is not None and abs(offset - self._last_offset) > CLOCK_STEP_THRESHOLD_S:
            self.clock_steps += 1
            log.warning("realtime clock stepped by %+.3f s", offset - self._last_offset)
        self._last_offset = offset
        return self._clock.write(f"{pair['realtime']:.6f},{pair['monotonic']:.6f}\n".encode("ascii"))

    def sync(self) -> None:
        for name in self.sensors:
            with self._locks[name]:
                for files in (self._records, self._raws):
                    if name in files:
                        files[name].sync()
        self._clock.sync()

    def rotate(self) -> None:
        """Close this part's files and start the next part (SIGHUP). The new
        part is in the sidecar on disk before its files are created (a crash
        between the two leaves a listed part without files, which readers
        skip); if that sidecar cannot be written the old part goes on. All
        sensor locks are held while the files change, so no record lands on a
        closed file; the sidecar's fsync is done before, not under them."""
        self.check_directory()  # a directory gone meanwhile is continued first
        nxt = self.part + 1
        entry = {"index": nxt, "start": clock_pair()}
        self._parts.append(entry)
        if not self.write_sidecar() or entry not in self._parts:  # (not listed if continued just now)
            if entry in self._parts:
                self._parts.remove(entry)
            log.error("cannot write the sidecar listing part %d in %s; staying on part %d", nxt, self.directory,
                      self.part)
            return
        for name in self.sensors:
            self._locks[name].acquire()
        try:
            for files in (self._records, self._raws):
                for f in files.values():
                    f.close()
            self._raws.clear()
            self.part = nxt
            try:
                self._open_part()
            except OSError as e:  # the new part cannot be created: keep writing the old one
                log.error("cannot start part %d in %s (%s); staying on part %d", self.part, self.directory,
                          e.strerror or e, self.part - 1)
                self._parts.pop()
                self.part -= 1
                self._reopen_part()
        finally:
            for name in self.sensors:
                self._locks[name].release()
        self.write_sidecar()
        log.info("rotated to part %d", self.part)

    def _reopen_part(self) -> None:
        for name, info in self.sensors.items():
            for files, ext, counts in ((self._records, "bin", self.counts), (self._raws, "raw", self.raw_counts)):
                if ext == "raw" and not info.raw_capture:
                    continue
                try:
                    files[name] = AppendFile(self.directory / part_name(name, self.part, ext), counts[name],
                                              self.health)
                except OSError as e:
                    log.error("cannot reopen %s: %s", part_name(name, self.part, ext), e.strerror or e)
                    files[name] = DeadFile(counts[name], self.health, self.directory / part_name(name, self.part, ext))

    # -- the directory going away -------------------------------------------------------
    def _files(self) -> list["AppendFile"]:
        return [self._clock, *self._records.values(), *self._raws.values()]

    def _gone(self) -> str | None:
        """Why the session directory or one of its open files is no longer
        where it was opened (compared by st_dev/st_ino), or None."""
        try:
            if file_ident(self.directory) != self._dir_id:
                return "was replaced (another directory now has its name)"
        except FileNotFoundError:
            return "was deleted"
        except OSError:
            return None  # cannot tell: keep going
        for f in self._files():
            why = f.moved_or_deleted()
            if why:
                return f"lost its file {f.path.name} ({why})"
        return None

    def check_directory(self) -> bool:
        """True when the directory and the open files are in place (then what
        was written so far counts as seen there). Otherwise the session goes
        on in a continuation directory; False if that could not be made."""
        why = self._gone()
        if why is None:
            seen = clock_pair()
            for name in self.sensors:
                with self._locks[name]:
                    for files in (self._records, self._raws):
                        if name in files:
                            files[name].verified = files[name].size
                    self._seen_frames[name] = self.counts[name].frames_written
            self._clock.verified = self._clock.size
            self._seen = seen
            self._continue_failed = False
            return True
        if self._closed:
            return False
        return self.continue_elsewhere(why)

    def continue_elsewhere(self, why: str) -> bool:
        """Go on in <directory>-cont<k>: the records written since the old
        directory was last seen are carried over from the deleted files'
        inodes (we still hold them open), then new records follow. If the
        old files still exist somewhere (the directory was moved), they keep
        their records and nothing is carried over."""
        old_dir = self.directory
        new_dir = continuation_dir(old_dir)
        try:
            created = _make_dirs(new_dir)
        except (StartupError, FileExistsError) as e:
            return self._cannot_continue(old_dir, why, new_dir, e)
        for name in self.sensors:
            self._locks[name].acquire()
        saved = (self._parts, self.continues)
        old_doc = self.sidecar()
        opened: list[AppendFile] = []
        failed: OSError | None = None
        try:
            carried, before, tails = {}, {}, []
            for name in self.sensors:
                for kind, files in (("bin", self._records), ("raw", self._raws)):
                    if name in files:
                        tail = files[name].unlinked_tail()
                        tails.append((kind, name, tail))
                        if kind == "bin":
                            n = self.counts[name].frames_written - self._seen_frames[name] if tail is not None else 0
                            carried[name] = n
                before[name] = self.counts[name].frames_written - carried.get(name, 0)
            self._parts = [{"index": self.part, "start": self._seen}]
            self.continues = {
                "previous": old_dir.name, "reason": f"the session directory {why}",
                "noticed": clock_pair(), "previous_last_seen": self._seen,
                # Frames in `counts` that are not in this directory (in the previous ones).
                "frames_before": before,
                "frames_carried_over": carried,
                "carried_over": "the records written since the previous directory was last seen, read from its "
                                "deleted files" if any(t is not None for _, _, t in tails) else
                                "nothing: the previous files still exist (moved), their records are there",
            }
            side = SidecarFile(new_dir)
            side.write(self.sidecar())  # lists the part before its files exist
            side.write(self.sidecar())
            clock = AppendFile(new_dir / CLOCK_FILE, self.clock_counts)
            opened.append(clock)
            head = (f"realtime,monotonic\n{self._seen['realtime']:.6f},{self._seen['monotonic']:.6f}\n")
            if not clock.write(head.encode("ascii")):
                raise OSError(errno.ENOSPC, "cannot write", str(clock.path))
            records, raws = self._part_files(new_dir)
            opened += [*records.values(), *raws.values()]
            for kind, name, tail in tails:
                f = (records if kind == "bin" else raws)[name]
                if tail and os.write(f._fd, tail) != len(tail):
                    raise OSError(errno.ENOSPC, "short write", str(f.path))
                f.size = f.verified = f.size + len(tail or b"")
        except OSError as e:  # undo: the old files go on, retried at the next check
            failed = e
            self._parts, self.continues = saved
            for f in opened:
                os.close(f._fd)
            for p in new_dir.glob("*"):
                p.unlink(missing_ok=True)
            for d in reversed(created):
                try:
                    d.rmdir()
                except OSError:
                    pass
        else:
            old_files = self._files()
            old_side = self._sidecar
            self._records, self._raws, self._clock = records, raws, clock
            self._clock.health = self.health
            self.directory, self._dir_id, self._sidecar = new_dir, file_ident(new_dir), side
            self.health.directory = new_dir
            self._seen = self.continues["noticed"]
            self._seen_frames = {name: self.counts[name].frames_written for name in self.sensors}
            self._continue_failed = False
        finally:
            for name in self.sensors:
                self._locks[name].release()
        if failed is not None:
            return self._cannot_continue(old_dir, why, new_dir, failed)
        for f in old_files:
            f.close()
        if not why.startswith(("was deleted", "was replaced")):  # the old directory is still ours: say where we went
            try:
                old_side.write({**old_doc, "state": "continued", "continued_in": new_dir.name})
            except OSError:
                pass
        total = sum(carried.values())
        log.error("session directory %s %s; continuing in %s%s", old_dir, why, new_dir,
                  f" with the {total} records written since it was last seen ("
                  + ", ".join(f"{k} {v}" for k, v in carried.items()) + ")"
                  if any(t is not None for _, _, t in tails) else " (the files so far still exist elsewhere)")
        return True

    def _cannot_continue(self, old_dir: Path, why: str, new_dir: Path, e: Exception) -> bool:
        if not self._continue_failed:
            self._continue_failed = True
            log.error("session directory %s %s, and the continuation %s cannot be written (%s); records go on "
                      "into the lost files, retrying", old_dir, why, new_dir, getattr(e, "strerror", None) or e)
        return False

    def sidecar(self) -> dict:
        sensors = {}
        for name, info in self.sensors.items():
            parts = [part_name(name, p["index"], "bin") for p in self._parts]
            raw = [part_name(name, p["index"], "raw") for p in self._parts] if info.raw_capture else []
            sensors[name] = {"device": info.device, "header_len": info.header_len, **info.settings,
                             "files": parts, "raw_files": raw, "port_state": dict(self.port_state[name])}
        counts = {}
        for name in self.sensors:
            c = dict(self.counts[name].__dict__)
            c["raw_write_errors"] = self.raw_counts[name].write_errors
            c["raw_bytes_skipped_for_reserve"] = self.raw_bytes_skipped[name]
            c.update(self.extra_counts[name])
            counts[name] = c
        return {
            "format": FORMAT_NAME,
            "format_version": FORMAT_VERSION,
            "software": {"name": "gpsins-logger", "version": __version__},
            "host": socket.gethostname(),
            "state": "stopped" if self.stop else "running",
            "start": self.start,
            "stop": self.stop,
            # When this version was written (readers compare it with the records' stamps).
            "written": clock_pair(),
            "stamp": STAMP_MEANING,
            "record_layout": "header | f8 stamp little-endian | rest of the device frame",
            "raw_layout": "per read: <I length><d monotonic><d realtime> then the bytes",
            "sensors": sensors,
            "parts": self._parts,
            "counts": counts,
            "continues": self.continues,
            "clock_steps": self.clock_steps,
            "disk": {**self.health.as_dict(), "clock_write_errors": self.clock_counts.write_errors,
                     "sidecar_write_errors": self.sidecar_write_errors, "raw_paused_for_reserve": self.raw_paused},
            "config": self.config,
        }

    def write_sidecar(self, strict: bool = False) -> bool:
        """Write-then-rename (SidecarFile): a crash leaves the old or the new
        sidecar, never half of one. A failure is counted (raised only when
        strict) and the last good version stays; the next call retries.
        First the directory is checked (check_directory)."""
        if not strict and not self.check_directory():
            self.sidecar_write_errors += 1  # gone, and no continuation yet: nowhere to write it
            return False
        try:
            self._sidecar.write(self.sidecar())
        except OSError as e:
            if strict:
                raise
            self.sidecar_write_errors += 1
            if self._gone() is not None:  # deleted while we wrote (rm -rf under way): not a disk fault
                self.check_directory()
                return False
            self.health.failed(Path(SIDECAR), e)
            return False
        return True

    def close(self) -> None:
        self.check_directory()  # a directory gone meanwhile: the last records go to the continuation
        self._closed = True
        self.clock_pair()
        for name in self.sensors:
            with self._locks[name]:
                self._records[name].close()
                if name in self._raws:
                    self._raws[name].close()
        self._clock.close()
        self.stop = clock_pair()
        self.write_sidecar()


    def remove_if_empty(self) -> bool:
        """Remove a closed session that holds no record: its own files, then
        its directory (kept if anything else is in it)."""
        if any(c.bytes_written for c in (*self.counts.values(), *self.raw_counts.values())):
            return False
        names = {CLOCK_FILE, *(p.name for p in self._sidecar.names())}
        for name, info in self.sensors.items():
            for p in self._parts:
                names.add(part_name(name, p["index"], "bin"))
                if info.raw_capture:
                    names.add(part_name(name, p["index"], "raw"))
        for n in names:
            try:
                (self.directory / n).unlink()
            except FileNotFoundError:
                pass
            except OSError:
                return False
        try:
            self.directory.rmdir()
        except OSError:
            return False
        return True


def _make_dirs(directory: Path) -> list[Path]:
    """mkdir -p that returns what it created (outermost first); the session
    directory itself must be new."""
    missing = []
    p = directory
    while not p.exists():
        missing.append(p)
        if p.parent == p:
            break
        p = p.parent
    if not missing:
        raise FileExistsError(errno.EEXIST, "File exists", str(directory))
    created = []
    try:
        for d in reversed(missing):
            d.mkdir()
            created.append(d)
    except OSError as e:
        for d in reversed(created):
            try:
                d.rmdir()
            except OSError:
                pass
        raise StartupError(f"cannot create the session directory {directory}: {e.strerror or e}"
                           f"{' (' + e.filename + ')' if e.filename else ''}") from None
    return created


def continuation_dir(directory: Path) -> Path:
    """The first free <name>-cont<k> beside directory (<name> without an earlier -cont<k>)."""
    m = re.fullmatch(r"(.+)-cont(\d+)", directory.name)
    stem, k = (m.group(1), int(m.group(2)) + 1) if m else (directory.name, 1)
    while (directory.parent / f"{stem}-cont{k}").exists():
        k += 1
    return directory.parent / f"{stem}-cont{k}"


def new_session_dir(root: Path) -> Path:
    """A fresh directory below root named by the UTC start time."""
    stem = time.strftime("%Y%m%dT%H%M%SZ", time.gmtime())
    path = Path(root) / stem
    k = 1
    while path.exists():
        path = Path(root) / f"{stem}-{k}"
        k += 1
    return path

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
raised into the caller's read loop.
"""

from __future__ import annotations

import errno
import json
import logging
import os
import socket
import struct
import threading
import time
from dataclasses import dataclass, field
from pathlib import Path

from . import __version__

log = logging.getLogger(__name__)

SIDECAR = "session.json"
CLOCK_FILE = "clock.csv"
FORMAT_NAME = "gpsins-session"
FORMAT_VERSION = 1
RAW_HEADER = struct.Struct("<Idd")
STAMP = struct.Struct("<d")
# A jump of (realtime - monotonic) beyond this between clock pairs is a step.
CLOCK_STEP_THRESHOLD_S = 0.05

STAMP_MEANING = ("CLOCK_REALTIME seconds (IEEE double, little-endian) at which the frame's first byte "
                 "arrived, estimated as the return time of the read that delivered it minus the bytes "
                 "after it at the line's byte time (10 bits per byte, 8N1)")


def clock_pair() -> dict[str, float]:
    return {"realtime": time.time(), "monotonic": time.monotonic()}


def part_name(sensor: str, part: int, ext: str) -> str:
    return f"{sensor}-{part:03d}.{ext}"


@dataclass
class FileCounts:
    frames_written: int = 0
    bytes_written: int = 0
    write_errors: int = 0
    frames_lost_to_disk_errors: int = 0


class _AppendFile:
    """An O_APPEND file written with one os.write per item."""

    def __init__(self, path: Path, counts: FileCounts):
        self.path = path
        self.counts = counts
        self._fd = os.open(path, os.O_WRONLY | os.O_CREAT | os.O_APPEND, 0o644)
        self._last_error_log = 0.0

    def write(self, data: bytes) -> bool:
        try:
            n = os.write(self._fd, data)
            if n != len(data):  # a short write on a regular file means the disk is full
                raise OSError(errno.ENOSPC, f"short write ({n} of {len(data)} bytes)")
        except OSError as e:
            self.counts.write_errors += 1
            self.counts.frames_lost_to_disk_errors += 1
            now = time.monotonic()
            if now - self._last_error_log > 10.0:  # one line per 10 s, the count says the rest
                log.error("write to %s failed: %s (%d errors so far)", self.path, e, self.counts.write_errors)
                self._last_error_log = now
            return False
        self.counts.bytes_written += n
        return True

    def sync(self) -> None:
        try:
            os.fsync(self._fd)
        except OSError as e:
            self.counts.write_errors += 1
            log.error("fsync of %s failed: %s", self.path, e)

    def close(self) -> None:
        self.sync()
        os.close(self._fd)


@dataclass
class SensorInfo:
    """What the sidecar says about one sensor."""

    device: str  # "superstar2" or "bp3010"
    header_len: int  # bytes of the device header before the stamp
    raw_capture: bool = False
    settings: dict = field(default_factory=dict)  # port, baud, requests, rate...


class Session:
    def __init__(self, directory: Path, sensors: dict[str, SensorInfo], config: dict | None = None,
                 fsync_interval_s: float = 1.0):
        self.directory = Path(directory)
        self.directory.mkdir(parents=True, exist_ok=False)
        self.sensors = sensors
        self.config = config or {}
        self.fsync_interval_s = fsync_interval_s
        self.part = 0
        self.counts = {name: FileCounts() for name in sensors}
        self.raw_counts = {name: FileCounts() for name in sensors}
        self.extra_counts: dict[str, dict[str, int]] = {name: {} for name in sensors}
        self.clock_steps = 0
        self._locks = {name: threading.Lock() for name in sensors}
        self._records: dict[str, _AppendFile] = {}
        self._raws: dict[str, _AppendFile] = {}
        self._parts: list[dict] = []
        self.start = clock_pair()
        self.stop: dict[str, float] | None = None
        self._last_offset: float | None = None
        self._clock = open(self.directory / CLOCK_FILE, "a", encoding="ascii")
        self._clock.write("realtime,monotonic\n")
        self._open_part()
        self.clock_pair()
        self.write_sidecar()

    def _open_part(self) -> None:
        self._parts.append({"index": self.part, "start": clock_pair()})
        for name, info in self.sensors.items():
            self._records[name] = _AppendFile(self.directory / part_name(name, self.part, "bin"), self.counts[name])
            if info.raw_capture:
                self._raws[name] = _AppendFile(self.directory / part_name(name, self.part, "raw"),
                                               self.raw_counts[name])

    def record(self, sensor: str, frame: bytes, stamp: float) -> bool:
        h = self.sensors[sensor].header_len
        rec = frame[:h] + STAMP.pack(stamp) + frame[h:]
        with self._locks[sensor]:
            ok = self._records[sensor].write(rec)
        if ok:
            self.counts[sensor].frames_written += 1
        return ok

    def raw(self, sensor: str, data: bytes, monotonic: float, realtime: float) -> None:
        with self._locks[sensor]:
            f = self._raws.get(sensor)
            if f is not None:
                f.write(RAW_HEADER.pack(len(data), monotonic, realtime) + data)

    def clock_pair(self) -> None:
        pair = clock_pair()
        offset = pair["realtime"] - pair["monotonic"]
        if self._last_offset is not None and abs(offset - self._last_offset) > CLOCK_STEP_THRESHOLD_S:
            self.clock_steps += 1
            log.warning("realtime clock stepped by %+.3f s", offset - self._last_offset)
        self._last_offset = offset
        self._clock.write(f"{pair['realtime']:.6f},{pair['monotonic']:.6f}\n")
        self._clock.flush()

    def sync(self) -> None:
        for name in self.sensors:
            with self._locks[name]:
                for files in (self._records, self._raws):
                    if name in files:
                        files[name].sync()
        os.fsync(self._clock.fileno())

    def rotate(self) -> None:
        """Close this part's files and start the next part (SIGHUP). All
        sensor locks are held throughout, so no record lands on a closed file."""
        for name in self.sensors:
            self._locks[name].acquire()
        try:
            for files in (self._records, self._raws):
                for f in files.values():
                    f.close()
            self._raws.clear()
            self.part += 1
            self._open_part()
        finally:
            for name in self.sensors:
                self._locks[name].release()
        self.write_sidecar()
        log.info("rotated to part %d", self.part)

    def sidecar(self) -> dict:
        sensors = {}
        for name, info in self.sensors.items():
            parts = [part_name(name, p["index"], "bin") for p in self._parts]
            raw = [part_name(name, p["index"], "raw") for p in self._parts] if info.raw_capture else []
            sensors[name] = {"device": info.device, "header_len": info.header_len, **info.settings,
                             "files": parts, "raw_files": raw}
        counts = {}
        for name in self.sensors:
            c = dict(self.counts[name].__dict__)
            c["raw_write_errors"] = self.raw_counts[name].write_errors
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
            "stamp": STAMP_MEANING,
            "record_layout": "header | f8 stamp little-endian | rest of the device frame",
            "raw_layout": "per read: <I length><d monotonic><d realtime> then the bytes",
            "sensors": sensors,
            "parts": self._parts,
            "counts": counts,
            "clock_steps": self.clock_steps,
            "config": self.config,
        }

    def write_sidecar(self) -> None:
        # Write-then-rename: a crash leaves the old or the new sidecar, never half of one.
        tmp = self.directory / (SIDECAR + ".tmp")
        with open(tmp, "w", encoding="utf-8") as f:
            json.dump(self.sidecar(), f, indent=2)
            f.write("\n")
            f.flush()
            os.fsync(f.fileno())
        os.replace(tmp, self.directory / SIDECAR)

    def close(self) -> None:
        self.clock_pair()
        for name in self.sensors:
            with self._locks[name]:
                self._records[name].close()
                if name in self._raws:
                    self._raws[name].close()
        self._clock.close()
        self.stop = clock_pair()
        self.write_sidecar()


def new_session_dir(root: Path) -> Path:
    """A fresh directory below root named by the UTC start time."""
    stem = time.strftime("%Y%m%dT%H%M%SZ", time.gmtime())
    path = Path(root) / stem
    k = 1
    while path.exists():
        path = Path(root) / f"{stem}-{k}"
        k += 1
    return path

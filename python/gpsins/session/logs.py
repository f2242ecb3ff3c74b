"""Fast NumPy readers of logger sessions and raw device captures.

A record file is a sequence of ``header | f8 stamp | rest`` records
(spec/logfile.md). The scanner is vectorised: it finds every candidate
record (sync, header test, device checksum, plausible stamp) in one pass,
then follows the chain of records from the start, resynchronising at the
next valid candidate after damage, exactly as the logger's streaming finder
does on a byte stream. Python loops only over damaged places, never over
records. A truncated last record is accepted as the file's tail and reported.
Files are read in blocks (:func:`scan_stream`, :func:`read_record_file`) with
the same result as the whole-buffer :func:`scan`, and kept as compact columns
(offsets, lengths, stamps, frame bytes; or a BP3010's decoded increments), so
memory grows with what is kept, not with the file's bytes plus index arrays.
Layouts: Superstar II (header SOH, ID, ~ID, N), BP3010 (sync byte) and u-blox
(header B5 62, class, id, length U2; the Fletcher checksum over class..length
and the payload, the stamp between them left out).
Stamps are checked against the session (see :func:`reject_bad_stamps`).
Damaged input of any kind reads as records plus counted damage; only a file
that cannot be read at all raises :class:`LogError`.
"""

from __future__ import annotations

import json
from dataclasses import dataclass
from pathlib import Path
from typing import Iterator

import numpy as np

from gpsins_logger import bp3010
from gpsins_logger.recorder import RAW_HEADER
from .stream import BLOCK_BYTES, FrameColumns, ImuColumns, decode_bp3010, file_size, stream_blocks
from .layouts import ImuLog, LAYOUTS, LogError, Scan, bp3010_lsb
from .stamps import StampLimits, first_backwards, reject_bad_stamps, stamp_limits


def read_record_file(path: str | Path, device: str, limits: StampLimits | None = None,
                     block_bytes: int = BLOCK_BYTES, imu_rate_hz: int | None = None) -> Scan:
    """A record file read in blocks (see :func:`scan_stream`), impossible stamps
    dropped. With imu_rate_hz (BP3010 files), the records are decoded as they
    are read into the Scan's `imu` and their frames are not kept."""
    path = Path(path)
    if device not in LAYOUTS:
        raise LogError(f"{path}: unknown device {device!r} (known: {', '.join(LAYOUTS)})")
    lay = LAYOUTS[device]
    if imu_rate_hz is not None and device != "bp3010":
        raise LogError(f"{path}: only BP3010 records decode as IMU samples, not {device!r}")
    limits = limits or StampLimits()
    try:
        with open(path, "rb", buffering=0) as f:
            size = file_size(f)
            columns = FrameColumns(lay, size) if imu_rate_hz is None else ImuColumns(lay, size, imu_rate_hz)
            out = columns.scan(str(path), stream_blocks(f, lay, limits, columns, block_bytes))
    except OSError as e:
        raise LogError(f"{path}: cannot read: {e.strerror}") from None
    out = reject_bad_stamps(out, limits)
    count, first = first_backwards(out.stamps)
    out.stats["stamps_backwards"] = count
    out.stats["first_backwards_offset"] = int(out.starts[first]) if first is not None else None
    return out


IMU_DECODE_ROWS = 1 << 20  # frames decoded at a time from a Scan's frame bytes


def imu_log(s: Scan, rate_hz: int = bp3010.NOMINAL_RATE_HZ) -> ImuLog:
    """The BP3010 records of s as increments (s.imu itself when s was read decoded)."""
    if s.imu is not None:
        if s.imu.rate_hz != rate_hz:
            raise LogError(f"{s.path}: decoded at {s.imu.rate_hz} Hz, asked for {rate_hz} Hz")
        return s.imu
    frames = s._require_frames().reshape(-1, bp3010.FRAME_LEN)
    n = len(frames)
    out = ImuLog(s.stamps, np.empty((n, 3), np.int16), np.empty((n, 3), np.int16), np.empty(n, np.uint8),
                 np.empty(n, np.uint8), rate_hz, bp3010_lsb(rate_hz))
    for a in range(0, n, IMU_DECODE_ROWS):
        r = slice(a, a + IMU_DECODE_ROWS)
        decode_bp3010(frames[r, 1:15], out.dtheta[r], out.dv[r], out.status[r], out.counter[r])
    return out


@dataclass
class SensorFiles:
    name: str
    device: str
    scans: list[Scan]

    @property
    def count(self) -> int:
        return sum(s.count for s in self.scans)

    @property
    def stamps(self) -> np.ndarray:
        return np.concatenate([s.stamps for s in self.scans]) if self.scans else np.zeros(0)

    def frames(self) -> list[bytes]:
        return [f for s in self.scans for f in s.frames()]

    def iter_frames(self) -> Iterator[tuple[bytes, float]]:
        """(frame, stamp) of every record of every file, in order."""
        for s in self.scans:
            yield from s.iter_frames()

    def stats(self) -> dict:
        keys = ("records", "bytes", "discarded_bytes", "truncated_tail_bytes", "resyncs", "bad_stamps",
                "stamps_backwards")
        return {k: sum(s.stats[k] for s in self.scans) for k in keys}


@dataclass
class SessionLog:
    directory: Path
    sidecar: dict
    sensors: dict[str, SensorFiles]

    @property
    def imu_rate_hz(self) -> int:
        return int(self.sidecar["sensors"]["imu"].get("rate_hz", bp3010.NOMINAL_RATE_HZ))

    def imu(self) -> ImuLog:
        files = self.sensors["imu"]
        rate = self.imu_rate_hz
        parts = [imu_log(s, rate) for s in files.scans]
        if len(parts) == 1:
            return parts[0]
        if not parts:
            return ImuLog(np.zeros(0), np.zeros((0, 3), np.int16), np.zeros((0, 3), np.int16), np.zeros(0, np.uint8),
                          np.zeros(0, np.uint8), rate, bp3010_lsb(rate))
        return ImuLog(*(np.concatenate([getattr(p, f) for p in parts]) for f in
                        ("stamps", "dtheta", "dv", "status", "counter")), rate, bp3010_lsb(rate))


def read_session(directory: str | Path, imu_frames: bool = True) -> SessionLog:
    """A session's record files. imu_frames=False decodes the BP3010 IMU as it
    is read and keeps no frames of it (replay: the samples are all it needs)."""
    directory = Path(directory)
    side = directory / "session.json"
    try:
        sidecar = json.loads(side.read_text(encoding="utf-8"))
    except FileNotFoundError:
        raise LogError(f"{side}: missing; not a gpsins session directory") from None
    except json.JSONDecodeError as e:
        raise LogError(f"{side}: not valid JSON ({e})") from None
    if not isinstance(sidecar, dict) or not isinstance(sidecar.get("sensors", {}), dict):
        raise LogError(f"{side}: not a gpsins sidecar (no sensors table)")
    limits = stamp_limits(directory, sidecar)
    sensors = {}
    for name, info in sidecar.get("sensors", {}).items():
        decode = None
        if not imu_frames and name == "imu" and info["device"] == "bp3010":
            decode = int(info.get("rate_hz", bp3010.NOMINAL_RATE_HZ))
        scans = []
        for fname in info.get("files", []):
            path = directory / fname
            if path.exists():
                scans.append(read_record_file(path, info["device"], limits, imu_rate_hz=decode))
        sensors[name] = SensorFiles(name, info["device"], scans)
    return SessionLog(directory, sidecar, sensors)


def read_raw_capture(path: str | Path) -> list[tuple[float, float, bytes]]:
    """A logger raw capture (.raw): per read (monotonic, realtime, bytes); a truncated last read is dropped."""
    data = Path(path).read_bytes()
    out, i = [], 0
    head = RAW_HEADER.size
    while i + head <= len(data):
        n, mono, real = RAW_HEADER.unpack_from(data, i)
        if i + head + n > len(data):
            break
        out.append((mono, real, data[i + head:i + head + n]))
        i += head + n
    return out

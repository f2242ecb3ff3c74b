"""Record layouts of the logger's files and raw device captures, and ``Scan``, the records a scan found.

A record file is a sequence of ``header | f8 stamp | rest`` records (spec/logfile.md). Layouts: Superstar II
(header SOH, ID, ~ID, N), BP3010 (sync byte) and u-blox (header B5 62, class, id, length U2; the Fletcher
checksum over class..length and the payload, the stamp between them left out). A BP3010 file's
records decode to an ``ImuLog``.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Iterator

import numpy as np

from gpsins_logger import bp3010
from gpsins_logger import superstar2 as ss2
from gpsins_logger import ubx


STAMP_BYTES = 8
# A stamp outside (1970, 2286) cannot be system time: the candidate is not a record.
STAMP_MIN, STAMP_MAX = 0.0, 1e10
# Stamps may lie this far outside the session's recorded span (start/stop, clock pairs).
SPAN_MARGIN_S = 2.0


class LogError(ValueError):
    """A file that cannot be read as a session file; names the file."""


@dataclass(frozen=True)
class Layout:
    device: str
    sync: int
    header_len: int
    stamped: bool  # record file (stamp after the header) or raw device stream

    @property
    def stamp_len(self) -> int:
        return STAMP_BYTES if self.stamped else 0

    @property
    def fixed_len(self) -> int | None:
        """The one record length of a layout that has one (BP3010), else None."""
        return bp3010.FRAME_LEN + self.stamp_len if self.device == "bp3010" else None

    @property
    def min_len(self) -> int:
        """The shortest record (or frame) this layout can hold."""
        frame = {"superstar2": 6, "bp3010": bp3010.FRAME_LEN, "ublox": 8}[self.device]
        return frame + self.stamp_len


SS2_RECORDS = Layout("superstar2", ss2.SOH, ss2.HEADER_LEN, True)
BP_RECORDS = Layout("bp3010", bp3010.SYNC, 1, True)
SS2_RAW = Layout("superstar2", ss2.SOH, ss2.HEADER_LEN, False)
# u-blox: header = sync B5 62, class, id, length (U2); rest = payload and CK_A CK_B. Record length = length + 16.
UBX_RECORDS = Layout("ublox", ubx.SYNC1, ubx.HEADER_LEN, True)
UBX_RAW = Layout("ublox", ubx.SYNC1, ubx.HEADER_LEN, False)
LAYOUTS = {"superstar2": SS2_RECORDS, "bp3010": BP_RECORDS, "ublox": UBX_RECORDS}


def cut_header(buf: np.ndarray, layout: Layout, start: int, size: int) -> int | None:
    """The first sync byte at or after start whose header the end of the data cuts: the streaming
    finder keeps such bytes as the truncated tail (it cannot tell them from a record's start)."""
    lo = max(start, size - layout.header_len + 1)
    hits = np.flatnonzero(np.asarray(buf[lo:size]) == layout.sync) if lo < size else ()
    return lo + int(hits[0]) if len(hits) else None


@dataclass
class Scan:
    """Accepted records of one file as compact columns: file offsets, lengths,
    stamps and the device frames back to back (stamps removed). A BP3010 file
    read for replay keeps its decoded increments (`imu`) instead of the frames."""

    path: str
    layout: Layout
    starts: np.ndarray  # int64 file offsets of accepted records
    lengths: np.ndarray  # int32 record lengths (stamp included for record files); read-only for BP3010
    stamps: np.ndarray  # float64 (NaN for raw device streams)
    frame_data: np.ndarray | None  # uint8, the accepted frames as the device sent them, back to back
    stats: dict = field(default_factory=dict)
    imu: "ImuLog | None" = None
    _offsets: np.ndarray | None = field(default=None, repr=False, compare=False)

    @property
    def count(self) -> int:
        return len(self.starts)

    @property
    def frame_offsets(self) -> np.ndarray:
        """(count + 1,) int64: frame k is frame_data[offsets[k]:offsets[k + 1]]."""
        if self._offsets is None:
            self._offsets = np.zeros(self.count + 1, dtype=np.int64)
            np.cumsum(self.lengths - self.layout.stamp_len, out=self._offsets[1:])
        return self._offsets

    def _require_frames(self) -> np.ndarray:
        if self.frame_data is None:
            raise LogError(f"{self.path}: read as decoded IMU samples; its frames were not kept")
        return self.frame_data

    def frame(self, k: int) -> bytes:
        """The device frame of record k, as the device sent it (stamp removed)."""
        off = self.frame_offsets
        return self._require_frames()[int(off[k]):int(off[k + 1])].tobytes()

    def frames(self) -> list[bytes]:
        data, off = self._require_frames().tobytes(), self.frame_offsets.tolist()
        return [data[a:b] for a, b in zip(off[:-1], off[1:])]

    def iter_frames(self, rows: int = 1 << 16) -> Iterator[tuple[bytes, float]]:
        """(frame, stamp) of every record, made a few thousand at a time (no list of them all)."""
        data, off = self._require_frames(), self.frame_offsets
        for a in range(0, self.count, rows):
            b = min(self.count, a + rows)
            chunk, o = data[off[a]:off[b]].tobytes(), (off[a:b + 1] - off[a]).tolist()
            yield from zip((chunk[x:y] for x, y in zip(o[:-1], o[1:])), self.stamps[a:b].tolist())

    def record(self, k: int) -> bytes:
        """Record k as it lies in the file (stamp included)."""
        f, h = self.frame(k), self.layout.header_len
        if not self.layout.stamped:
            return f
        return f[:h] + self.stamps[k:k + 1].astype("<f8").tobytes() + f[h:]

    def keep(self, keep: np.ndarray) -> None:
        """Keep only the records where keep is true (one column copied at a time)."""
        if self.frame_data is not None:
            self.frame_data = self.frame_data[np.repeat(keep, self.lengths - self.layout.stamp_len)]
        if self.imu is not None:
            self.imu.keep(keep)
            self.stamps = self.imu.stamps
        else:
            self.stamps = self.stamps[keep]
        self.starts, self.lengths = self.starts[keep], self.lengths[keep]
        self._offsets = None


def message_ids(s: Scan) -> np.ndarray:
    """Superstar II message ID of every record."""
    return s._require_frames()[s.frame_offsets[:-1] + 1] & 0x7F


def ubx_class_ids(s: Scan) -> np.ndarray:
    """(n, 2) UBX class and id of every record."""
    data, off = s._require_frames(), s.frame_offsets[:-1]
    return np.column_stack([data[off + 2], data[off + 3]])


@dataclass
class ImuLog:
    """IMU samples. A BP3010's increments are kept as the int16 counts its frames carry
    (``lsb`` set: a quarter of the memory of floats, exactly the same values back);
    other sources give floats (``lsb`` None). ``dtheta_rad``/``dv_mps`` give floats either way."""

    stamps: np.ndarray  # (n,) system time of each frame's first byte
    dtheta: np.ndarray  # (n, 3) rad, or counts of lsb[0]
    dv: np.ndarray  # (n, 3) m/s, or counts of lsb[1]
    status: np.ndarray  # (n,) uint8
    counter: np.ndarray  # (n,) uint8
    rate_hz: int
    lsb: tuple[float, float] | None = None  # (rad, m/s) per count when the increments are counts

    def __len__(self) -> int:
        return len(self.stamps)

    @property
    def dtheta_rad(self) -> np.ndarray:
        return self.dtheta if self.lsb is None else self.dtheta * self.lsb[0]

    @property
    def dv_mps(self) -> np.ndarray:
        return self.dv if self.lsb is None else self.dv * self.lsb[1]

    def keep(self, keep: np.ndarray) -> None:
        """Keep only the samples where keep is true, in place, one column at a time."""
        for name in ("stamps", "dtheta", "dv", "status", "counter"):
            setattr(self, name, getattr(self, name)[keep])


def bp3010_lsb(rate_hz: int) -> tuple[float, float]:
    """A BP3010's angle (rad) and velocity (m/s) increment per count at this rate."""
    return bp3010.dtheta_lsb_rad(rate_hz), bp3010.dv_lsb_mps(rate_hz)

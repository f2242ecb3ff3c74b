"""RTKLIB time-tag files (``FILE.tag`` beside a stream that str2str or rtknavi logged with ``::T``).

The logger writes each chunk it received to the stream file and then one tag: the host's millisecond tick
at that moment (counted from the start) and the file offset after the chunk. So every byte before a tag's
offset had arrived by the tag's tick. Layout (the extended form, header text "TIMETAG RTKLIB EX"): 60 bytes
of text, u32 tick at the start, u32 whole seconds and f64 fraction of the start time (GPS time counted
like Unix time), then (u32 tick ms, u32 offset) pairs, little-endian.

The ticks are the host's, arrival times rather than measurement times, and on Windows they step by
15.6 ms; a sensor's own sample counter (``imu_csv``'s ``counter`` column) carries the measurement
times, and ``timing.lower_envelope`` of arrival against counter gives the mapping (``counter_times``).
"""

from __future__ import annotations

import struct
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from .common import UNIX_TO_GPS_S, ReaderError, read_bytes

MAGIC = b"TIMETAG RTKLIB"
TEXT_BYTES = 60
HEADER_BYTES = TEXT_BYTES + 4 + 4 + 8
PAIR = np.dtype([("tick_ms", "<u4"), ("offset", "<u4")])


@dataclass
class TimeTags:
    start_t_abs: float  # GPS seconds since the GPS epoch of tick 0
    tick_ms: np.ndarray  # (n,) host ms since the start, unwrapped (int64)
    offset: np.ndarray  # (n,) stream offset after each chunk (int64), non-decreasing
    source: str = ""

    def arrival_t_abs(self, end_offsets: np.ndarray) -> np.ndarray:
        """GPS time by which the byte just before each end offset had arrived (NaN past the last tag)."""
        k = np.searchsorted(self.offset, np.asarray(end_offsets), side="left")
        out = np.full(len(k), np.nan)
        ok = k < len(self.offset)
        out[ok] = self.start_t_abs + self.tick_ms[k[ok]] * 1e-3
        return out

    def stream_offsets(self, end_offset: np.ndarray, line_no: np.ndarray, file_bytes: int, newlines: int
                       ) -> np.ndarray:
        """A text file's line-end offsets as offsets of the logged stream: the same, or, when the stream had
        CR LF line ends that the file no longer has (its last tag then lies one byte further per line), moved
        by the line number."""
        last = int(self.offset[-1]) if len(self.offset) else -1
        if last == file_bytes:
            return end_offset
        if last == file_bytes + newlines:
            return end_offset + line_no
        raise ReaderError(self.source, f"the last tag's offset {last} matches neither the stream file's "
                          f"{file_bytes} bytes nor {file_bytes + newlines} with CR LF line ends: not this "
                          "file's tags, or the file was cut", field="offset")


def read(path: str | Path) -> TimeTags:
    path = Path(path)
    data = read_bytes(path)
    if len(data) < HEADER_BYTES or not data.startswith(MAGIC):
        raise ReaderError(path, f"not an RTKLIB time-tag file (no {MAGIC.decode()} header)", offset=0)
    if b"EX" not in data[len(MAGIC):TEXT_BYTES].split(b"\0")[0]:
        raise ReaderError(path, "only the extended tag layout (TIMETAG RTKLIB EX) is read", offset=0)
    seconds, = struct.unpack_from("<I", data, TEXT_BYTES + 4)
    fraction, = struct.unpack_from("<d", data, TEXT_BYTES + 8)
    n = (len(data) - HEADER_BYTES) // PAIR.itemsize
    pairs = np.frombuffer(data, PAIR, count=n, offset=HEADER_BYTES)
    tick = pairs["tick_ms"].astype(np.int64)
    tick += np.concatenate([[0], np.cumsum(np.diff(tick) < -(1 << 31))]) << 32  # a 49-day wrap
    offset = pairs["offset"].astype(np.int64)
    back = np.flatnonzero(np.diff(offset) < 0)
    if len(back):
        k = int(back[0]) + 1
        raise ReaderError(path, f"stream offset goes back ({offset[k - 1]} then {offset[k]})",
                          offset=HEADER_BYTES + k * PAIR.itemsize, field="offset")
    if not 0.0 <= fraction < 1.0:
        raise ReaderError(path, f"start fraction {fraction} is not a fraction of a second",
                          offset=TEXT_BYTES + 8, field="start time")
    return TimeTags(seconds + fraction - UNIX_TO_GPS_S, tick, offset, path.name)

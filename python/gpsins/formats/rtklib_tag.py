"""RTKLIB time-tag files (``FILE.tag`` beside a stream that str2str or rtknavi logged with ``::T``).

The logger writes each chunk it received to the stream file and then one tag: the host's millisecond tick
at that moment (counted from the start) and the file offset after the chunk. So every byte before a tag's
offset had arrived by the tag's tick.

Layout, little-endian: 60 bytes of text (the writer's label, "TIMETAG RTKLIB 2.4.3", "TIMETAG RTKLIB demo5
b34k", "TIMETAG RTKLIB EX 2.5.0", ..., NUL-padded), the u32 host tick at the start (RTKLIB's tick_f), the
start time (GPS time counted like Unix time), then (u32 tick ms, offset) pairs to the end of the file. The
forks differ in two sizes, and the label says neither:

- the start time: u32 whole seconds and f64 fraction (12 bytes: demo5, EX and 2.4.3 b34 write it so), or the
  C struct gtime_t as it lies in memory, time_t and f64 (16 bytes: RTKLIB 2.4.3 before b34 on 64-bit hosts;
  the time_t's upper half, zero until 2106, or alignment padding on 32-bit ones);
- the offsets: u32 (``::P=4``, demo5's and EX's default) or u64 (``::P=8``, 2.4.3's default on 64-bit hosts).

So the layout is decided from the file itself: of the four, the one whose pairs fill the file exactly, whose
start fraction is a clock's fraction of a second, whose offsets never go back (and stay within the stream
file beside the tag, when there is one) and whose ticks go forward. Misread, each other layout takes offsets
for ticks or the upper half of a u64 for an offset, and fails those at once; where a handful of tags fit two
layouts, the one with the smaller offsets (a misread offset has a tick or a length in its upper 32 bits). Only
when no layout fits the whole file is a last, incomplete pair (a file cut while being written) left out.

The ticks are the host's, arrival times rather than measurement times, and on Windows they step by
15.6 ms; a sensor's own sample counter (``imu_csv``'s ``counter`` column) carries the measurement
times, and ``timing.envelope.lower_envelope`` of arrival against counter gives the mapping (``counter_times``).
"""

from __future__ import annotations

import struct
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from .gpstime import UNIX_TO_GPS_S
from .common import ReaderError, read_bytes

MAGIC = b"TIMETAG RTKLIB"  # how RTKLIB's labels start (not required)
TEXT_BYTES = 60
HEADER_BYTES = TEXT_BYTES + 4 + 4 + 8  # the demo5 / EX layout's header
PAIR = np.dtype([("tick_ms", "<u4"), ("offset", "<u4")])


@dataclass(frozen=True)
class Layout:
    name: str
    time_bytes: int  # 12: u32 seconds, f64 fraction; 16: time_t (its low u32 read), f64 fraction
    offset_bytes: int  # 4 or 8

    @property
    def header_bytes(self) -> int:
        return TEXT_BYTES + 4 + self.time_bytes

    @property
    def pair(self) -> np.dtype:
        return np.dtype([("tick_ms", "<u4"), ("offset", "<u4" if self.offset_bytes == 4 else "<u8")])


# In order of preference where a file (a handful of tags) fits more than one.
LAYOUTS = (Layout("12-byte start time, 4-byte offsets (demo5, EX)", 12, 4),
           Layout("16-byte start time, 8-byte offsets (RTKLIB 2.4.3, 64-bit)", 16, 8),
           Layout("12-byte start time, 8-byte offsets (demo5, EX with ::P=8)", 12, 8),
           Layout("16-byte start time, 4-byte offsets (RTKLIB 2.4.3 with ::P=4)", 16, 4))
FRACTION_RESOLUTION_S = 1e-9  # a host clock's fraction of a second is 0 or at least a nanosecond
TICK_BACKSTEPS_ALLOWED = 0.1  # share of tags whose tick may go back (a stepped host clock, a damaged tick),
# other than a wrap; misread, half of them do


@dataclass
class TimeTags:
    start_t_abs: float  # GPS seconds since the GPS epoch of tick 0
    tick_ms: np.ndarray  # (n,) host ms since the start, unwrapped (int64)
    offset: np.ndarray  # (n,) stream offset after each chunk (int64), non-decreasing
    source: str = ""
    label: str = ""  # the header's text, as written
    layout: str = LAYOUTS[0].name
    cut_bytes: int = 0  # bytes of a last, incomplete pair left out (a file cut while the logger wrote it)

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


class _Misfit(Exception):
    """Why a file cannot have one layout: the message, the byte offset and the field."""

    def __init__(self, message: str, offset: int, field: str, stage: int):
        super().__init__(message)
        self.offset, self.field, self.stage, self.cut = offset, field, stage, False


def _decode(data: bytes, lay: Layout, stream_bytes: int | None, cut_ok: bool = False
            ) -> tuple[float, np.ndarray, np.ndarray]:
    """(start seconds, unwrapped ticks, offsets) of the file read with one layout, or _Misfit; ``cut_ok``: a last,
    incomplete pair is left out."""
    head = lay.header_bytes
    if len(data) < head:
        raise _Misfit(f"{len(data)} bytes, shorter than the {head}-byte header", 0, "header", 0)
    rest = len(data) - head
    if cut_ok:
        data = data[:len(data) - rest % lay.pair.itemsize]
    elif rest % lay.pair.itemsize:
        raise _Misfit(f"the {rest} bytes after the {head}-byte header are not whole {lay.pair.itemsize}-byte "
                      f"(tick, offset) pairs", head + rest - rest % lay.pair.itemsize, "pairs", 1)
    seconds, = struct.unpack_from("<I", data, TEXT_BYTES + 4)
    fraction, = struct.unpack_from("<d", data, TEXT_BYTES + 4 + lay.time_bytes - 8)
    if not (0.0 <= fraction < 1.0 and (fraction == 0.0 or fraction >= FRACTION_RESOLUTION_S)):
        raise _Misfit(f"start fraction {fraction:.6g} is not a clock's fraction of a second",
                      TEXT_BYTES + 4 + lay.time_bytes - 8, "start time", 2)
    pairs = np.frombuffer(data, lay.pair, offset=head)
    offset = pairs["offset"].astype(np.uint64)
    if len(offset) and int(offset.max()) >= 1 << 62:
        k = int(np.argmax(offset >= 1 << 62))
        raise _Misfit(f"stream offset {int(offset[k])} is no file offset", head + k * lay.pair.itemsize + 4,
                      "offset", 3)
    offset = offset.astype(np.int64)
    back = np.flatnonzero(np.diff(offset) < 0)
    if len(back):
        k = int(back[0]) + 1
        raise _Misfit(f"stream offset goes back ({offset[k - 1]} then {offset[k]}) at tag {k}",
                      head + k * lay.pair.itemsize + 4, "offset", 4)
    if stream_bytes is not None and len(offset) and offset[-1] > 2 * stream_bytes:
        # The stream file may have lost one CR per line (CR LF -> LF), never more than half its bytes.
        raise _Misfit(f"the last stream offset {int(offset[-1])} lies beyond the stream file's {stream_bytes} "
                      "bytes (even with CR LF line ends)", len(data) - lay.offset_bytes, "offset", 5)
    tick = pairs["tick_ms"].astype(np.int64)
    step = np.diff(tick)
    wrap = step < -(1 << 31)  # the u32 millisecond tick wraps after 49.7 days
    if (len(step) and np.count_nonzero((step < 0) & ~wrap) > TICK_BACKSTEPS_ALLOWED * len(step)) \
            or np.count_nonzero(wrap) > 1 + len(step) // 1000:
        k = int(np.flatnonzero(step < 0)[0]) + 1
        raise _Misfit(f"host ticks go back at {np.count_nonzero(step < 0)} of {len(step)} tags (first "
                      f"{tick[k - 1]} then {tick[k]} ms at tag {k})", head + k * lay.pair.itemsize, "tick", 6)
    tick += np.concatenate([[0], np.cumsum(wrap)]) << 32
    return seconds + fraction, tick, offset


def _stream_size(path: Path) -> int | None:
    """The size of the stream file the tag file belongs to (FILE for FILE.tag), if it is there."""
    stream = path.with_suffix("") if path.suffix.lower() == ".tag" else None
    try:
        return stream.stat().st_size if stream is not None and stream.is_file() else None
    except OSError:
        return None


def read(path: str | Path, stream_bytes: int | None = None) -> TimeTags:
    """A tag file in whichever layout it has. ``stream_bytes``: the stream file's size (default: that of the
    file beside it, FILE for FILE.tag, when it exists), which no offset may exceed."""
    path = Path(path)
    data = read_bytes(path)
    if stream_bytes is None:
        stream_bytes = _stream_size(path)
    text = data[:TEXT_BYTES].split(b"\0")[0]
    if any(b < 0x20 and b not in b"\t\r\n" or b == 0x7F for b in text):
        k = next(i for i, b in enumerate(text) if b < 0x20 and b not in b"\t\r\n" or b == 0x7F)
        raise ReaderError(path, f"the header's first {TEXT_BYTES} bytes are no text label (byte {text[k]:#04x}): "
                          "not a time-tag file", offset=k, field="header")
    misfits = {}
    for cut_ok in (False, True):  # a file whose last pair was cut short only when no layout fits it whole
        fits = []
        for k, lay in enumerate(LAYOUTS):
            try:
                fits.append((k, lay, *_decode(data, lay, stream_bytes, cut_ok)))
            except _Misfit as m:
                if not cut_ok or misfits[lay].stage == 1:  # cut short, and still no fit: say why not
                    m.cut = cut_ok
                    misfits[lay] = m
        if fits:
            # A handful of tags can fill the file in two layouts; misread, the offsets take in a tick or the upper
            # half of a u64 and grow by 2^32 at least: the smallest offsets are the stream's own.
            _, lay, seconds, tick, offset = min(fits, key=lambda f: (int(f[4][-1]) if len(f[4]) else 0, f[0]))
            return TimeTags(seconds - UNIX_TO_GPS_S, tick, offset, path.name, text.decode("utf-8", "replace"),
                            lay.name, (len(data) - lay.header_bytes) % lay.pair.itemsize)
    # The layout that got furthest (read whole before read cut short) says why; the others in short.
    lay, best = max(misfits.items(), key=lambda x: (x[1].stage > 1 and not x[1].cut, x[1].stage))
    others = "; ".join(f"{o.name.split(' (')[0]}: {m}" for o, m in misfits.items() if o is not lay)
    raise ReaderError(path, f"{best}, read as {lay.name}; no other tag layout fits either ({others})",
                      offset=best.offset, field=best.field)

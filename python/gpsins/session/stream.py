"""Record files read in blocks (``scan_stream``), with the same result as the whole-buffer ``scan``, kept
as compact columns (offsets, lengths, stamps, frame bytes; or a BP3010's decoded increments); and the
tail of a growing file (``RecordTail``).
"""

from __future__ import annotations

import os
from pathlib import Path

import numpy as np

from .layouts import ImuLog, LAYOUTS, Layout, Scan, cut_header, bp3010_lsb
from .stamps import StampLimits, stamp_outliers
from .scan import header_candidates, follow_chain, frame_bytes, gather, stamps_at


BLOCK_BYTES = 4 << 20  # read size: the transient arrays of one block are a few times this


class _Growing:
    """A column filled block by block. Sized for the most records the file can
    hold, up to 1 GiB (pages never written take no memory); grown past that, or
    if the file grew, by reallocation, which moves no pages of a large array."""

    def __init__(self, dtype, capacity: int, width: tuple = ()):
        row = np.dtype(dtype).itemsize * int(np.prod(width, dtype=np.int64))
        self.a = np.empty((max(min(capacity, (1 << 30) // row), 16), *width), dtype)
        self.n = 0

    def reserve(self, m: int) -> np.ndarray:
        """The next m rows, to be written by the caller."""
        if self.n + m > len(self.a):
            self.a.resize((max(2 * len(self.a), self.n + m), *self.a.shape[1:]), refcheck=False)
        out = self.a[self.n:self.n + m]
        self.n += m
        return out

    def extend(self, v: np.ndarray) -> None:
        self.reserve(len(v))[...] = v

    def take(self) -> np.ndarray:
        self.a.resize((self.n, *self.a.shape[1:]), refcheck=False)  # shrinks in place
        return self.a


class FrameColumns:
    """What a Scan keeps of each record: offset, length, stamp, frame bytes."""

    def __init__(self, lay: Layout, size: int):
        n = size // lay.min_len + 1
        self.lay = lay
        self.starts, self.stamps, self.frames = _Growing(np.int64, n), _Growing(np.float64, n), _Growing(np.uint8, size)
        self.lengths = _Growing(np.int32, n) if lay.fixed_len is None else None

    def add(self, buf: np.ndarray, p: np.ndarray, length: np.ndarray, base: int) -> None:
        self.starts.extend(p + base)
        if self.lengths is not None:
            self.lengths.extend(length)
        self.stamps.extend(stamps_at(buf, p, self.lay))
        self.frames.extend(frame_bytes(buf, p, length, self.lay))

    def scan(self, path: str, stats: dict) -> Scan:
        starts = self.starts.take()
        lengths = self.lengths.take() if self.lengths is not None else _same_lengths(self.lay, len(starts))
        return Scan(path, self.lay, starts, lengths, self.stamps.take(), self.frames.take(), stats)


def _same_lengths(lay: Layout, n: int) -> np.ndarray:
    """Lengths of n records of a fixed-length layout: one value seen n times (read-only, no memory)."""
    return np.broadcast_to(np.int32(lay.fixed_len), (n,))


class ImuColumns:
    """BP3010 records decoded as they are read: offset, stamp, increments, status, counter."""

    def __init__(self, lay: Layout, size: int, rate_hz: int):
        n = size // lay.min_len + 1
        self.lay, self.rate_hz = lay, rate_hz
        self.starts, self.stamps = _Growing(np.int64, n), _Growing(np.float64, n)
        self.dtheta, self.dv = _Growing(np.int16, n, (3,)), _Growing(np.int16, n, (3,))
        self.status, self.counter = _Growing(np.uint8, n), _Growing(np.uint8, n)

    def add(self, buf: np.ndarray, p: np.ndarray, length: np.ndarray, base: int) -> None:
        self.starts.extend(p + base)
        self.stamps.extend(stamps_at(buf, p, self.lay))
        decode_bp3010(gather(buf, p + (1 + self.lay.stamp_len), 14), self.dtheta.reserve(len(p)),
                       self.dv.reserve(len(p)), self.status.reserve(len(p)), self.counter.reserve(len(p)))

    def scan(self, path: str, stats: dict) -> Scan:
        starts = self.starts.take()
        imu = ImuLog(self.stamps.take(), self.dtheta.take(), self.dv.take(), self.status.take(), self.counter.take(),
                     self.rate_hz, bp3010_lsb(self.rate_hz))
        return Scan(path, self.lay, starts, _same_lengths(self.lay, len(starts)), imu.stamps, None, stats, imu)


def decode_bp3010(body: np.ndarray, dtheta: np.ndarray, dv: np.ndarray, status: np.ndarray,
                   counter: np.ndarray) -> None:
    """(n, 14) frame bodies (after the sync, without the checksum) into the given outputs (counts)."""
    counts = np.ascontiguousarray(body[:, :12]).view("<i2")
    dtheta[:] = counts[:, 0:3]
    dv[:] = counts[:, 3:6]
    status[:] = body[:, 12]
    counter[:] = body[:, 13]


class _Chain:
    """The greedy chain of records across blocks, and the damage counts the
    whole-buffer :func:`scan` makes, decided block by block.

    A block decides everything before its first undecided position u: a
    header-valid candidate that runs past the block's end, or a place too near
    the end to hold a header. The chain runs through the valid candidates
    before u and waits at the last record's end; the bytes from u on are
    carried into the next block, so a record across a boundary is found once,
    in the block that holds all of it."""

    def __init__(self, lay: Layout, limits: StampLimits, columns):
        self.lay, self.columns = lay, columns
        self.lo, self.hi = limits.lo, limits.hi
        self.last_end = 0  # end of the last accepted record; the next is the first valid candidate from here
        self.records = self.covered = self.resyncs = 0
        self.first_discarded: int | None = None
        # Places where the chain resumes (0 and every record's end) not yet checked for a record with a good
        # checksum and an impossible stamp, because the candidate there was not yet complete.
        self.pending = np.zeros(1, np.int64)
        self.broken: set[int] = set()
        self.stats: dict = {}

    def block(self, buf: np.ndarray, base: int, final: bool) -> int:
        """Decide what buf (at file offset base) decides; returns how many of its bytes are done."""
        size, lay = len(buf), self.lay
        p, length, ok, bad_stamp = header_candidates(buf, lay, self.lo, self.hi)
        incomplete = p + length > size
        u = size
        if not final:
            u = max(0, min([size - lay.header_len + 1, *p[incomplete][:1].tolist()]))
        decided = ok & (p < u)
        vp, vl = p[decided], length[decided]
        chosen = follow_chain(vp, vl, int(np.searchsorted(vp, self.last_end - base)))
        starts, lengths = vp[chosen], vl[chosen]
        ends = starts + lengths
        if len(starts):
            prev_end = np.concatenate(([self.last_end - base], ends[:-1]))
            gap = starts != prev_end
            if self.first_discarded is None and gap.any():
                self.first_discarded = base + int(prev_end[np.argmax(gap)])
            self.resyncs += int(np.count_nonzero(gap[1:])) + int(bool(gap[0]) and self.records > 0)
            self.records += len(starts)
            self.covered += int(lengths.sum())
            self.last_end = base + int(ends[-1])
            self.columns.add(buf, starts, lengths, base)
        pending = self.pending - base
        bp_, bl_ = p[bad_stamp], length[bad_stamp]  # few: random bytes that pass the checksum, broken stamps
        k = np.minimum(np.searchsorted(ends, bp_), max(len(ends) - 1, 0))
        hit = np.isin(bp_, pending) | (ends[k] == bp_ if len(ends) else False)
        more = hit
        while more.any():
            more = ~hit & np.isin(bp_, bp_[more] + bl_[more])
            hit |= more
        self.broken.update((bp_[hit] + base).tolist())
        later = np.concatenate((pending, ends[-1:], bp_[hit] + bl_[hit]))  # records' ends before u were checked
        self.pending = np.unique(later[later >= u]) + base
        if final:
            self._finish(buf, p, length, incomplete, base, size)
        return u

    def _finish(self, buf: np.ndarray, p: np.ndarray, length: np.ndarray, incomplete: np.ndarray, base: int,
                size: int) -> None:
        total = base + size
        inc = p[incomplete & (p + base >= self.last_end)]
        if len(inc):
            tail_offset = base + int(inc[0])
        else:
            cut = cut_header(buf, self.lay, max(self.last_end - base, 0), size)
            tail_offset = base + cut if cut is not None else None
        tail = total - tail_offset if tail_offset is not None else 0
        if self.first_discarded is None and self.last_end != total - tail:
            self.first_discarded = self.last_end
        broken = sorted(self.broken)
        self.stats = {
            "records": self.records,
            "bad_stamps": len(broken),
            "first_bad_stamp_offset": broken[0] if broken else None,
            "bytes": total,
            "discarded_bytes": total - self.covered - tail,
            "truncated_tail_bytes": tail,
            "truncated_tail_offset": tail_offset,
            "first_discarded_offset": self.first_discarded,
            "resyncs": self.resyncs,
        }


def stream_blocks(f, layout: Layout, limits: StampLimits, columns, block_bytes: int) -> dict:
    """Feed the chain block by block from a binary file object; returns the damage counts."""
    chain = _Chain(layout, limits, columns)
    carry, base = np.zeros(0, np.uint8), 0
    while True:
        buf = np.empty(len(carry) + block_bytes, np.uint8)
        buf[:len(carry)] = carry
        got = f.readinto(memoryview(buf)[len(carry):])
        if not got:
            chain.block(carry, base, final=True)
            return chain.stats
        buf = buf[:len(carry) + got]
        u = chain.block(buf, base, final=False)
        carry, base = buf[u:].copy(), base + u


class RecordTail:
    """The records a growing record file gains, as the block reader (:func:`read_record_file`) finds
    them: ``read()`` reads the bytes added since the last call and returns the records they complete
    (decided exactly as :func:`scan_stream` decides them, a record across a read's end waiting for its
    last bytes). The whole-file neighbour test of the stamps (:func:`reject_bad_stamps`) is made on
    the new records against the last few before them: a record at the end is judged on the side it
    has (as the whole-file test judges a file's last record). ``gpsins live`` follows a session with it."""

    CONTEXT = 16  # stamps before the new records that the neighbour test sees

    def __init__(self, path: str | Path, device: str, limits: StampLimits | None = None):
        self.path, self.layout = Path(path), LAYOUTS[device]
        self.limits = limits or StampLimits()
        self._chain = _Chain(self.layout, self.limits, self)
        self._carry, self._base = np.zeros(0, np.uint8), 0
        self._new: list[tuple] = []
        self._context = np.zeros(0)
        self.records = self.bad_stamps = 0

    def add(self, buf: np.ndarray, p: np.ndarray, length: np.ndarray, base: int) -> None:  # the chain's columns
        self._new.append((p + base, np.asarray(length, np.int64), stamps_at(buf, p, self.layout),
                          frame_bytes(buf, p, length, self.layout)))

    @property
    def size(self) -> int:
        """File bytes read so far."""
        return self._base + len(self._carry)

    def read(self, limits: StampLimits | None = None) -> Scan:
        """The records completed since the last call (an empty Scan when none); ``limits``: the
        session's span as it stands now (it grows with the clock pairs)."""
        if limits is not None:
            self.limits = limits
            self._chain.lo, self._chain.hi = limits.lo, limits.hi
        data = b""
        try:
            if os.stat(self.path).st_size > self.size:  # a stat when nothing came: cheap to poll often
                with open(self.path, "rb", buffering=0) as f:
                    f.seek(self.size)
                    data = f.read()
        except OSError:
            pass  # not there yet (the sidecar lists a part before its files exist)
        if data:
            buf = np.concatenate([self._carry, np.frombuffer(data, np.uint8)])
            u = self._chain.block(buf, self._base, final=False)
            self._carry, self._base = buf[u:].copy(), self._base + u
        new, self._new = self._new, []
        lay = self.layout
        if not new:
            return Scan(str(self.path), lay, np.zeros(0, np.int64), np.zeros(0, np.int32), np.zeros(0),
                        np.zeros(0, np.uint8))
        starts, lengths, stamps, frames = (np.concatenate([x[j] for x in new]) for j in range(4))
        out = Scan(str(self.path), lay, starts, lengths.astype(np.int32), stamps, frames)
        if lay.stamped and out.count:
            ctx = self._context
            bad = stamp_outliers(np.concatenate([ctx, out.stamps]), self.limits)[len(ctx):]
            if bad.any():
                self.bad_stamps += int(bad.sum())
                out.keep(~bad)
            self._context = np.concatenate([ctx, out.stamps])[-self.CONTEXT:]
        self.records += out.count
        return out


def file_size(f) -> int:
    try:
        here = f.tell()
        end = f.seek(0, 2)
        f.seek(here)
        return end - here
    except (OSError, AttributeError, ValueError):
        return 1 << 16


def scan_stream(f, layout: Layout, path: str = "<stream>", limits: "StampLimits | None" = None,
                block_bytes: int = BLOCK_BYTES) -> Scan:
    """The same records and counts as :func:`scan` of the whole content of the
    binary file object f, read in blocks of block_bytes: memory is the result's
    columns plus a few blocks, whatever the file's size."""
    limits = limits or StampLimits()
    columns = FrameColumns(layout, file_size(f))
    return columns.scan(path, stream_blocks(f, layout, limits, columns, block_bytes))

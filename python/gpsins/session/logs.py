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
import os
from dataclasses import dataclass, field
from pathlib import Path
from typing import Iterator

import numpy as np

from gpsins_logger import bp3010
from gpsins_logger import superstar2 as ss2
from gpsins_logger import ubx
from gpsins_logger.recorder import CLOCK_STEP_THRESHOLD_S, RAW_HEADER

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


def _cut_header(buf: np.ndarray, layout: Layout, start: int, size: int) -> int | None:
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


def _gather(buf: np.ndarray, offsets: np.ndarray, width: int) -> np.ndarray:
    """(n, width) uint8 rows of buf starting at offsets, without an (n, width) index array."""
    if len(buf) < width:
        return np.zeros((0, width), np.uint8)
    return np.lib.stride_tricks.sliding_window_view(buf, width)[offsets]


def _check_stamps(buf: np.ndarray, pc: np.ndarray, lay: Layout, lo: float, hi: float, good: np.ndarray
                  ) -> tuple[np.ndarray, np.ndarray]:
    """(valid, checksum-valid but with an impossible stamp) for complete candidates at pc."""
    if not lay.stamped:
        return good, np.zeros(len(good), dtype=bool)
    st = _gather(buf, pc + lay.header_len, STAMP_BYTES).view("<f8").reshape(-1)
    with np.errstate(invalid="ignore"):
        plausible = np.isfinite(st) & (st > lo) & (st < hi)
    return good & plausible, good & ~plausible


def _candidates(buf: np.ndarray, lay: Layout, lo: float = STAMP_MIN, hi: float = STAMP_MAX
                ) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """All header-valid candidates: positions, lengths, checksum/stamp validity,
    and which pass the checksum but carry an impossible stamp."""
    size = len(buf)
    sl = lay.stamp_len
    if lay.device == "ublox":
        return _ubx_candidates(buf, lay, lo, hi)
    if lay.device == "superstar2":
        p = np.flatnonzero(buf[:max(size - 3, 0)] == ss2.SOH).astype(np.int64)
        p = p[buf[p + 2] == (buf[p + 1] ^ 0xFF)]
        n_payload = buf[p + 3].astype(np.int64)
        length = n_payload + 6 + sl
    else:
        p = np.flatnonzero(buf == bp3010.SYNC).astype(np.int64)
        length = np.full(len(p), bp3010.FRAME_LEN + sl, dtype=np.int64)
    complete = p + length <= size
    ok = np.zeros(len(p), dtype=bool)
    bad_stamp = np.zeros(len(p), dtype=bool)
    pc, lc = p[complete], length[complete]
    if len(pc) and lay.device == "superstar2":
        # Running sums modulo the checksum's width: unsigned wrap-around is exact
        # here and keeps the array 2 bytes per input byte.
        cs = np.zeros(size + 1, dtype=np.uint16)
        np.cumsum(buf, dtype=np.uint16, out=cs[1:])
        body = pc + ss2.HEADER_LEN + sl
        end = pc + lc - 2  # checksum position
        total = (cs[pc + ss2.HEADER_LEN] - cs[pc]) + (cs[end] - cs[body])
        want = buf[end].astype(np.int64) | buf[end + 1].astype(np.int64) << 8
        good = total.astype(np.uint16) == want
    elif len(pc):
        # One length: the 14 body bytes of each candidate summed modulo 256 (faster than running sums).
        body = pc + 1 + sl
        end = pc + lc - 1
        good = _gather(buf, body, bp3010.FRAME_LEN - 2).sum(axis=1, dtype=np.uint8) == buf[end]
    if len(pc):
        ok[complete], bad_stamp[complete] = _check_stamps(buf, pc, lay, lo, hi, good)
    return p, length, ok, bad_stamp


def _ubx_candidates(buf: np.ndarray, lay: Layout, lo: float, hi: float):
    """UBX candidates: B5 62 and a plausible length; the Fletcher checksum over
    class..length and the payload (the stamp between them left out) from
    running sums modulo 256: with C[k] the sum of the first k bytes and D[k]
    the sum of C[1..k], a stretch [a, b) has CK_A = C[b] - C[a] and CK_B =
    D[b] - D[a] - (b - a) C[a]; two stretches chain as A2 = A1 + A', B2 = B1 +
    B' + len' A1."""
    size, sl = len(buf), lay.stamp_len
    p = np.flatnonzero(buf[:max(size - lay.header_len + 1, 0)] == ubx.SYNC1).astype(np.int64)
    p = p[buf[p + 1] == ubx.SYNC2]
    n_payload = buf[p + 4].astype(np.int64) | buf[p + 5].astype(np.int64) << 8
    plausible_len = n_payload <= ubx.MAX_PAYLOAD
    p, n_payload = p[plausible_len], n_payload[plausible_len]
    length = n_payload + 8 + sl
    complete = p + length <= size
    ok = np.zeros(len(p), dtype=bool)
    bad_stamp = np.zeros(len(p), dtype=bool)
    pc, npc = p[complete], n_payload[complete]
    if len(pc):
        c = np.zeros(size + 1, dtype=np.uint8)
        np.cumsum(buf, dtype=np.uint8, out=c[1:])
        d = np.zeros(size + 1, dtype=np.uint8)
        np.cumsum(c[1:], dtype=np.uint8, out=d[1:])

        def stretch(a, b):
            ca = c[a]
            return c[b] - ca, d[b] - d[a] - ((b - a) & 0xFF).astype(np.uint8) * ca

        a1, b1 = stretch(pc + 2, pc + ubx.HEADER_LEN)
        body = pc + ubx.HEADER_LEN + sl
        a2, b2 = stretch(body, body + npc)
        ck_a = a1 + a2
        ck_b = b1 + b2 + (npc & 0xFF).astype(np.uint8) * a1
        end = body + npc
        good = (ck_a == buf[end]) & (ck_b == buf[end + 1])
        ok[complete], bad_stamp[complete] = _check_stamps(buf, pc, lay, lo, hi, good)
    return p, length, ok, bad_stamp


def scan(buf: np.ndarray | bytes, layout: Layout, path: str = "<bytes>", limits: "StampLimits | None" = None
         ) -> Scan:
    """Accepted records of buf. With limits (the session's span), a candidate
    whose stamp lies outside the span is not a record: random bytes that pass
    an 8-bit sum then almost never pass as a record, so they cannot swallow
    an intact record that overlaps them."""
    buf = np.frombuffer(buf, dtype=np.uint8) if isinstance(buf, (bytes, bytearray, memoryview)) else buf
    size = len(buf)
    lo, hi = (limits.lo, limits.hi) if limits is not None else (STAMP_MIN, STAMP_MAX)
    p, length, ok, bad_stamp = _candidates(buf, layout, lo, hi)
    vp, vl = p[ok], length[ok]
    chosen = _follow(vp, vl, 0)  # the greedy chain from the start
    starts, lengths = vp[chosen], vl[chosen]
    # The tail: the first incomplete header-valid candidate after the last
    # accepted record. An incomplete candidate earlier than that was a false
    # header (whole records follow it), as the streaming finder decides at flush.
    tail_offset = None
    last_end = int(starts[-1] + lengths[-1]) if len(starts) else 0
    inc = p[(p + length > size) & (p >= last_end)]
    if len(inc):
        tail_offset = int(inc[0])
    else:
        tail_offset = _cut_header(buf, layout, last_end, size)
    tail = size - tail_offset if tail_offset is not None else 0
    covered = int(lengths.sum())
    # Where each covered stretch ends vs where the next begins: the first mismatch is the first discarded byte.
    prev_end = np.concatenate(([0], starts + lengths))
    gaps = np.flatnonzero(prev_end != np.concatenate((starts, [size - tail])))
    first_discarded = int(prev_end[gaps[0]]) if len(gaps) else None
    # A record with a good checksum but a stamp no clock can give (non-finite,
    # <= 0, beyond 2286) that sits where the chain of records resumes.
    # Several in a row each start where the one before ends.
    resume = np.concatenate(([0], starts + lengths))  # sorted
    bp_, bl_ = p[bad_stamp], length[bad_stamp]
    k = np.minimum(np.searchsorted(resume, bp_), len(resume) - 1)
    hit = resume[k] == bp_
    more = hit
    while more.any():
        more = ~hit & np.isin(bp_, bp_[more] + bl_[more])  # small arrays: the broken ones only
        hit |= more
    broken = bp_[hit]
    stats = {
        "records": int(len(starts)),
        "bad_stamps": int(len(broken)),
        "first_bad_stamp_offset": int(broken[0]) if len(broken) else None,
        "bytes": int(size),
        "discarded_bytes": int(size - covered - tail),
        "truncated_tail_bytes": int(tail),
        "truncated_tail_offset": tail_offset,
        "first_discarded_offset": first_discarded,
        "resyncs": int(np.count_nonzero(np.diff(starts) != lengths[:-1])) if len(starts) > 1 else 0,
    }
    return Scan(path, layout, starts, lengths.astype(np.int32), _stamps_at(buf, starts, layout),
                _frame_bytes(buf, starts, lengths, layout), stats)


def _stamps_at(buf: np.ndarray, starts: np.ndarray, lay: Layout) -> np.ndarray:
    if not lay.stamped:
        return np.full(len(starts), np.nan)
    return _gather(buf, starts + lay.header_len, STAMP_BYTES).view("<f8").reshape(-1)


def _frame_bytes(buf: np.ndarray, starts: np.ndarray, lengths: np.ndarray, lay: Layout) -> np.ndarray:
    """The records at starts (non-overlapping, sorted) without their stamps, back to back:
    a +1/-1 step at each record's and stamp's ends, summed, marks the bytes to keep."""
    if not len(starts):
        return np.zeros(0, np.uint8)
    if lay.device == "bp3010":  # one length: rows of the record, the stamp's columns left out
        rows = _gather(buf, starts, bp3010.FRAME_LEN + lay.stamp_len)
        h = lay.header_len
        return np.concatenate((rows[:, :h], rows[:, h + lay.stamp_len:]), axis=1).reshape(-1)
    step = np.zeros(len(buf) + 1, np.int8)
    step[starts] += 1  # each assignment's indices are distinct, so no step is lost
    step[starts + lengths] -= 1
    if lay.stamped:
        stamp = starts + lay.header_len
        step[stamp] -= 1
        step[stamp + STAMP_BYTES] += 1
    return buf[np.cumsum(step[:-1], dtype=np.int8) > 0]


# --- streaming reader ---------------------------------------------------------------

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


class _FrameColumns:
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
        self.stamps.extend(_stamps_at(buf, p, self.lay))
        self.frames.extend(_frame_bytes(buf, p, length, self.lay))

    def scan(self, path: str, stats: dict) -> Scan:
        starts = self.starts.take()
        lengths = self.lengths.take() if self.lengths is not None else _same_lengths(self.lay, len(starts))
        return Scan(path, self.lay, starts, lengths, self.stamps.take(), self.frames.take(), stats)


def _same_lengths(lay: Layout, n: int) -> np.ndarray:
    """Lengths of n records of a fixed-length layout: one value seen n times (read-only, no memory)."""
    return np.broadcast_to(np.int32(lay.fixed_len), (n,))


class _ImuColumns:
    """BP3010 records decoded as they are read: offset, stamp, increments, status, counter."""

    def __init__(self, lay: Layout, size: int, rate_hz: int):
        n = size // lay.min_len + 1
        self.lay, self.rate_hz = lay, rate_hz
        self.starts, self.stamps = _Growing(np.int64, n), _Growing(np.float64, n)
        self.dtheta, self.dv = _Growing(np.int16, n, (3,)), _Growing(np.int16, n, (3,))
        self.status, self.counter = _Growing(np.uint8, n), _Growing(np.uint8, n)

    def add(self, buf: np.ndarray, p: np.ndarray, length: np.ndarray, base: int) -> None:
        self.starts.extend(p + base)
        self.stamps.extend(_stamps_at(buf, p, self.lay))
        _decode_bp3010(_gather(buf, p + (1 + self.lay.stamp_len), 14), self.dtheta.reserve(len(p)),
                       self.dv.reserve(len(p)), self.status.reserve(len(p)), self.counter.reserve(len(p)))

    def scan(self, path: str, stats: dict) -> Scan:
        starts = self.starts.take()
        imu = ImuLog(self.stamps.take(), self.dtheta.take(), self.dv.take(), self.status.take(), self.counter.take(),
                     self.rate_hz, bp3010_lsb(self.rate_hz))
        return Scan(path, self.lay, starts, _same_lengths(self.lay, len(starts)), imu.stamps, None, stats, imu)


def _decode_bp3010(body: np.ndarray, dtheta: np.ndarray, dv: np.ndarray, status: np.ndarray,
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
        p, length, ok, bad_stamp = _candidates(buf, lay, self.lo, self.hi)
        incomplete = p + length > size
        u = size
        if not final:
            u = max(0, min([size - lay.header_len + 1, *p[incomplete][:1].tolist()]))
        decided = ok & (p < u)
        vp, vl = p[decided], length[decided]
        chosen = _follow(vp, vl, int(np.searchsorted(vp, self.last_end - base)))
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
            cut = _cut_header(buf, self.lay, max(self.last_end - base, 0), size)
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


def _follow(vp: np.ndarray, vl: np.ndarray, k: int) -> np.ndarray:
    """Which of the valid candidates (positions vp, lengths vl) the chain takes from candidate k on:
    after a record ending at e, the first valid candidate at or after e."""
    n = len(vp)
    chosen = np.zeros(n, dtype=bool)
    if k >= n:
        return chosen
    succ = np.searchsorted(vp, vp + vl)
    irregular = np.flatnonzero(succ != np.arange(1, n + 1))
    while k < n:
        j = np.searchsorted(irregular, k)
        if j == len(irregular):
            chosen[k:] = True
            break
        stop = irregular[j]
        chosen[k:stop + 1] = True
        k = succ[stop]
    return chosen


def _stream(f, layout: Layout, limits: StampLimits, columns, block_bytes: int) -> dict:
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
        self._new.append((p + base, np.asarray(length, np.int64), _stamps_at(buf, p, self.layout),
                          _frame_bytes(buf, p, length, self.layout)))

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


def _file_size(f) -> int:
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
    columns = _FrameColumns(layout, _file_size(f))
    return columns.scan(path, _stream(f, layout, limits, columns, block_bytes))


@dataclass(frozen=True)
class StampLimits:
    """What a plausible stamp is for one session: inside [lo, hi], and never
    earlier than a neighbouring record's stamp by more than back_s (a clock
    step the clock pairs saw, or the logger's clamp tolerance)."""

    lo: float = STAMP_MIN
    hi: float = STAMP_MAX
    back_s: float = CLOCK_STEP_THRESHOLD_S


def stamp_limits(directory: Path, sidecar: dict) -> StampLimits:
    """The session's span from the sidecar's start/stop and the clock pairs,
    widened by a margin; a session without a stop (the logger was killed) may
    have records up to a clock-pair interval after the last pair. Between two
    pairs the realtime clock may have stepped at any moment, so each interval
    spans its monotonic length under either pair's offset."""
    pairs = []
    for key in ("start", "stop"):
        pair = sidecar.get(key)
        if isinstance(pair, dict) and _finite(pair.get("realtime")):
            m = pair.get("monotonic")
            pairs.append((float(pair["realtime"]), float(m) if _finite(m) else np.nan))
    try:
        with open(directory / "clock.csv", encoding="ascii", errors="replace") as f:
            next(f, None)
            for line in f:
                try:
                    r, m = (float(v) for v in line.split(","))
                except ValueError:
                    continue  # a torn last line
                if np.isfinite(r) and np.isfinite(m):
                    pairs.append((r, m))
    except OSError:
        pass
    if not pairs:
        return StampLimits()
    real = np.array([r for r, _ in pairs])
    lo, hi = float(real.min()), float(real.max())
    timed = np.array(sorted((m, r - m) for r, m in pairs if np.isfinite(m)))
    back = CLOCK_STEP_THRESHOLD_S
    if len(timed) > 1:
        mono, off = timed[:, 0], timed[:, 1]
        lo = min(lo, float(np.min(mono[:-1] + np.minimum(off[:-1], off[1:]))))
        hi = max(hi, float(np.max(mono[1:] + np.maximum(off[:-1], off[1:]))))
        back = max(back, -float(np.min(np.diff(off))) + CLOCK_STEP_THRESHOLD_S)
    interval = 0.0
    if not isinstance(sidecar.get("stop"), dict):
        cfg = sidecar.get("config", {}).get("session", {}) if isinstance(sidecar.get("config"), dict) else {}
        interval = float(cfg.get("clock_pair_interval_s", 10.0)) if _finite(cfg.get("clock_pair_interval_s", 10.0)) \
            else 10.0
    return StampLimits(lo - SPAN_MARGIN_S, hi + interval + SPAN_MARGIN_S, back)


def _finite(v) -> bool:
    return isinstance(v, (int, float)) and not isinstance(v, bool) and bool(np.isfinite(v))


OUTLIER_ROWS = 1 << 20  # stamps compared at a time: the temporaries stay a few MB whatever the file


def stamp_outliers(st: np.ndarray, limits: StampLimits) -> np.ndarray:
    """Which stamps are impossible: outside the session, or out of line with both neighbours."""
    bad = ~((st >= limits.lo) & (st <= limits.hi))
    # Neighbour test on the records left: a stamp is damaged when it runs back
    # from the previous record or ahead of the next by more than a clock step,
    # while those two agree with each other. Repeat so a damaged record does
    # not hide its neighbour's damage; each pass only removes records.
    for _ in range(8):
        keep = np.flatnonzero(~bad) if bad.any() else None  # None: all of them, no copy
        t = st if keep is None else st[keep]
        if len(t) < 2:
            break
        out = _out_of_line(t, limits.back_s)
        if not out.any():
            break
        bad[out if keep is None else keep[out]] = True
    return bad


def _out_of_line(t: np.ndarray, back: float) -> np.ndarray:
    """One pass of the neighbour test over t, a block of rows at a time."""
    n = len(t)
    out = np.zeros(n, dtype=bool)
    for a in range(0, n, OUTLIER_ROWS):
        b = min(n, a + OUTLIER_ROWS)
        cur = t[a:b]
        prev = t[a - 1:b - 1] if a > 0 else np.concatenate(([-np.inf], t[:b - 1]))
        nxt = t[a + 1:b + 1] if b < n else np.concatenate((t[a + 1:], [np.inf]))
        agree = nxt >= prev - back
        # The ends have one neighbour: it must agree with its own other neighbour.
        if n < 3:
            agree[:] = False
        else:
            if a == 0:
                agree[0] = t[2] >= t[1] - back
            if b == n:
                agree[-1] = t[-2] >= t[-3] - back
        out[a:b] = ((cur < prev - back) | (cur > nxt + back)) & agree
    return out


def _first_backwards(st: np.ndarray) -> tuple[int, int | None]:
    """How many stamps run back from the one before, and the index of the first."""
    count, first = 0, None
    for a in range(0, len(st) - 1, OUTLIER_ROWS):
        back = np.flatnonzero(st[a + 1:a + 1 + OUTLIER_ROWS] < st[a:a + OUTLIER_ROWS][:len(st) - 1 - a])
        count += len(back)
        if first is None and len(back):
            first = a + int(back[0]) + 1
    return count, first


def reject_bad_stamps(s: Scan, limits: StampLimits) -> Scan:
    """Drop records whose stamp is impossible (see :func:`stamp_outliers`),
    count them, keep their neighbours."""
    if not s.layout.stamped or not s.count:
        return s
    bad = stamp_outliers(s.stamps, limits)
    n_bad = int(np.count_nonzero(bad))
    if n_bad:
        s.stats["bad_stamps"] += n_bad
        first = int(s.starts[np.argmax(bad)])
        old = s.stats["first_bad_stamp_offset"]
        s.stats["first_bad_stamp_offset"] = first if old is None else min(old, first)
        s.stats["discarded_bytes"] += int(s.lengths[bad].sum())
        s.stats["records"] -= n_bad
        s.keep(~bad)
    return s


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
            size = _file_size(f)
            columns = _FrameColumns(lay, size) if imu_rate_hz is None else _ImuColumns(lay, size, imu_rate_hz)
            out = columns.scan(str(path), _stream(f, lay, limits, columns, block_bytes))
    except OSError as e:
        raise LogError(f"{path}: cannot read: {e.strerror}") from None
    out = reject_bad_stamps(out, limits)
    count, first = _first_backwards(out.stamps)
    out.stats["stamps_backwards"] = count
    out.stats["first_backwards_offset"] = int(out.starts[first]) if first is not None else None
    return out


def message_ids(s: Scan) -> np.ndarray:
    """Superstar II message ID of every record."""
    return s._require_frames()[s.frame_offsets[:-1] + 1] & 0x7F


def ubx_class_ids(s: Scan) -> np.ndarray:
    """(n, 2) UBX class and id of every record."""
    data, off = s._require_frames(), s.frame_offsets[:-1]
    return np.column_stack([data[off + 2], data[off + 3]])


# --- BP3010 -----------------------------------------------------------------------


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
        _decode_bp3010(frames[r, 1:15], out.dtheta[r], out.dv[r], out.status[r], out.counter[r])
    return out


# --- sessions ---------------------------------------------------------------------


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

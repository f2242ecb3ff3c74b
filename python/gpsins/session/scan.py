"""The vectorised scanner of a whole buffer: every candidate record (sync, header test, device checksum,
plausible stamp) found in one pass, then the chain of records followed from the start, resynchronising at
the next valid candidate after damage, as the logger's streaming finder does on a byte stream.
"""

from __future__ import annotations


import numpy as np

from gpsins_logger import bp3010
from gpsins_logger import superstar2 as ss2
from gpsins_logger import ubx
from .layouts import Layout, STAMP_BYTES, STAMP_MAX, STAMP_MIN, Scan, cut_header
from .stamps import StampLimits


def gather(buf: np.ndarray, offsets: np.ndarray, width: int) -> np.ndarray:
    """(n, width) uint8 rows of buf starting at offsets, without an (n, width) index array."""
    if len(buf) < width:
        return np.zeros((0, width), np.uint8)
    return np.lib.stride_tricks.sliding_window_view(buf, width)[offsets]


def _check_stamps(buf: np.ndarray, pc: np.ndarray, lay: Layout, lo: float, hi: float, good: np.ndarray
                  ) -> tuple[np.ndarray, np.ndarray]:
    """(valid, checksum-valid but with an impossible stamp) for complete candidates at pc."""
    if not lay.stamped:
        return good, np.zeros(len(good), dtype=bool)
    st = gather(buf, pc + lay.header_len, STAMP_BYTES).view("<f8").reshape(-1)
    with np.errstate(invalid="ignore"):
        plausible = np.isfinite(st) & (st > lo) & (st < hi)
    return good & plausible, good & ~plausible


def header_candidates(buf: np.ndarray, lay: Layout, lo: float = STAMP_MIN, hi: float = STAMP_MAX
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
        good = gather(buf, body, bp3010.FRAME_LEN - 2).sum(axis=1, dtype=np.uint8) == buf[end]
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
    p, length, ok, bad_stamp = header_candidates(buf, layout, lo, hi)
    vp, vl = p[ok], length[ok]
    chosen = follow_chain(vp, vl, 0)  # the greedy chain from the start
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
        tail_offset = cut_header(buf, layout, last_end, size)
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
    return Scan(path, layout, starts, lengths.astype(np.int32), stamps_at(buf, starts, layout),
                frame_bytes(buf, starts, lengths, layout), stats)


def stamps_at(buf: np.ndarray, starts: np.ndarray, lay: Layout) -> np.ndarray:
    if not lay.stamped:
        return np.full(len(starts), np.nan)
    return gather(buf, starts + lay.header_len, STAMP_BYTES).view("<f8").reshape(-1)


def frame_bytes(buf: np.ndarray, starts: np.ndarray, lengths: np.ndarray, lay: Layout) -> np.ndarray:
    """The records at starts (non-overlapping, sorted) without their stamps, back to back:
    a +1/-1 step at each record's and stamp's ends, summed, marks the bytes to keep."""
    if not len(starts):
        return np.zeros(0, np.uint8)
    if lay.device == "bp3010":  # one length: rows of the record, the stamp's columns left out
        rows = gather(buf, starts, bp3010.FRAME_LEN + lay.stamp_len)
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


def follow_chain(vp: np.ndarray, vl: np.ndarray, k: int) -> np.ndarray:
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

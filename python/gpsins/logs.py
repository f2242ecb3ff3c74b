"""Fast NumPy readers of logger sessions and raw device captures.

A record file is a sequence of ``header | f8 stamp | rest`` records
(spec/logfile.md). The scanner is vectorised: it finds every candidate
record (sync, header test, device checksum, plausible stamp) in one pass,
then follows the chain of records from the start, resynchronising at the
next valid candidate after damage, exactly as the logger's streaming finder
does on a byte stream. Python loops only over damaged places, never over
records. A truncated last record is accepted as the file's tail and reported.
Layouts: Superstar II (header SOH, ID, ~ID, N), BP3010 (sync byte) and u-blox
(header B5 62, class, id, length U2; the Fletcher checksum over class..length
and the payload, the stamp between them left out).
Stamps are checked against the session (see :func:`reject_bad_stamps`).
Damaged input of any kind reads as records plus counted damage; only a file
that cannot be read at all raises :class:`LogError`.
"""

from __future__ import annotations

import json
from dataclasses import dataclass, field
from pathlib import Path

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


SS2_RECORDS = Layout("superstar2", ss2.SOH, ss2.HEADER_LEN, True)
BP_RECORDS = Layout("bp3010", bp3010.SYNC, 1, True)
SS2_RAW = Layout("superstar2", ss2.SOH, ss2.HEADER_LEN, False)
# u-blox: header = sync B5 62, class, id, length (U2); rest = payload and CK_A CK_B. Record length = length + 16.
UBX_RECORDS = Layout("ublox", ubx.SYNC1, ubx.HEADER_LEN, True)
UBX_RAW = Layout("ublox", ubx.SYNC1, ubx.HEADER_LEN, False)
LAYOUTS = {"superstar2": SS2_RECORDS, "bp3010": BP_RECORDS, "ublox": UBX_RECORDS}


@dataclass
class Scan:
    """Accepted records of one file: offsets into `data`, lengths, stamps."""

    path: str
    layout: Layout
    data: np.ndarray  # uint8, the whole file
    starts: np.ndarray  # int64 offsets of accepted records
    lengths: np.ndarray  # int64 record lengths (stamp included for record files)
    stats: dict = field(default_factory=dict)

    @property
    def count(self) -> int:
        return len(self.starts)

    @property
    def stamps(self) -> np.ndarray:
        if not self.layout.stamped:
            return np.full(self.count, np.nan)
        return _gather(self.data, self.starts + self.layout.header_len, STAMP_BYTES).view("<f8").reshape(-1)

    def frame(self, k: int) -> bytes:
        """The device frame of record k, as the device sent it (stamp removed)."""
        s, n, h, sl = int(self.starts[k]), int(self.lengths[k]), self.layout.header_len, self.layout.stamp_len
        raw = self.data[s:s + n].tobytes()
        return raw[:h] + raw[h + sl:]

    def frames(self) -> list[bytes]:
        return [self.frame(k) for k in range(self.count)]


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
    if len(pc):
        # Running sums modulo the checksum's width: unsigned wrap-around is exact
        # here and keeps the array 1-2 bytes per input byte.
        wide = np.uint16 if lay.device == "superstar2" else np.uint8
        cs = np.zeros(size + 1, dtype=wide)
        np.cumsum(buf, dtype=wide, out=cs[1:])
        if lay.device == "superstar2":
            body = pc + ss2.HEADER_LEN + sl
            end = pc + lc - 2  # checksum position
            total = (cs[pc + ss2.HEADER_LEN] - cs[pc]) + (cs[end] - cs[body])
            want = buf[end].astype(np.int64) | buf[end + 1].astype(np.int64) << 8
            good = total.astype(np.uint16) == want
        else:
            body = pc + 1 + sl
            end = pc + lc - 1
            good = (cs[end] - cs[body]) == buf[end]
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
    # Greedy chain from the start: after a record ending at e, the next record is
    # the first valid candidate at or after e. succ[k] is that candidate's index.
    succ = np.searchsorted(vp, vp + vl)
    n = len(vp)
    irregular = np.flatnonzero(succ != np.arange(1, n + 1))
    chosen = np.zeros(n, dtype=bool)
    k = 0
    while k < n:
        j = np.searchsorted(irregular, k)
        if j == len(irregular):
            chosen[k:] = True
            break
        stop = irregular[j]
        chosen[k:stop + 1] = True
        k = succ[stop]
    starts, lengths = vp[chosen], vl[chosen]
    # The tail: the first incomplete header-valid candidate after the last
    # accepted record. An incomplete candidate earlier than that was a false
    # header (whole records follow it), as the streaming finder decides at flush.
    tail_offset = None
    last_end = int(starts[-1] + lengths[-1]) if len(starts) else 0
    inc = p[(p + length > size) & (p >= last_end)]
    if len(inc):
        tail_offset = int(inc[0])
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
    return Scan(path, layout, buf, starts, lengths, stats)


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


def reject_bad_stamps(s: Scan, limits: StampLimits) -> Scan:
    """Drop records whose stamp is impossible (outside the session, or out of
    line with both its neighbours), count them, keep their neighbours."""
    if not s.layout.stamped or not s.count:
        return s
    st = s.stamps
    bad = ~((st >= limits.lo) & (st <= limits.hi))
    # Neighbour test on the records left: a stamp is damaged when it runs back
    # from the previous record or ahead of the next by more than a clock step,
    # while those two agree with each other. Repeat so a damaged record does
    # not hide its neighbour's damage; each pass only removes records.
    for _ in range(8):
        keep = np.flatnonzero(~bad)
        if len(keep) < 2:
            break
        t = st[keep]
        prev = np.concatenate(([-np.inf], t[:-1]))
        nxt = np.concatenate((t[1:], [np.inf]))
        back_from_prev = t < prev - limits.back_s
        ahead_of_next = t > nxt + limits.back_s
        agree = nxt >= prev - limits.back_s
        # The ends have one neighbour: it must agree with its own other neighbour.
        if len(t) >= 3:
            agree[0] = t[2] >= t[1] - limits.back_s
            agree[-1] = t[-2] >= t[-3] - limits.back_s
        else:
            agree[:] = False
        out = (back_from_prev | ahead_of_next) & agree
        if not out.any():
            break
        bad[keep[out]] = True
    n_bad = int(np.count_nonzero(bad))
    if n_bad:
        s.stats["bad_stamps"] += n_bad
        first = int(s.starts[np.argmax(bad)])
        old = s.stats["first_bad_stamp_offset"]
        s.stats["first_bad_stamp_offset"] = first if old is None else min(old, first)
        s.stats["discarded_bytes"] += int(s.lengths[bad].sum())
        s.stats["records"] -= n_bad
        s.starts, s.lengths = s.starts[~bad], s.lengths[~bad]
    return s


def read_record_file(path: str | Path, device: str, limits: StampLimits | None = None) -> Scan:
    path = Path(path)
    if device not in LAYOUTS:
        raise LogError(f"{path}: unknown device {device!r} (known: {', '.join(LAYOUTS)})")
    try:
        buf = np.fromfile(path, dtype=np.uint8)
    except OSError as e:
        raise LogError(f"{path}: cannot read: {e.strerror}") from None
    limits = limits or StampLimits()
    out = reject_bad_stamps(scan(buf, LAYOUTS[device], str(path), limits), limits)
    st = out.stamps
    back = np.flatnonzero(np.diff(st) < 0)
    out.stats["stamps_backwards"] = int(len(back))
    out.stats["first_backwards_offset"] = int(out.starts[back[0] + 1]) if len(back) else None
    return out


def message_ids(s: Scan) -> np.ndarray:
    """Superstar II message ID of every record."""
    return s.data[s.starts + 1] & 0x7F


def ubx_class_ids(s: Scan) -> np.ndarray:
    """(n, 2) UBX class and id of every record."""
    return np.column_stack([s.data[s.starts + 2], s.data[s.starts + 3]])


# --- BP3010 -----------------------------------------------------------------------


@dataclass
class ImuLog:
    stamps: np.ndarray  # (n,) system time of each frame's first byte
    dtheta_rad: np.ndarray  # (n, 3)
    dv_mps: np.ndarray  # (n, 3)
    status: np.ndarray  # (n,) uint8
    counter: np.ndarray  # (n,) uint8
    rate_hz: int

    def __len__(self) -> int:
        return len(self.stamps)


def imu_log(s: Scan, rate_hz: int = bp3010.NOMINAL_RATE_HZ) -> ImuLog:
    body = s.starts + (1 + s.layout.stamp_len)
    raw = _gather(s.data, body, 14)
    counts = raw[:, :12].copy().view("<i2").astype(np.float64)
    return ImuLog(s.stamps, counts[:, 0:3] * bp3010.dtheta_lsb_rad(rate_hz), counts[:, 3:6] * bp3010.dv_lsb_mps(rate_hz),
                  raw[:, 12].copy(), raw[:, 13].copy(), rate_hz)


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

    def stats(self) -> dict:
        keys = ("records", "bytes", "discarded_bytes", "truncated_tail_bytes", "resyncs", "bad_stamps",
                "stamps_backwards")
        return {k: sum(s.stats[k] for s in self.scans) for k in keys}


@dataclass
class SessionLog:
    directory: Path
    sidecar: dict
    sensors: dict[str, SensorFiles]

    def imu(self) -> ImuLog:
        files = self.sensors["imu"]
        rate = int(self.sidecar["sensors"]["imu"].get("rate_hz", bp3010.NOMINAL_RATE_HZ))
        parts = [imu_log(s, rate) for s in files.scans]
        return ImuLog(*(np.concatenate([getattr(p, f) for p in parts]) for f in
                        ("stamps", "dtheta_rad", "dv_mps", "status", "counter")), rate)


def read_session(directory: str | Path) -> SessionLog:
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
        scans = []
        for fname in info.get("files", []):
            path = directory / fname
            if path.exists():
                scans.append(read_record_file(path, info["device"], limits))
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

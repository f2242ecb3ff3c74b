"""Seeded byte corpora of both devices for framing tests."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from gpsins.devices.sources import StaticSource
from gpsins_logger.recorder import CLOCK_STEP_THRESHOLD_S


def ss2_frames(seconds: float = 20.0, seed: int = 0) -> list[bytes]:
    return [m.frame for m in StaticSource(seconds, seed=seed).gps_messages()]


def bp_frames(n: int = 2000, seed: int = 0) -> list[bytes]:
    out = []
    for k, s in enumerate(StaticSource(n / 64 + 1, seed=seed).imu_samples(64)):
        if k == n:
            break
        s.sample.counter = k & 0xFF
        out.append(s.sample.encode(64))
    return out


def faulted_stream(frames: list[bytes], rng: np.random.Generator, p_flip: float, p_garbage: float,
                   garbage_max: int = 30, p_truncate: float = 0.0, p_drop: float = 0.0) -> tuple[bytes, list[bool]]:
    """Concatenate frames with one random bit flipped in some, garbage inserted
    before others, some cut short (at least 2 bytes, as the emulator does) and
    some dropped; returns the stream and which frames are intact on it."""
    out = bytearray()
    intact = []
    for f in frames:
        if rng.random() < p_garbage:
            out += rng.integers(0, 256, int(rng.integers(1, garbage_max + 1)), dtype=np.uint8).tobytes()
        if p_drop and rng.random() < p_drop:
            intact.append(False)
        elif p_truncate and rng.random() < p_truncate:
            out += f[:int(rng.integers(1, len(f) - 1))]
            intact.append(False)
        elif rng.random() < p_flip:
            b = bytearray(f)
            bit = int(rng.integers(0, 8 * len(f)))
            b[bit // 8] ^= 1 << (bit % 8)
            out += b
            intact.append(False)
        else:
            out += f
            intact.append(True)
    return bytes(out), intact


# --- record files and mutations (fuzzing) ------------------------------------------------------------

STAMP_T0 = 1.7e9


def record_file(frames: list[bytes], header_len: int, dt: float, t0: float = STAMP_T0) -> tuple[bytes, list[bytes]]:
    """A logger record file: header | f8 stamp | rest per frame, stamps t0 + k dt."""
    recs = [f[:header_len] + np.float64(t0 + k * dt).astype("<f8").tobytes() + f[header_len:]
            for k, f in enumerate(frames)]
    return b"".join(recs), recs


MUTATIONS = ("flip", "insert", "delete", "truncate", "splice")


def mutate(data: bytes, rng: np.random.Generator, n_mutations: int = 3) -> tuple[bytes, np.ndarray, list[str]]:
    """Apply 1..n_mutations random mutations (bit flips, insertions of random
    bytes, deletions, a truncation, splices of another stretch of the file).
    Returns the bytes, the original index of every byte (-1: not an original
    byte in its original state) and the kinds applied."""
    buf = np.frombuffer(data, np.uint8).copy()
    origin = np.arange(len(buf), dtype=np.int64)
    kinds = []
    for _ in range(int(rng.integers(1, n_mutations + 1))):
        kind = MUTATIONS[int(rng.integers(len(MUTATIONS)))]
        kinds.append(kind)
        size = len(buf)
        if size == 0:
            break
        p = int(rng.integers(0, size))
        if kind == "flip":
            for _ in range(int(rng.integers(1, 4))):
                q = min(size - 1, p + int(rng.integers(0, 8)))
                buf[q] ^= np.uint8(1 << int(rng.integers(8)))
                origin[q] = -1
        elif kind == "insert":
            k = int(rng.integers(1, 40))
            buf = np.insert(buf, p, rng.integers(0, 256, k, dtype=np.uint8))
            origin = np.insert(origin, p, np.full(k, -1))
        elif kind == "delete":
            k = int(rng.integers(1, 40))
            buf, origin = np.delete(buf, np.s_[p:p + k]), np.delete(origin, np.s_[p:p + k])
        elif kind == "truncate":
            buf, origin = buf[:p], origin[:p]
        else:  # splice: a stretch of the file copied over another place (a torn or reordered write)
            k = int(rng.integers(1, 200))
            src = int(rng.integers(0, size))
            piece = buf[src:src + k].copy()
            end = min(size, p + int(rng.integers(0, 200)))
            buf = np.concatenate((buf[:p], piece, buf[end:]))
            origin = np.concatenate((origin[:p], np.full(len(piece), -1), origin[end:]))
    return buf.tobytes(), origin, kinds


def intact_records(recs: list[bytes], origin: np.ndarray, size: int) -> np.ndarray:
    """Which original records survive a mutation byte for byte and in one piece."""
    where = np.full(size, -1, dtype=np.int64)
    kept = origin >= 0
    where[origin[kept]] = np.flatnonzero(kept)
    ends = np.cumsum([len(r) for r in recs])
    starts = ends - np.array([len(r) for r in recs])
    ok = np.zeros(len(recs), dtype=bool)
    for k, (a, b) in enumerate(zip(starts, ends)):
        w = where[a:b]
        ok[k] = bool(np.all(w >= 0)) and int(w[-1] - w[0]) == b - a - 1
    return ok


@dataclass
class FuzzTally:
    cases: int = 0
    crashes: int = 0
    intact: int = 0  # original records/frames left intact by the mutations
    intact_lost: int = 0
    damaged_accepted: int = 0  # device bytes not those of any original frame
    stamp_changed_accepted: int = 0  # device bytes intact, stamp changed by a flip
    worst_stamp_error_over_gap: float = 0.0  # |stamp error| / (neighbour gap + clock step); <= 1 by design
    first_crash: str = ""

    def add(self, other: "FuzzTally") -> None:
        for k, v in other.__dict__.items():
            if k == "worst_stamp_error_over_gap":
                self.worst_stamp_error_over_gap = max(self.worst_stamp_error_over_gap, v)
            elif k == "first_crash":
                self.first_crash = self.first_crash or v
            else:
                setattr(self, k, getattr(self, k) + v)


class Corpus:
    """One device's frames as a record file and as a raw stream, with what the checks need."""

    def __init__(self, device: str, frames: list[bytes], header_len: int, dt: float):
        self.device, self.frames, self.header_len, self.dt = device, frames, header_len, dt
        self.records_bytes, self.recs = record_file(frames, header_len, dt)
        self.raw = b"".join(frames)
        self.frame_set = set(frames)
        self.record_set = set(self.recs)
        self.stamps_of: dict[bytes, list[float]] = {}
        for k, f in enumerate(frames):  # a static receiver repeats some frames byte for byte
            self.stamps_of.setdefault(f, []).append(STAMP_T0 + k * dt)


def fuzz_reader_case(c: Corpus, rng: np.random.Generator) -> FuzzTally:
    from gpsins.session import stamps as stamps_mod
    from gpsins.session import scan as log_scan
    from gpsins.session import layouts

    t = FuzzTally(cases=1)
    data, origin, kinds = mutate(c.records_bytes, rng)
    ok = intact_records(c.recs, origin, len(c.records_bytes))
    t.intact = int(ok.sum())
    limits = stamps_mod.StampLimits(STAMP_T0 - 2.0, STAMP_T0 + len(c.frames) * c.dt + 2.0, CLOCK_STEP_THRESHOLD_S)
    try:
        s = stamps_mod.reject_bad_stamps(log_scan.scan(data, layouts.LAYOUTS[c.device], limits=limits), limits)
        frames, stamps = s.frames(), s.stamps
        assert s.stats["records"] == s.count
    except Exception as e:  # noqa: BLE001 - the point is to catch anything
        t.crashes = 1
        t.first_crash = f"{c.device} reader {kinds}: {type(e).__name__}: {e}"
        return t
    got = set()
    for k, (f, st) in enumerate(zip(frames, stamps)):
        if f not in c.frame_set:
            t.damaged_accepted += 1
            continue
        rec = s.record(k)
        got.add(rec)
        if rec not in c.record_set:
            t.stamp_changed_accepted += 1
            # A changed stamp the reader keeps lies within a neighbour's gap plus a clock step.
            err = min(abs(st - x) for x in c.stamps_of[f])
            t.worst_stamp_error_over_gap = max(t.worst_stamp_error_over_gap,
                                               err / (c.dt + CLOCK_STEP_THRESHOLD_S))
    t.intact_lost = sum(1 for k in np.flatnonzero(ok) if c.recs[k] not in got)
    return t


def fuzz_finder_case(c: Corpus, rng: np.random.Generator) -> FuzzTally:
    from gpsins_logger import bp3010, superstar2
    from gpsins_logger.framing import FrameFinder

    t = FuzzTally(cases=1)
    data, origin, kinds = mutate(c.raw, rng)
    ok = intact_records(c.frames, origin, len(c.raw))
    t.intact = int(ok.sum())
    rule = superstar2.FRAMING if c.device == "superstar2" else bp3010.FRAMING
    try:
        finder = FrameFinder(rule)
        cuts = np.sort(rng.integers(0, len(data) + 1, int(rng.integers(0, 8))))
        found, last = [], 0
        for cut in [*cuts.tolist(), len(data)]:
            found += finder.feed(data[last:cut])
            last = cut
        found += finder.flush()
        st = finder.stats
        assert st.discarded_bytes + st.tail_bytes + sum(len(f.data) for f in found) == len(data)
    except Exception as e:  # noqa: BLE001
        t.crashes = 1
        t.first_crash = f"{c.device} finder {kinds}: {type(e).__name__}: {e}"
        return t
    got = {f.data for f in found}
    t.damaged_accepted = sum(1 for f in found if f.data not in c.frame_set)
    t.intact_lost = sum(1 for k in np.flatnonzero(ok) if c.frames[k] not in got)
    return t

"""Streaming frame finder: bytes in any chunking in, whole checked frames out.

A device describes its framing with a :class:`FrameRule` (sync byte, header
test, frame length, checksum, and optionally a frame counter); the finder
knows nothing else about any device.

Two hunting policies, chosen by the rule:

- Without a counter (Superstar II: 3-byte sync, 16-bit sum) a candidate is a
  frame when its checksum passes. After a failed checksum hunting restarts at
  the byte after the false sync, so a real header hidden inside a false
  frame is not lost.
- With a counter (BP3010: 1-byte sync, 8-bit sum, which a false sync passes
  about once in 256 tries) a candidate found while hunting is accepted only
  when its counter continues the last accepted frame's within MAX_GAP frames,
  or when a valid frame within the next MAX_GAP frames' worth of bytes
  continues its counter. When damage on both sides leaves no such frame
  near (truncated frames before and after an intact one), it is taken when
  its counter continues the last accepted frame's, a frame starts right
  after it and a valid frame ahead continues its counter. Once locked, a
  frame that fails is dropped alone if the frame after it is where the lock
  expects it.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import NamedTuple, Protocol


class Frame(NamedTuple):
    offset: int  # stream offset of the frame's first byte (bytes fed before it)
    data: bytes


class FrameRule(Protocol):
    name: str
    sync: int  # first byte of every frame
    header_len: int  # bytes needed before header_ok and frame_len can be asked
    has_counter: bool
    fixed_len: int  # frame length of counter rules (0 for variable-length frames)

    def header_ok(self, buf: bytearray, i: int) -> bool: ...
    def frame_len(self, buf: bytearray, i: int) -> int: ...
    def checksum_ok(self, buf: bytearray, i: int, n: int) -> bool: ...
    # Counter rules only: frames from `prev` to the frame at buf[j] by their
    # counters (1 = the next frame), modulo the counter's range. Needs the
    # bytes up to counter_end(j).
    def counter_gap(self, prev: bytes, buf: bytearray, j: int) -> int: ...
    def counter_end(self, j: int) -> int: ...


# Counter rules: how many frames a confirmation may skip (faulted frames in a
# row), and how many bytes ahead a forward confirmation may look per frame.
MAX_GAP = 8
LOOKAHEAD_BYTES_PER_FRAME = 64


@dataclass
class FinderStats:
    frames: int = 0
    bytes_in: int = 0
    discarded_bytes: int = 0  # bytes that were not part of an accepted frame
    checksum_failures: int = 0
    lock_losses: int = 0
    tail_bytes: int = 0  # a truncated last frame left at flush()
    tail_offset: int | None = None

    def as_dict(self) -> dict[str, int | None]:
        return dict(self.__dict__)


@dataclass
class FrameFinder:
    rule: FrameRule
    stats: FinderStats = field(default_factory=FinderStats)

    def __post_init__(self) -> None:
        self._buf = bytearray()
        self._base = 0  # stream offset of _buf[0]
        self._locked = False
        self._last: bytes | None = None  # last accepted frame (counter rules)
        self._tail_start: int | None = None  # flush(): first incomplete candidate after the last frame

    @property
    def pending(self) -> int:
        """Bytes held back waiting for more input (a partial frame)."""
        return len(self._buf)

    def feed(self, data: bytes) -> list[Frame]:
        self._buf += data
        self.stats.bytes_in += len(data)
        out: list[Frame] = []
        i = self._scan(out, final=False)
        del self._buf[:i]
        self._base += i
        return out

    def flush(self) -> list[Frame]:
        """End of stream: decide what can still be decided. A candidate whose
        declared length runs past the end is skipped like a false sync, so
        whole frames inside its span are still found; the bytes from the first
        such candidate after the last frame are the truncated tail (reported
        as the tail, not as discarded bytes)."""
        out: list[Frame] = []
        self._tail_start: int | None = None
        i = self._scan(out, final=True)
        tail_start = self._tail_start if self._tail_start is not None else i
        self.stats.tail_bytes = len(self._buf) - tail_start
        # The hunt counted the tail's bytes as discarded; they are the tail.
        self.stats.discarded_bytes -= i - tail_start
        self.stats.tail_offset = self._base + tail_start if self.stats.tail_bytes else None
        self._base += len(self._buf)
        del self._buf[:]
        return out

    def _discard(self, n: int) -> None:
        self.stats.discarded_bytes += n

    def _emit(self, out: list[Frame], i: int, n: int) -> None:
        frame = bytes(self._buf[i:i + n])
        out.append(Frame(self._base + i, frame))
        self._last = frame
        self.stats.frames += 1
        self._tail_start = None

    def _scan(self, out: list[Frame], final: bool) -> int:
        buf, rule = self._buf, self.rule
        i, size = 0, len(buf)
        while True:
            if not self._locked:
                j = buf.find(rule.sync, i)
                if j < 0:
                    self._discard(size - i)
                    return size
                self._discard(j - i)
                i = j
            if size - i < rule.header_len:
                return i
            n = rule.frame_len(buf, i) if rule.header_ok(buf, i) else 0
            if n and size - i < n:
                if not final:
                    return i
                if self._tail_start is None:
                    self._tail_start = i
                self._discard(1)
                i += 1
                continue
            good = n > 0 and rule.checksum_ok(buf, i, n)
            # A complete frame with a valid header whose checksum fails: counted
            # once, where the finder decides what to do with it.
            failed = n > 0 and not good
            if not rule.has_counter:
                if good:
                    self._emit(out, i, n)
                    i += n
                else:
                    self.stats.checksum_failures += failed
                    self._discard(1)
                    i += 1
                continue

            if self._locked:
                # Locked, a frame must also continue the counter (frames lost
                # on the line allowed): an 8-bit sum alone lets garbage that
                # starts with the sync through once in 256 times.
                if good and 1 <= rule.counter_gap(self._last, buf, i) <= MAX_GAP:
                    self._emit(out, i, n)
                    i += n
                    continue
                # A damaged frame while locked: drop just it when the next
                # frame sits where the lock expects it, with its counter.
                m = rule.fixed_len
                need = rule.counter_end(i + m)
                if size < need and not final:
                    return i
                self.stats.checksum_failures += failed
                if size >= need and buf[i + m] == rule.sync and self._last is not None and \
                        rule.counter_gap(self._last, buf, i + m) == 2:
                    self._discard(m)
                    i += m
                    continue
                self._locked = False
                self.stats.lock_losses += 1
                self._discard(1)
                i += 1
                continue

            # Hunting with a counter rule.
            if not good:
                self.stats.checksum_failures += failed
                self._discard(1)
                i += 1
                continue
            verdict = self._confirm(i, n, final)
            if verdict is None:
                return i
            if verdict:
                self._locked = True
                self._emit(out, i, n)
                i += n
            else:
                self._discard(1)
                i += 1

    def _confirm(self, i: int, n: int, final: bool) -> bool | None:
        """May the checksum-valid candidate at i be taken while hunting?
        None: not enough bytes yet to tell.

        Evidence points: its counter is the next after the last accepted
        frame's; the frame right after it has the sync and the next counter.
        With a point it is taken, unless a candidate overlapping it has more.
        With none (several damaged frames in a row), it is taken when its
        counter lies between the last accepted frame's and that of the next
        anchored frame ahead (a valid frame whose own successor follows it),
        and no overlapping candidate has a point."""
        score = self._score(i, n, final)
        if score is None:
            return None
        if score == 0:
            between = self._between(i, n, final)
            if between is False:
                between = self._bridged(i, n, final)
            if not between:
                return between
        buf, rule = self._buf, self.rule
        j = i + 1
        while True:
            j = buf.find(rule.sync, j, i + n)
            if j < 0:
                return True
            if j + n > len(buf):
                return None if not final else True
            if rule.checksum_ok(buf, j, n):
                other = self._score(j, n, final)
                if other is None:
                    return None
                if other > score:
                    return False
            j += 1

    def _score(self, i: int, n: int, final: bool) -> int | None:
        buf, rule = self._buf, self.rule
        back = int(self._last is not None and rule.counter_gap(self._last, buf, i) == 1)
        if len(buf) < rule.counter_end(i + n):
            return None if not final else back
        return back + int(self._anchored(i, n))

    def _anchored(self, j: int, n: int) -> bool:
        """The frame right after j has the sync and the next counter."""
        buf, rule = self._buf, self.rule
        return buf[j + n] == rule.sync and rule.counter_gap(bytes(buf[j:j + n]), buf, j + n) == 1

    def _bridged(self, i: int, n: int, final: bool) -> bool | None:
        """Damage on both sides (e.g. truncated frames before and after it),
        so no anchored frame is near: taken when its counter continues the
        last accepted frame's (if any), a frame starts right after it, and a
        valid frame ahead continues its counter. Garbage passes all three about once
        in 256 * 256 * 256 / 7^2 sync bytes."""
        buf, rule = self._buf, self.rule
        if self._last is not None and not 2 <= rule.counter_gap(self._last, buf, i) <= MAX_GAP:
            return False
        if len(buf) <= i + n:
            return False if final else None
        if buf[i + n] != rule.sync:
            return False
        candidate = bytes(buf[i:i + n])
        window_end = i + n + MAX_GAP * LOOKAHEAD_BYTES_PER_FRAME
        j = i + n
        while True:
            j = buf.find(rule.sync, j, window_end)
            if j < 0:
                return False if final or len(buf) >= window_end + n else None
            if j + n > len(buf):
                return False if final else None
            if rule.checksum_ok(buf, j, n):
                if self._continues_last(j):
                    return False
                if 1 <= rule.counter_gap(candidate, buf, j) <= MAX_GAP:
                    return True
            j += 1

    def _continues_last(self, j: int) -> bool:
        """Whether the valid frame at j has the counter next after the last accepted frame's: that frame, not
        a candidate before it without such evidence, comes next (a garbage frame taken there lost it)."""
        return self._last is not None and self.rule.counter_gap(self._last, self._buf, j) == 1

    def _between(self, i: int, n: int, final: bool) -> bool | None:
        buf, rule = self._buf, self.rule
        gap_back = rule.counter_gap(self._last, buf, i) if self._last is not None else None
        if gap_back is not None and not 2 <= gap_back <= MAX_GAP:
            return False
        # At the end of the stream there may be no frame ahead: then the
        # evidence from the last accepted frame has to do.
        ended = gap_back is not None
        candidate = bytes(buf[i:i + n])
        window_end = i + n + MAX_GAP * LOOKAHEAD_BYTES_PER_FRAME
        j = i + n
        while True:
            j = buf.find(rule.sync, j, window_end)
            if j < 0:
                if len(buf) < window_end + n:
                    return ended if final else None
                return False
            if rule.counter_end(j + n) > len(buf):
                return ended if final else None
            if rule.checksum_ok(buf, j, n):
                if self._continues_last(j):
                    return False
                if self._anchored(j, n):
                    ahead = rule.counter_gap(candidate, buf, j)
                    if not 1 <= ahead <= MAX_GAP:
                        return False
                    return gap_back is None or 1 <= rule.counter_gap(self._last, buf, j) - gap_back <= MAX_GAP
            j += 1

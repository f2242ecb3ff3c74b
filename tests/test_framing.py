"""Streaming frame finder: chunking invariance, fault tolerance, agreement with the NumPy scanner."""

import numpy as np
from hypothesis import example, given, settings
from hypothesis import strategies as st

from corpora import bp_frames, faulted_stream, ss2_frames
from gpsins.session import scan as log_scan
from gpsins.session import layouts
from gpsins_logger import bp3010
from gpsins_logger import superstar2 as ss2
from gpsins_logger.framing import FrameFinder

SS2 = ss2_frames(20.0)
BP = bp_frames(1500)


def find_all(rule, data: bytes, cuts=()):
    finder = FrameFinder(rule)
    out, last = [], 0
    for c in sorted(cuts) + [len(data)]:
        out += finder.feed(data[last:c])
        last = c
    out += finder.flush()
    return out, finder.stats


@settings(max_examples=60, deadline=None)
@given(st.lists(st.integers(0, 10**6), max_size=40), st.integers(0, 2**32 - 1))
def test_chunking_never_changes_what_is_found(cut_seeds, seed):
    rng = np.random.default_rng(seed)
    for rule, frames in ((ss2.FRAMING, SS2), (bp3010.FRAMING, BP)):
        data, _ = faulted_stream(frames, rng, p_flip=0.05, p_garbage=0.05)
        cuts = [c % (len(data) + 1) for c in cut_seeds]
        whole, s1 = find_all(rule, data)
        chunked, s2 = find_all(rule, data, cuts)
        assert whole == chunked
        assert s1 == s2


def check_no_loss(rule, frames, seed, p_flip, p_garbage):
    rng = np.random.default_rng(seed)
    data, intact = faulted_stream(frames, rng, p_flip, p_garbage)
    found, stats = find_all(rule, data)
    found_set = [f.data for f in found]
    want = [f for f, ok in zip(frames, intact) if ok]
    # Every intact frame is found, in order; nothing else is (no false accepts).
    assert found_set == want, f"seed {seed}: {len(want)} intact, {len(found_set)} found"
    # Every byte is a found frame's, discarded, or the tail: a last candidate whose declared length
    # runs past the end (here a damaged frame near the end, which looks exactly like a cut one).
    assert stats.discarded_bytes + stats.tail_bytes + sum(map(len, want)) == len(data)
    return stats


@settings(max_examples=40, deadline=None)
@given(st.integers(0, 2**32 - 1))
@example(seed=260)  # a damaged frame near the end claims more bytes than are left: the tail
def test_flips_and_garbage_never_lose_an_intact_superstar2_frame(seed):
    check_no_loss(ss2.FRAMING, SS2, seed, p_flip=0.1, p_garbage=0.1)


@settings(max_examples=40, deadline=None)
@given(st.integers(0, 2**32 - 1))
# Garbage with a valid sum and counter 175 between frames 173 and 176 was taken while hunting, and lost the
# intact 174 after it (found by this test beside the suite under load).
@example(seed=34898)
def test_flips_and_garbage_never_lose_an_intact_bp3010_frame(seed):
    check_no_loss(bp3010.FRAMING, BP, seed, p_flip=0.1, p_garbage=0.1)


def test_false_accepts_are_zero_on_seeded_heavy_corpora():
    # Half the frames damaged: everything found must be a sent intact frame, in order.
    lost = total = 0
    for seed in range(20):
        check_no_loss(ss2.FRAMING, SS2, seed, p_flip=0.3, p_garbage=0.3)
        rng = np.random.default_rng(seed)
        data, intact = faulted_stream(BP, rng, 0.3, 0.3)
        found = [f.data for f in find_all(bp3010.FRAMING, data)[0]]
        want = [f for f, ok in zip(BP, intact) if ok]
        it = iter(want)
        assert all(any(f == w for w in it) for f in found), f"seed {seed}: a frame was falsely accepted"
        lost += len(want) - len(found)
        total += len(want)
    # The 8-bit sum's hunting loses an intact frame only after long runs of damage.
    assert lost / total < 0.005


def test_real_header_inside_a_false_frame_is_found():
    real = ss2.NavEcef(1.0, 2, 3.0, 4.0, 5.0, 0.0, 0.0, 0.0).encode()
    # A false header claiming 200 bytes of payload swallows the real frame.
    data = bytes([1, 7, 7 ^ 0xFF, 200]) + real + bytes(250)
    found, stats = find_all(ss2.FRAMING, data)
    assert [f.data for f in found] == [real]
    assert stats.checksum_failures == 1


def test_bp3010_hunting_needs_confirmation():
    frames = BP[:10]
    # A lone false sync with a valid checksum is not a frame unless a frame follows it.
    fake = bytearray(16)
    fake[0] = 0xA5
    fake[15] = sum(fake[1:15]) & 0xFF
    data = bytes(fake) + b"\x00" + b"".join(frames)
    found, _ = find_all(bp3010.FRAMING, data)
    assert [f.data for f in found] == frames


def test_dropped_frames_keep_the_lock():
    frames = BP[:50]
    data = b"".join(f for k, f in enumerate(frames) if k % 7 != 3)
    found, stats = find_all(bp3010.FRAMING, data)
    assert len(found) == 50 - len([k for k in range(50) if k % 7 == 3])
    assert stats.discarded_bytes == 0


@settings(max_examples=40, deadline=None)
@given(st.integers(0, 2**32 - 1))
@example(seed=120678)  # ends in SOH and one more byte: a header cut by the end is the tail
def test_numpy_scanner_agrees_with_the_streaming_finder_on_raw_superstar2(seed):
    rng = np.random.default_rng(seed)
    data, _ = faulted_stream(SS2, rng, p_flip=0.1, p_garbage=0.1)
    data = data[:len(data) - int(rng.integers(0, 100))]  # cut the tail anywhere
    found, stats = find_all(ss2.FRAMING, data)
    s = log_scan.scan(data, layouts.SS2_RAW)
    assert s.frames() == [f.data for f in found]
    assert s.stats["discarded_bytes"] == stats.discarded_bytes
    assert s.stats["truncated_tail_bytes"] == stats.tail_bytes


def test_truncations_and_drops_together_keep_intact_bp3010_frames():
    """10 % truncated plus 5 % dropped frames: an intact frame between two truncated ones has no anchored frame
    near it. It used to be lost in about 11 of 1000 seeds of 600 frames (13 frames); bench: 1000 seeds now lose
    1 frame, displaced by the one false accept."""
    lost = false = 0
    frames = BP[:600]
    for seed in range(150):
        rng = np.random.default_rng(seed)
        data, intact = faulted_stream(frames, rng, 0.0, 0.0, p_truncate=0.10, p_drop=0.05)
        found = [f.data for f in find_all(bp3010.FRAMING, data)[0]]
        want = [f for f, ok in zip(frames, intact) if ok]
        false += len(set(found) - set(want))
        lost += len(set(want) - set(found))
    assert lost == 0 and false == 0

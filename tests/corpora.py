"""Seeded byte corpora of both devices for framing tests."""

from __future__ import annotations

import numpy as np

from gpsins.sources import StaticSource


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
                   garbage_max: int = 30) -> tuple[bytes, list[bool]]:
    """Concatenate frames with one random bit flipped in some and garbage inserted
    before others; returns the stream and which frames are intact."""
    out = bytearray()
    intact = []
    for f in frames:
        if rng.random() < p_garbage:
            out += rng.integers(0, 256, int(rng.integers(1, garbage_max + 1)), dtype=np.uint8).tobytes()
        if rng.random() < p_flip:
            b = bytearray(f)
            bit = int(rng.integers(0, 8 * len(f)))
            b[bit // 8] ^= 1 << (bit % 8)
            out += b
            intact.append(False)
        else:
            out += f
            intact.append(True)
    return bytes(out), intact

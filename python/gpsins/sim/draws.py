"""Random numbers addressed by their place in a stream, so a simulation run in
blocks draws exactly what it draws in one piece.

A stream is a key (the seed and the stream's own numbers) and a distribution;
its rows are cut into fixed atoms of ``ATOM`` rows, each drawn from its own
generator seeded with (key, atom index). Row i is therefore the same whatever
block asks for it, and a block never needs more than the atoms it touches.
"""

from __future__ import annotations

import numpy as np

ATOM = 4096  # rows per independently seeded piece of a stream


class Stream:
    """Rows of one distribution, ``rows(i0, i1)`` of shape (i1 - i0, width) (or (i1 - i0,) for width None)."""

    def __init__(self, key: tuple[int, ...], kind: str = "normal", width: int | None = None, atom: int = ATOM,
                 cache: bool = True):
        if kind not in ("normal", "uniform", "exponential"):
            raise ValueError(f"unknown distribution {kind!r}")
        self.key, self.kind, self.width = tuple(int(k) for k in key), kind, width
        self.atom, self.cache = int(atom), cache  # cache: keep the last atom (for streams read in order)
        self._cached: tuple[int, np.ndarray] | None = None

    def _atom(self, a: int) -> np.ndarray:
        if self._cached is not None and self._cached[0] == a:
            return self._cached[1]
        g = np.random.Generator(np.random.PCG64(np.random.SeedSequence([*self.key, a])))
        shape = (self.atom,) if self.width is None else (self.atom, self.width)
        x = getattr(g, "standard_" + self.kind)(shape) if self.kind != "uniform" else g.random(shape)
        if self.cache:
            self._cached = (a, x)
        return x

    def rows(self, i0: int, i1: int) -> np.ndarray:
        if i1 <= i0:
            return np.empty((0,) if self.width is None else (0, self.width))
        parts, size = [], self.atom
        for a in range(i0 // size, (i1 - 1) // size + 1):
            lo, hi = max(i0, a * size) - a * size, min(i1, (a + 1) * size) - a * size
            parts.append(self._atom(a)[lo:hi])
        return parts[0].copy() if len(parts) == 1 else np.concatenate(parts)


class Sequential:
    """The same interface over one generator drawn in call order (for one-piece runs such as the IMU lab)."""

    def __init__(self, rng: np.random.Generator, width: int | None = None):
        self.rng, self.width = rng, width

    def rows(self, i0: int, i1: int) -> np.ndarray:
        return self.rng.normal(0.0, 1.0, (i1 - i0,) if self.width is None else (i1 - i0, self.width))

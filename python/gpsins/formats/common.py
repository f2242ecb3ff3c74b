"""What every reader shares: the error type, GPS time helpers and the decoded containers.

Times are GPS seconds since the GPS epoch (1980-01-06 00:00 GPST), "t_abs", as the C++
core takes them. Positions are ECEF metres; sigmas are 1-sigma standard deviations.
"""

from __future__ import annotations

import gzip
from collections import Counter
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np


class ReaderError(ValueError):
    """Input that cannot be read: names the file, the byte offset or line, and the field."""

    def __init__(self, path, message: str, *, offset: int | None = None, line: int | None = None,
                 field: str | None = None):
        self.path, self.offset, self.line, self.field = str(path), offset, line, field
        where = self.path
        if line is not None:
            where += f":{line}"
        if offset is not None:
            where += f" (offset {offset})"
        super().__init__(f"{where}: {field + ': ' if field else ''}{message}")


@dataclass
class Fixes:
    """Position (and velocity) solutions with their own standard deviations, in time order.

    q follows RTKLIB: 1 fix, 2 float, 3 SBAS, 4 DGPS, 5 single, 6 PPP (0: unknown).
    sigma_ned_m / sigma_v_ned_mps are as the source states them (they may be zero: the
    user of the fixes applies floors); NaN where the source has none. ``skipped`` counts the rows the reader
    left out (a value written as nan or inf, ...), by reason.
    """

    t_abs: np.ndarray  # (n,)
    r_ecef: np.ndarray  # (n, 3)
    sigma_ned_m: np.ndarray  # (n, 3) north, east, down
    q: np.ndarray  # (n,) int
    ns: np.ndarray  # (n,) satellites, 0 when unknown
    v_ned_mps: np.ndarray | None = None  # (n, 3), NaN rows where absent
    sigma_v_ned_mps: np.ndarray | None = None  # (n, 3)
    source: str = ""
    skipped: Counter = field(default_factory=Counter)

    def __len__(self) -> int:
        return len(self.t_abs)

    def select(self, keep: np.ndarray) -> "Fixes":
        pick = (lambda a: None if a is None else a[keep])
        return Fixes(self.t_abs[keep], self.r_ecef[keep], self.sigma_ned_m[keep], self.q[keep], self.ns[keep],
                     pick(self.v_ned_mps), pick(self.sigma_v_ned_mps), self.source, Counter(self.skipped))

    def llh(self) -> np.ndarray:
        from .. import _core
        return _core.ecef_to_geodetic(self.r_ecef) if len(self) else np.zeros((0, 3))

    def v_ecef(self) -> np.ndarray:
        """Velocity in ECEF (NaN where the source has none)."""
        if self.v_ned_mps is None:
            return np.full((len(self), 3), np.nan)
        llh = self.llh()
        return ned_vectors_to_ecef(self.v_ned_mps, llh[:, 0], llh[:, 1])


@dataclass
class Pseudoranges:
    """GPS L1 C/A (and Galileo E1: ids above 32, the core's) observations: one row per satellite and epoch, an
    epoch's rows together, epochs in time order."""

    t_abs: np.ndarray  # (k,) receiver time of the epoch, GPS s since the GPS epoch
    prn: np.ndarray  # (k,) int
    pr_m: np.ndarray
    doppler_hz: np.ndarray  # NaN where absent
    cn0_dbhz: np.ndarray  # NaN where absent
    lock_s: np.ndarray  # time in continuous lock, NaN where unknown
    source: str = ""

    def __len__(self) -> int:
        return len(self.t_abs)

    def epoch_starts(self) -> np.ndarray:
        """Row index where each epoch begins (plus the end)."""
        if not len(self.t_abs):
            return np.zeros(1, int)
        cut = np.flatnonzero(np.diff(self.t_abs) != 0) + 1
        return np.concatenate([[0], cut, [len(self.t_abs)]])

    def select(self, keep: np.ndarray) -> "Pseudoranges":
        return Pseudoranges(self.t_abs[keep], self.prn[keep], self.pr_m[keep], self.doppler_hz[keep],
                            self.cn0_dbhz[keep], self.lock_s[keep], self.source)

    def epochs(self):
        """(t_abs, prns, pseudoranges) per epoch, for ``spp`` and the like."""
        b = self.epoch_starts()
        return [(float(self.t_abs[i]), self.prn[i:j].tolist(), self.pr_m[i:j].tolist()) for i, j in zip(b[:-1], b[1:])]

    def table(self, t0: float = 0.0) -> np.ndarray:
        """The tight filter's (k, 6) [t - t0, prn, pseudorange m, C/N0 dB-Hz, lock count, Doppler Hz]; the lock
        count is the lock time in ms (0 where unknown: tracking taken as continuous while the satellite is
        present), the Doppler NaN where absent."""
        lock = np.where(np.isfinite(self.lock_s), np.round(self.lock_s * 1e3), 0.0)
        cn0 = np.where(np.isfinite(self.cn0_dbhz), self.cn0_dbhz, 0.0)
        return np.column_stack([self.t_abs - t0, self.prn, self.pr_m, cn0, lock, self.doppler_hz]).reshape(-1, 6)

    @classmethod
    def empty(cls, source: str = "") -> "Pseudoranges":
        z = np.zeros(0)
        return cls(z, np.zeros(0, int), z, z, z, z, source)


@dataclass
class Navigation:
    """Broadcast navigation data: GPS ephemerides (``_core.gnss.Ephemeris``) and Klobuchar coefficients."""

    ephemerides: list
    alpha: list[float] = field(default_factory=list)
    beta: list[float] = field(default_factory=list)
    leap_s: int | None = None
    # Galileo's BGD(E1, E5a) by core id: the E1/E5a pair's group delay (I/NAV word type 5), which the
    # ephemeris's tgd_s (BGD(E1, E5b), for the E1 single-frequency user) does not carry.
    bgd_e1_e5a_s: dict[int, float] = field(default_factory=dict)
    skipped: Counter = field(default_factory=Counter)  # records the reader left out, by reason

    def store(self):
        from .. import _core
        s = _core.gnss.EphemerisStore()
        for e in self.ephemerides:
            s.add(e)
        return s

    def prns(self) -> list[int]:
        return sorted({e.prn for e in self.ephemerides})


def read_bytes(path: str | Path) -> bytes:
    """A file's bytes, gunzipped when its name ends in .gz (archives keep RINEX and logs that way)."""
    return read_head(path, -1)


def read_head(path: str | Path, n: int) -> bytes:
    """A file's first n bytes (of its content when gzipped; n < 0: all of it), errors as ReaderError."""
    path = Path(path)
    try:
        if path.suffix.lower() == ".gz":
            with gzip.open(path, "rb") as f:
                return f.read(n)
        with open(path, "rb") as f:
            return f.read(n)
    except (OSError, EOFError) as e:
        raise ReaderError(path, getattr(e, "strerror", None) or str(e)) from None


def read_text_lines(path: str | Path) -> list[str]:
    return read_bytes(path).decode("ascii", errors="replace").splitlines()


def finite_rows(a: np.ndarray) -> np.ndarray:
    """Which rows of a table hold only finite values."""
    a = np.asarray(a, float)
    return np.isfinite(a.reshape(len(a), -1)).all(1)


NON_FINITE_ROWS = "rows with a value written as nan or inf (dropped)"


def ned_vectors_to_ecef(v_ned: np.ndarray, lat_rad: np.ndarray, lon_rad: np.ndarray) -> np.ndarray:
    """(n, 3) vectors from local north, east, down to ECEF at each row's latitude and longitude."""
    from ..evaluate import c_en

    return np.einsum("nij,nj->ni", c_en(lat_rad, lon_rad), v_ned)

"""The filter's inputs by columns (``ImuColumns``, ``PseudorangeColumns``) and as the tables a batch
call of the core takes.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

# The configuration language lives in filter_config; these are the names callers reach through here.


@dataclass
class ImuColumns:
    """IMU samples as the decoders give them: times (n,), angle and velocity increments (n, 3)
    each. A run takes them a chunk at a time, so the (n, 7) table a batch call wants is never
    built whole (for a day at 64 Hz that would be another 300 MB); ``[a:b]`` gives its rows."""

    t: np.ndarray
    dtheta: np.ndarray  # rad, or counts of lsb[0]
    dv: np.ndarray  # m/s, or counts of lsb[1]
    lsb: tuple[float, float] | None = None  # set: the increments are held as integer counts of these units

    def increments(self, rows: slice) -> tuple[np.ndarray, np.ndarray]:
        """Angle (rad) and velocity (m/s) increments of these rows."""
        if self.lsb is None:
            return self.dtheta[rows], self.dv[rows]
        return self.dtheta[rows] * self.lsb[0], self.dv[rows] * self.lsb[1]

    def __len__(self) -> int:
        return len(self.t)

    def __getitem__(self, index):
        rows, cols = (index[0], index[1:]) if isinstance(index, tuple) else (index, ())
        if isinstance(rows, (int, np.integer)):
            k = range(len(self))[rows]  # negative rows count from the end; out of range raises
            out = self[k:k + 1][0]
            return out[cols] if cols else out
        if not isinstance(rows, slice):
            raise TypeError("ImuColumns: rows by an integer or a slice (table() for the whole array)")
        out = np.column_stack([self.t[rows], *self.increments(rows)])
        return out[(slice(None),) + cols] if cols else out

    def table(self) -> np.ndarray:
        """The whole (n, 7) table [t, dtheta xyz, dv xyz]."""
        return self[:]

    def __array__(self, dtype=None, copy=None):
        # np.asarray of the columns: the table at once, not NumPy's walk through every row by
        # __getitem__ (7 s for an hour at 200 Hz).
        table = self.table()
        return table if dtype is None else table.astype(dtype, copy=False)


@dataclass
class PseudorangeColumns:
    """A pseudorange table (k, 5) [t, prn, pseudorange m, C/N0 dB-Hz, lock count], or (k, 6) with the
    Doppler (Hz, NaN: none), held by columns in the smallest types that give every value back exactly
    (a day at 10 Hz is 5 million rows): ``[a:b]`` gives those rows as the float table, ``[:, 0]`` the
    times, ``[mask]`` a subset."""

    t: np.ndarray
    prn: np.ndarray
    pseudorange_m: np.ndarray
    cn0_dbhz: np.ndarray
    lock: np.ndarray
    doppler_hz: np.ndarray | None = None

    @classmethod
    def compact(cls, table: np.ndarray):
        """The table by columns, or the table itself where a smaller type would change a value."""
        table = pr_table(table)
        cols = []
        dtypes = (np.float64, np.uint8, np.float64, np.float32, np.float32, np.float64)[:table.shape[1]]
        for j, dtype in enumerate(dtypes):
            c = table[:, j].astype(dtype)
            if not np.array_equal(c.astype(np.float64), table[:, j], equal_nan=True):
                return table
            cols.append(c)
        return cls(*cols)

    def __len__(self) -> int:
        return len(self.t)

    def __getitem__(self, index):
        rows, cols = (index[0], index[1:]) if isinstance(index, tuple) else (index, ())
        if cols == (0,):
            return self.t[rows]
        if isinstance(rows, np.ndarray) and rows.dtype == bool and not cols:
            return PseudorangeColumns(*(c[rows] for c in self._columns()))
        if not isinstance(rows, slice):
            raise TypeError("PseudorangeColumns: rows by a slice or a boolean mask")
        out = np.empty((len(self.t[rows]), len(self._columns())))
        for j, c in enumerate(self._columns()):
            out[:, j] = c[rows]
        return out[(slice(None),) + cols] if cols else out

    def _columns(self) -> tuple:
        base = self.t, self.prn, self.pseudorange_m, self.cn0_dbhz, self.lock
        return base if self.doppler_hz is None else base + (self.doppler_hz,)


def pr_table(prs) -> np.ndarray:
    """Pseudoranges as a float table of 5 columns, or 6 with the Doppler."""
    a = np.ascontiguousarray(prs, dtype=float)
    width = a.shape[-1] if a.ndim == 2 else 5
    if width not in (5, 6):
        raise ValueError(f"pseudoranges: 5 or 6 columns, got {width}")
    return a.reshape(-1, width)


def pseudorange_table(prs):
    """Pseudoranges as floats (``pr_table``); a ``PseudorangeColumns`` stays by columns."""
    if prs is None or isinstance(prs, PseudorangeColumns):
        return prs
    return pr_table(prs)


def imu_table(imu) -> np.ndarray:
    return imu.table() if isinstance(imu, ImuColumns) else np.ascontiguousarray(imu, dtype=float)

"""IMU recordings as rate samples, and where they stood still.

A record is (n, 6) rates: gyro x, y, z (rad/s) then accelerometer x, y, z
(m/s^2), from a logger session directory (increments / interval) or a CSV/NPY
file with a declared rate and column kinds. Steady windows are the stretches
between jumps of the 1 s block means, a jump being a change larger than
JUMP_SIGMA times what the in-block noise allows: a unit standing still (or
turning at a constant rate on a table) is steady; a flip, a table ramp or a
car accelerating is not.
"""

from __future__ import annotations

import warnings
from dataclasses import dataclass
from pathlib import Path

import numpy as np

AXES = ("gyro_x", "gyro_y", "gyro_z", "accel_x", "accel_y", "accel_z")
COLUMN_KINDS = AXES + ("time", "skip")
# Optional unit after a colon (accel_x:g, gyro_z:deg/s): the factor to SI.
UNITS = {"accel": {"m/s^2": 1.0, "m/s2": 1.0, "g": 9.80665}, "gyro": {"rad/s": 1.0, "deg/s": np.pi / 180,
                                                                       "deg/h": np.pi / 180 / 3600}}
JUMP_SIGMA = 8.0
DRIFT_ALLOWANCE = 3.0  # blocks' noise is inflated this much for the slow wander of the bias
MIN_SAMPLES = 64


class RecordError(ValueError):
    pass


@dataclass
class Record:
    name: str
    rates: np.ndarray  # (n, k) in the units of `columns`
    rate_hz: float
    columns: tuple[str, ...]
    start_unix_s: float | None = None  # from a session's sidecar: places records on one time line
    notes: tuple[str, ...] = ()
    # load(spare_front=True): the N + 1 float64 whose last N are rates[:, 0] (the first is free), else None
    front: np.ndarray | None = None

    def column(self, name: str) -> np.ndarray:
        return self.rates[:, self.columns.index(name)]

    @property
    def duration_s(self) -> float:
        return len(self.rates) / self.rate_hz


def parse_columns(spec: str | list | None, width: int, where: str) -> tuple[tuple[str, ...], np.ndarray]:
    """Column kinds and each column's factor to SI."""
    if spec is None:
        if width == 6:
            return AXES, np.ones(6)
        raise RecordError(f"{where}: {width} columns; declare what they are (columns = gyro_x,...,accel_z, "
                          f"time or skip; a unit after a colon: accel_x:g, gyro_x:deg/s)")
    cols, factors = [], []
    for c in (spec.split(",") if isinstance(spec, str) else spec):
        kind, _, unit = c.strip().partition(":")
        if kind not in COLUMN_KINDS:
            raise RecordError(f"{where}: unknown column kind {kind!r} (known: {', '.join(COLUMN_KINDS)})")
        table = UNITS.get(kind.split("_")[0], {})
        if unit and unit not in table:
            raise RecordError(f"{where}: unknown unit {unit!r} for {kind} (known: {', '.join(table) or 'none'})")
        cols.append(kind)
        factors.append(table.get(unit, 1.0) if unit else 1.0)
    if len(cols) != width:
        raise RecordError(f"{where}: {len(cols)} column kinds declared for {width} columns")
    return tuple(cols), np.array(factors)


def load(source: str | Path, rate_hz: float | None = None, columns=None, start_s: float | None = None,
         end_s: float | None = None, name: str | None = None, spare_front: bool = False) -> Record:
    """A session directory or a CSV/NPY file, trimmed to [start_s, end_s) seconds from its start.
    ``spare_front``: the rates of a one-column NPY of float64 come as a view of a buffer with one
    element free before the first (``Record.front``), so that the phase (N + 1 points) can be
    made in place of the record (``allan.phase_from_rate``) without a second copy."""
    p = Path(source)
    notes = []
    start_unix = None
    if not p.exists():
        raise RecordError(f"{p}: no such file or directory; give a session directory or a CSV/NPY of rates")
    if p.is_dir():
        from ..session import logs
        from ..session import layouts

        try:
            session = logs.read_session(p)
            imu = session.imu()
        except (layouts.LogError, KeyError) as e:
            raise RecordError(f"{p}: {e}") from None
        if len(imu) == 0:
            raise RecordError(f"{p}: no IMU frames")
        gaps = (np.diff(imu.counter.astype(np.int64)) - 1) % 256
        if gaps.any():
            notes.append(f"{int(gaps.sum())} IMU frame(s) missing (counter gaps); the samples are taken as contiguous")
        dt = 1.0 / imu.rate_hz
        data = np.hstack([imu.dtheta_rad, imu.dv_mps]) / dt
        rate, cols = float(imu.rate_hz), AXES
        start_unix = float(session.sidecar.get("start", {}).get("realtime", imu.stamps[0]))
    else:
        if rate_hz is None:
            raise RecordError(f"{p}: give the sample rate (rate_hz / --rate) of a CSV/NPY file")
        try:
            if p.suffix == ".npy":
                data = _read_npy(p, 1 if spare_front else 0)
            else:
                with warnings.catch_warnings():
                    warnings.simplefilter("ignore")  # an empty file: said below
                    data = np.loadtxt(p, delimiter="," if p.suffix == ".csv" else None, comments="#", ndmin=2)
        except (OSError, ValueError) as e:
            raise RecordError(f"{p}: not a table of numbers ({e})") from None
        if np.size(data) == 0:
            raise RecordError(f"{p}: no samples; expected one row per sample, one column per axis")
        data = np.asarray(data, dtype=float).reshape(len(data), -1)
        cols, factors = parse_columns(columns, data.shape[1], str(p))
        keep = [i for i, c in enumerate(cols) if c not in ("time", "skip")]
        if len(keep) < data.shape[1]:
            data = data[:, keep]
        cols, factors, rate = tuple(cols[i] for i in keep), factors[keep], float(rate_hz)
        # The file's own array (or a copy of its columns): scaled in place, x * 1.0 left out (the same numbers).
        for k in np.flatnonzero(factors != 1.0):
            data[:, k] *= factors[k]
        bad = _first_not_finite(data)
        if bad is not None:
            raise RecordError(f"{p}: row {bad + 1} is not finite")
    i0 = 0 if start_s is None else int(round(start_s * rate))
    i1 = len(data) if end_s is None else min(len(data), int(round(end_s * rate)))
    data = data[i0:i1]
    if len(data) < MIN_SAMPLES:
        raise RecordError(f"{p}: {len(data)} samples{' after trimming' if i0 or i1 < len(data) else ''}; "
                          f"at least {MIN_SAMPLES} are needed")
    if start_unix is not None:
        start_unix += i0 / rate
    front = None
    base = data.base
    if spare_front and data.shape[1] == 1 and base is not None and base.ndim == 1 and base.dtype == np.float64 \
            and base.flags.c_contiguous and data.strides[0] == 8:
        at = (data.__array_interface__["data"][0] - base.__array_interface__["data"][0]) // 8
        front = base[at - 1:at + len(data)] if at >= 1 else None
    return Record(name or p.name, data, rate, cols, start_unix, tuple(notes), front)


ROWS_PER_PIECE = 1 << 18  # rows per piece of a pass over a record: its temporaries stay small


def _read_npy(p: Path, front: int) -> np.ndarray:
    """np.load of an NPY file; a 1-D or one-column float64 one read straight into a buffer with ``front``
    free elements before its data (the array returned is the (n, 1) view after them)."""
    fmt = np.lib.format
    if front:
        with open(p, "rb") as fh:
            try:
                version = fmt.read_magic(fh)
                header = {(1, 0): fmt.read_array_header_1_0, (2, 0): fmt.read_array_header_2_0}.get(version)
                shape, fortran, dtype = header(fh) if header else ((), False, None)
            except ValueError:
                shape, dtype = (), None  # np.load says what is wrong
            if dtype == np.dtype("<f8") and (len(shape) == 1 or (len(shape) == 2 and shape[1] == 1)):
                n = int(shape[0])
                buf = np.empty(front + n)
                got = fh.readinto(memoryview(buf[front:]).cast("B"))
                if got == 8 * n:
                    return buf[front:].reshape(n, 1)
    return np.load(p)


def _first_not_finite(data: np.ndarray) -> int | None:
    """The first row holding a NaN or an infinity, looked for piece by piece."""
    for a in range(0, len(data), ROWS_PER_PIECE):
        bad = ~np.isfinite(data[a:a + ROWS_PER_PIECE]).all(1)
        if bad.any():
            return a + int(np.flatnonzero(bad)[0])
    return None


@dataclass
class Steadiness:
    windows: list[tuple[int, int]]  # sample ranges [i0, i1)
    jumps: int
    steady_fraction: float
    block_s: float

    @property
    def moved(self) -> bool:
        return self.jumps > 0 or self.steady_fraction < 0.9


def steady_windows(rates: np.ndarray, rate_hz: float, block_s: float = 1.0, min_s: float = 5.0,
                   edge_s: float = 1.0) -> Steadiness:
    """Windows where every column's 1 s means stay steady; edge_s is cut off next to each jump."""
    m = max(2, int(round(block_s * rate_hz)))
    nb = len(rates) // m
    if nb < 3:
        return Steadiness([(0, len(rates))] if len(rates) else [], 0, 1.0, block_s)
    blocks = rates[:nb * m].reshape(nb, m, -1)
    # Block by block, in pieces of blocks: the spread's temporaries stay small (the same numbers).
    step = max(1, ROWS_PER_PIECE // m)
    means = np.concatenate([blocks[a:a + step].mean(1) for a in range(0, nb, step)])
    spread = np.concatenate([blocks[a:a + step].std(1) for a in range(0, nb, step)])
    # Noise of a block mean from the spread inside blocks (the median block: robust to the moving ones).
    sigma = np.median(spread, axis=0) / np.sqrt(m) * DRIFT_ALLOWANCE
    sigma = np.maximum(sigma, 1e-12)
    jump = (np.abs(np.diff(means, axis=0)) > JUMP_SIGMA * np.sqrt(2) * sigma).any(1)
    edge = int(np.ceil(edge_s / block_s))
    bad = np.zeros(nb, bool)
    for j in np.flatnonzero(jump):
        bad[max(0, j - edge + 1):j + edge + 1] = True
    windows = []
    k = 0
    while k < nb:
        if bad[k]:
            k += 1
            continue
        j = k
        while j < nb and not bad[j]:
            j += 1
        if (j - k) * block_s >= min_s:
            windows.append((k * m, j * m if j < nb else len(rates)))
        k = j
    covered = sum(b - a for a, b in windows) / len(rates)
    return Steadiness(windows, int(jump.sum()), float(covered), block_s)


def motion_warning(st: Steadiness, duration_s: float) -> str | None:
    if not st.moved:
        return None
    longest = max((b - a for a, b in st.windows), default=0)
    return (f"the record moved: {st.jumps} jump(s) of the 1 s means, steady windows cover "
            f"{100 * st.steady_fraction:.0f} % of {duration_s:.0f} s (longest {longest} samples). Noise terms of a "
            f"moving record describe the motion, not the sensor: trim to a static span (start/end seconds)")

"""KF-GINS text files.

IMU: 7 columns, GPS seconds of week, angle increments x y z (rad), velocity increments
x y z (m/s), each over the interval ending at its time, axes forward-right-down.
GNSS: 7 columns, seconds of week, latitude and longitude (deg), ellipsoidal height (m),
standard deviations north, east, down (m); files with 13 columns add velocity north,
east, down (m/s) and its standard deviations.
Whitespace or commas between values; ``#`` starts a comment.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np

from .. import _core
from .common import Fixes, ReaderError, read_text_lines
from .imu_csv import ImuData, to_gps_seconds


def _table(path: Path, min_cols: int) -> np.ndarray:
    lines = read_text_lines(path)
    rows, first = [], None
    for i, line in enumerate(lines, start=1):
        text = line.split("#", 1)[0].replace(",", " ").strip()
        if not text:
            continue
        try:
            values = [float(x) for x in text.split()]
        except ValueError as e:
            raise ReaderError(path, str(e), line=i, field="value") from None
        if first is None:
            first = len(values)
            if first < min_cols:
                raise ReaderError(path, f"{first} columns, at least {min_cols} expected", line=i)
        if len(values) != first:
            raise ReaderError(path, f"{len(values)} columns where the file started with {first}", line=i)
        rows.append(values)
    if not rows:
        raise ReaderError(path, "no data rows")
    return np.array(rows)


def read_imu(path: str | Path, week: int) -> ImuData:
    path = Path(path)
    a = _table(path, 7)
    t = to_gps_seconds(a[:, 0], "gps_sow", week, path)
    return ImuData(t, a[:, 1:4], a[:, 4:7], path.name)


def read_gnss(path: str | Path, week: int, geoid_height_m: float = 0.0) -> Fixes:
    """``geoid_height_m`` is added to the heights (for heights above the geoid)."""
    path = Path(path)
    a = _table(path, 7)
    t = to_gps_seconds(a[:, 0], "gps_sow", week, path)
    llh = np.column_stack([np.radians(a[:, 1]), np.radians(a[:, 2]), a[:, 3] + geoid_height_m])
    r = _core.geodetic_to_ecef(llh)
    v = sv = None
    if a.shape[1] >= 13:
        v, sv = a[:, 7:10], a[:, 10:13]
    n = len(a)
    return Fixes(t, np.asarray(r).reshape(-1, 3), a[:, 4:7], np.zeros(n, int), np.zeros(n, int), v, sv, path.name)


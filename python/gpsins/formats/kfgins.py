"""KF-GINS text files.

IMU: 7 columns, GPS seconds of week, angle increments x y z (rad), velocity increments
x y z (m/s), each over the interval ending at its time, axes forward-right-down.
GNSS: 7 columns, seconds of week, latitude and longitude (deg), ellipsoidal height (m),
standard deviations north, east, down (m); files with 13 columns add velocity north,
east, down (m/s) and its standard deviations.
Whitespace or commas between values; ``#`` starts a comment. Rows with a value written as nan or
inf, and IMU increments whose time does not increase, are dropped and counted (``skipped``); fixes
are put in time order.
"""

from __future__ import annotations

from collections import Counter
from pathlib import Path

import numpy as np

from .. import _core
from .common import NON_FINITE_ROWS, Fixes, ReaderError, finite_rows, ned_vectors_to_ecef, read_text_lines
from .gpstime import SECONDS_PER_WEEK
from .imu_csv import ImuData, to_gps_seconds


def _table(path: Path, min_cols: int) -> tuple[np.ndarray, np.ndarray, Counter]:
    """The file's rows, their line numbers, and what was left out: rows with a value written as nan or inf."""
    lines = read_text_lines(path)
    rows, line_no, first = [], [], None
    skipped = Counter()
    for i, line in enumerate(lines, start=1):
        text = line.split("#", 1)[0].replace(",", " ").strip()
        if not text:
            continue
        tokens = text.split()
        values = []
        for k, x in enumerate(tokens, start=1):
            try:
                values.append(float(x))
            except ValueError:
                raise ReaderError(path, f"{x[:20]!r} is not a number", line=i, field=f"column {k}") from None
        if first is None:
            first = len(values)
            if first < min_cols:
                raise ReaderError(path, f"{first} columns, at least {min_cols} expected", line=i, field="columns")
        if len(values) != first:
            raise ReaderError(path, f"{len(values)} columns where the file started with {first}", line=i,
                              field="columns")
        rows.append(values)
        line_no.append(i)
    a, line_no = np.array(rows), np.array(line_no, int)
    ok = finite_rows(a) if len(a) else np.zeros(0, bool)
    if not ok.all():
        skipped[NON_FINITE_ROWS] = int((~ok).sum())
        a, line_no = a[ok], line_no[ok]
    if not len(a):
        raise ReaderError(path, "no data rows" + (" (every row has a nan or inf)" if skipped else ""),
                          line=len(lines) + 1, field="rows")
    return a, line_no, skipped


def _times(path: Path, sow: np.ndarray, line_no: np.ndarray, week: int) -> np.ndarray:
    wrong = np.flatnonzero(~((sow >= 0) & (sow <= SECONDS_PER_WEEK)))
    if len(wrong):
        k = int(wrong[0])
        raise ReaderError(path, f"{sow[k]!r} is no GPS second of the week", line=int(line_no[k]), field="column 1")
    return to_gps_seconds(sow, "gps_sow", week, path)


def read_imu(path: str | Path, week: int) -> ImuData:
    path = Path(path)
    a, line_no, skipped = _table(path, 7)
    t = _times(path, a[:, 0], line_no, week)
    skipped = Counter({f"IMU {k}": n for k, n in skipped.items()})
    keep = np.ones(len(t), bool)  # an increment whose time does not pass the last kept one is a glitch
    keep[1:] = t[1:] > np.maximum.accumulate(t)[:-1]
    if not keep.all():
        skipped["IMU samples whose time does not increase"] = int((~keep).sum())
    return ImuData(t[keep], a[keep, 1:4], a[keep, 4:7], path.name, skipped)


def read_gnss(path: str | Path, week: int, geoid_height_m: float = 0.0) -> Fixes:
    """``geoid_height_m`` is added to the heights (for heights above the geoid)."""
    path = Path(path)
    a, line_no, skipped = _table(path, 7)
    t = _times(path, a[:, 0], line_no, week)
    bad = np.flatnonzero((np.abs(a[:, 1]) > 90.0) | (np.abs(a[:, 2]) > 360.0))
    if len(bad):
        k = int(bad[0])
        raise ReaderError(path, f"latitude {a[k, 1]!r}, longitude {a[k, 2]!r} are no position", line=int(line_no[k]),
                          field="columns 2-3")
    llh = np.column_stack([np.radians(a[:, 1]), np.radians(a[:, 2]), a[:, 3] + geoid_height_m])
    r = _core.geodetic_to_ecef(llh)
    v = sv = None
    if a.shape[1] >= 13:
        v, sv = a[:, 7:10], a[:, 10:13]
    n = len(a)
    order = np.argsort(t, kind="stable")
    pick = (lambda x: None if x is None else x[order])
    return Fixes(t[order], np.asarray(r).reshape(-1, 3)[order], a[order, 4:7], np.zeros(n, int), np.zeros(n, int),
                 pick(v), pick(sv), path.name, Counter({f"GNSS {k}": n for k, n in skipped.items()}))


def read_nav(path: str | Path) -> dict:
    """KF-GINS's navigation result (``NavResult.nav``): week, seconds of week, latitude, longitude (deg),
    height (m), velocity north, east, down (m/s), roll, pitch, yaw (deg), at the IMU point. Returns
    t_abs, r_ecef, v_ecef and q_eb (body to ECEF)."""
    path = Path(path)
    a, line_no, skipped = _table(path, 11)
    t = np.empty(len(a))
    for week in np.unique(a[:, 0]):
        m = a[:, 0] == week
        t[m] = _times(path, a[m, 1], line_no[m], int(week))
    llh = np.column_stack([np.radians(a[:, 2]), np.radians(a[:, 3]), a[:, 4]])
    r = np.asarray(_core.geodetic_to_ecef(llh)).reshape(-1, 3)
    v = ned_vectors_to_ecef(a[:, 5:8], llh[:, 0], llh[:, 1])
    ypr = np.radians(a[:, [10, 9, 8]])
    q = np.asarray(_core.quat_body_to_ecef(ypr, llh)).reshape(-1, 4)
    order = np.argsort(t, kind="stable")
    return {"t_abs": t[order], "r_ecef": r[order], "v_ecef": v[order], "q_eb": q[order], "skipped": skipped}

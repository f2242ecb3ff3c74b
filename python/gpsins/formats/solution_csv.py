"""A navigation solution as a text table with declared columns (``gpsins score --format csv``).

Column names (``-`` skips a column): ``t``, then a position as ``x, y, z`` (ECEF m) or ``lat_deg,
lon_deg, h_m`` (ellipsoidal height); optionally a velocity as ``vx, vy, vz`` (ECEF m/s) or ``vn, ve,
vd`` (m/s); optionally an attitude as ``qw, qx, qy, qz`` (body to ECEF) or ``roll_deg, pitch_deg,
yaw_deg`` (against local NED). Commas or whitespace; lines starting with ``#`` and a header line
that is not numbers are skipped; the time scale is one of the IMU tables' (``imu_csv.TIME_SCALES``).
A value that is not a number is an error naming the file, line and column; rows with nan or inf are
dropped and counted.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np

from .. import _core
from .common import ReaderError, ned_vectors_to_ecef, read_text_lines
from .imu_csv import to_gps_seconds

POSITION = (("x", "y", "z"), ("lat_deg", "lon_deg", "h_m"))
VELOCITY = (("vx", "vy", "vz"), ("vn", "ve", "vd"))
ATTITUDE = (("qw", "qx", "qy", "qz"), ("roll_deg", "pitch_deg", "yaw_deg"))
KNOWN = {"t", "-", *(c for group in (POSITION, VELOCITY, ATTITUDE) for cols in group for c in cols)}


def read(path: str | Path, columns: list[str], time: str = "gps_abs", week: int | None = None) -> dict:
    """t_abs, r_ecef, v_ecef and q_eb (NaN where the table has none)."""
    path = Path(path)
    unknown = [c for c in columns if c not in KNOWN]
    if unknown or "t" not in columns:
        raise ReaderError(path, f"columns {columns}: need t and a position; unknown {unknown}" if unknown else
                          f"columns {columns}: no t", field="columns")
    col = {c: i for i, c in enumerate(columns) if c != "-"}

    def group(options, what: str, required: bool):
        for names in options:
            if all(n in col for n in names):
                return names
            if any(n in col for n in names):
                raise ReaderError(path, f"{what}: give all of {', '.join(names)}", field="columns")
        if required:
            raise ReaderError(path, f"no {what} ({' or '.join(', '.join(n) for n in options)})", field="columns")
        return None

    pos, vel, att = group(POSITION, "position", True), group(VELOCITY, "velocity", False), \
        group(ATTITUDE, "attitude", False)
    rows = []
    for i, line in enumerate(read_text_lines(path), start=1):
        text = line.split("#", 1)[0].strip()
        if not text:
            continue
        parts = text.replace(",", " ").split()
        try:
            values = [float(parts[col[c]]) for c in col]
        except IndexError:
            raise ReaderError(path, f"{len(parts)} values, the columns need {max(col.values()) + 1}", line=i,
                              field="row") from None
        except ValueError:
            if not rows:
                continue  # a header line
            bad = next(c for c in col if not _is_number(parts[col[c]]))
            raise ReaderError(path, f"{parts[col[bad]][:20]!r} is not a number", line=i,
                              field=f"column {col[bad] + 1} ({bad})") from None
        rows.append(values)
    if not rows:
        raise ReaderError(path, "no data rows", line=1, field="rows")
    a = np.array(rows)
    a = a[np.isfinite(a).all(axis=1)]
    v = {c: a[:, k] for k, c in enumerate(col)}
    t = to_gps_seconds(v["t"], time, week, path)
    if pos[0] == "x":
        r = np.column_stack([v["x"], v["y"], v["z"]])
        llh = _core.ecef_to_geodetic(r)
    else:
        llh = np.column_stack([np.radians(v["lat_deg"]), np.radians(v["lon_deg"]), v["h_m"]])
        r = np.asarray(_core.geodetic_to_ecef(llh)).reshape(-1, 3)
    n = len(t)
    ve = np.full((n, 3), np.nan)
    if vel == VELOCITY[0]:
        ve = np.column_stack([v["vx"], v["vy"], v["vz"]])
    elif vel is not None:
        ve = ned_vectors_to_ecef(np.column_stack([v["vn"], v["ve"], v["vd"]]), llh[:, 0], llh[:, 1])
    q = np.full((n, 4), np.nan)
    if att == ATTITUDE[0]:
        q = np.column_stack([v["qw"], v["qx"], v["qy"], v["qz"]])
    elif att is not None:
        ypr = np.radians(np.column_stack([v["yaw_deg"], v["pitch_deg"], v["roll_deg"]]))
        q = np.asarray(_core.quat_body_to_ecef(ypr, llh)).reshape(-1, 4)
    order = np.argsort(t, kind="stable")
    return {"t_abs": t[order], "r_ecef": r[order], "v_ecef": ve[order], "q_eb": q[order]}


def _is_number(text: str) -> bool:
    try:
        float(text)
        return True
    except ValueError:
        return False

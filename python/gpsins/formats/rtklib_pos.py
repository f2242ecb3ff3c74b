"""RTKLIB ``.pos`` solution files: positions with Q, satellites, standard deviations and, when the
file has them, velocities with their standard deviations.

The column header (the last ``%`` line before the data) says what the columns are:
latitude/longitude/height in degrees (or ``d m s`` in three tokens each), ECEF x/y/z, or
ENU baselines are told apart by it; times are calendar GPST ``YYYY/MM/DD hh:mm:ss.sss``,
``week seconds`` or UTC (converted to GPST with the leap seconds). Signed covariance
terms (sdne, sdeu, sdun as RTKLIB writes them: sign(c) sqrt|c|) are read but only the
standard deviations are kept.

Heights: RTKLIB writes ellipsoidal heights unless told to write geodetic (above the geoid)
ones, and then says "height=WGS84/geodetic" in its header; files converted elsewhere may
not say (the walk's heights are above the geoid). ``geoid_height_m`` (N, added: h = H + N)
turns such heights into the ellipsoidal heights every position here is in; a file whose
header says geodetic without it is an error rather than a 20-30 m height bias.
"""

from __future__ import annotations

import datetime as dt
import io
import re
from collections import Counter
from pathlib import Path

import numpy as np

from .. import _core
from .common import NON_FINITE_ROWS, Fixes, ReaderError, read_text_lines
from .gpstime import SECONDS_PER_WEEK, gps_seconds, leap_seconds


def _time_parser(header: list[str], path):
    """How many tokens the time takes and how to turn them into GPS seconds."""
    name = header[0].upper() if header else "GPST"
    utc = name.startswith("UTC") or name.startswith("JST")
    if name.startswith("JST"):
        raise ReaderError(path, "JST times are not supported; write GPST or UTC", field="time")

    def parse(tokens):
        if "/" in tokens[0]:
            y, mo, d = (int(x) for x in tokens[0].split("/"))
            h, mi, s = tokens[1].split(":")
            t = gps_seconds(y, mo, d, int(h), int(mi), float(s))
            if utc:
                when = dt.datetime(y, mo, d, int(h), int(mi))
                t += leap_seconds(when)
            return t
        return int(tokens[0]) * SECONDS_PER_WEEK + float(tokens[1])
    return parse


def read(path: str | Path, geoid_height_m: float | None = None) -> Fixes:
    """Fixes from a .pos; ``geoid_height_m``: the geoid's height above the ellipsoid, added to heights above the
    geoid (None: the heights are taken as ellipsoidal, as RTKLIB writes them by default). Rows with a value
    written as nan or inf, and a last row cut short, are dropped and counted in ``skipped``; any other row
    shorter than the header is an error."""
    path = Path(path)
    lines = read_text_lines(path)
    header, header_line = None, None
    rows = []
    for i, line in enumerate(lines):
        if line.startswith("%"):
            text = line[1:].strip()
            if "height=wgs84/geodetic" in text.lower().replace(" ", "") and geoid_height_m is None:
                raise ReaderError(path, "heights are above the geoid (header says geodetic): give the geoid height",
                                  line=i + 1, field="height")
            if re.match(r"^(GPST|UTC|JST)\b", text):
                header, header_line = text.split(), i + 1
            continue
        if not line.strip():
            continue
        if header is None:
            raise ReaderError(path, "no column header ('%  GPST ...') before the data", line=i + 1, field="header")
        rows.append((i + 1, line))
    if header is None:
        raise ReaderError(path, "no column header ('%  GPST ...')", line=len(lines) + 1, field="header")
    names = header[1:]
    lower = [n.lower() for n in names]
    kind = None if not lower else "llh" if lower[0].startswith("latitude") else \
        "xyz" if lower[0].startswith("x-ecef") else "enu" if lower[0].startswith("e-baseline") else None
    if kind is None or len(names) < 3:
        raise ReaderError(path, f"unknown position columns {names[:3]}", line=header_line, field="header")
    if kind == "enu":
        raise ReaderError(path, "ENU baseline solutions have no absolute position; write lat/lon/height or ECEF",
                          line=header_line, field="header")
    parse_time = _time_parser(header, path)
    col = {n: k for k, n in enumerate(lower)}

    def find(*candidates):
        return next((col[c] for c in candidates if c in col), None)
    iq, ins = find("q"), find("ns")
    isd = [find("sdn(m)", "sdx(m)"), find("sde(m)", "sdy(m)"), find("sdu(m)", "sdz(m)")]
    ivel = [find("vn(m/s)", "vx-ecef(m/s)"), find("ve(m/s)", "vy-ecef(m/s)"), find("vu(m/s)", "vz-ecef(m/s)")]
    isv = [find("sdvn", "sdvx"), find("sdve", "sdvy"), find("sdvu", "sdvz")]
    has_vel = all(v is not None for v in ivel)

    n = len(rows)
    t = np.empty(n)
    pos = np.empty((n, 3))
    sd = np.full((n, 3), np.nan)
    q = np.zeros(n, int)
    ns = np.zeros(n, int)
    vel = np.full((n, 3), np.nan)
    sdv = np.full((n, 3), np.nan)
    finite, cut = np.ones(n, bool), np.zeros(n, bool)
    dms = None
    table = _table(rows, names, header, kind)
    if table is not None:  # every row whole and plain: the per-row loop only to say what a bad one is
        t, values = table
        finite = np.isfinite(t) & np.isfinite(values).all(1)
        pos[:] = values[:, 0:3]
        for j in range(3):
            for index, out in ((isd[j], sd), (ivel[j] if has_vel else None, vel), (isv[j], sdv)):
                if index is not None:
                    out[:, j] = values[:, index]
        for index, out in ((iq, q), (ins, ns)):
            if index is not None:
                out[finite] = values[finite, index].astype(int)
        rows = []
    for k, (lineno, line) in enumerate(rows):
        tok = line.split()
        try:
            field = "time"
            t[k] = parse_time(tok[:2])
            rest = tok[2:]
            if kind == "llh":
                if dms is None:  # "d m s" needs 3 tokens for each angle: the row is 4 tokens longer
                    dms = len(rest) >= len(names) + 4
                if dms:
                    field = names[0]
                    lat = _dms(rest[0:3])
                    field = names[1]
                    lon = _dms(rest[3:6])
                    rest = [str(lat), str(lon)] + rest[6:]
            values = []
            for j, x in enumerate(rest[:len(names)]):
                field = names[j]
                values.append(float(x))
        except (ValueError, IndexError, OverflowError) as e:
            raise ReaderError(path, f"bad value ({e})", line=lineno, field=field) from None
        if len(values) < len(names):
            if k == n - 1:  # the file was cut while its last row was written
                cut[k] = True
                continue
            raise ReaderError(path, f"{len(values)} values where the header has {len(names)} columns", line=lineno,
                              field="row")
        if not (np.isfinite(values).all() and np.isfinite(t[k])):
            finite[k] = False
            continue
        pos[k] = values[0:3]
        if kind == "llh" and not (abs(values[0]) <= 90.0 and abs(values[1]) <= 360.0):
            raise ReaderError(path, f"{values[0]!r}, {values[1]!r} is no latitude, longitude", line=lineno,
                              field=f"{names[0]} {names[1]}")
        for name, i, lo, hi, out in (("Q", iq, 0, 255, q), ("ns", ins, 0, 1 << 16, ns)):
            if i is not None and i < len(values):
                if not (lo <= values[i] <= hi):
                    raise ReaderError(path, f"{values[i]!r} is not a {name} ({lo} to {hi})", line=lineno,
                                      field=names[i])
                out[k] = int(values[i])
        for j in range(3):
            if isd[j] is not None and isd[j] < len(values):
                sd[k, j] = values[isd[j]]
            if has_vel and ivel[j] < len(values):
                vel[k, j] = values[ivel[j]]
            if isv[j] is not None and isv[j] < len(values):
                sdv[k, j] = values[isv[j]]
    skipped = Counter()
    if not finite.all():
        skipped[f"GNSS {NON_FINITE_ROWS}"] = int((~finite).sum())
    if cut.any():
        skipped["GNSS rows cut short at the end of the file (dropped)"] = 1
    if not finite.all() or cut.any():
        keep = finite & ~cut
        t, pos, sd, q, ns, vel, sdv = (a[keep] for a in (t, pos, sd, q, ns, vel, sdv))
        n = len(t)
    if kind == "llh":
        llh = np.column_stack([np.radians(pos[:, 0]), np.radians(pos[:, 1]), pos[:, 2] + (geoid_height_m or 0.0)])
        r = _core.geodetic_to_ecef(llh) if n else np.zeros((0, 3))
        sd_ned = sd[:, [0, 1, 2]]  # up and down have the same sigma
        v_ned = vel * [1, 1, -1] if has_vel else None
        sv_ned = sdv if has_vel else None
    else:
        r = pos
        llh = _core.ecef_to_geodetic(r) if n else np.zeros((0, 3))
        from ..evaluate import c_en
        c = c_en(llh[:, 0], llh[:, 1])  # NED -> ECEF
        # ECEF sigmas to NED: only the diagonal is known, so rotate the diagonal covariance.
        p = np.einsum("nji,nj,njk->nik", c, np.nan_to_num(sd) ** 2, c)
        sd_ned = np.where(np.isnan(sd).any(1)[:, None], np.nan, np.sqrt(np.diagonal(p, axis1=1, axis2=2)))
        v_ned = np.einsum("nji,nj->ni", c, vel) if has_vel else None
        if has_vel:
            pv = np.einsum("nji,nj,njk->nik", c, np.nan_to_num(sdv) ** 2, c)
            sv_ned = np.where(np.isnan(sdv).any(1)[:, None], np.nan, np.sqrt(np.diagonal(pv, axis1=1, axis2=2)))
        else:
            sv_ned = None
    order = np.argsort(t, kind="stable")
    return Fixes(t[order], np.asarray(r).reshape(-1, 3)[order], sd_ned[order], q[order], ns[order],
                 None if v_ned is None else v_ned[order], None if sv_ned is None else sv_ned[order], path.name,
                 skipped)


_DATE_SEPARATORS = bytes.maketrans(b"/:", b"  ")


def _table(rows: list, names: list[str], header: list[str], kind: str) -> tuple[np.ndarray, np.ndarray] | None:
    """GPS seconds and values of every row at once (NumPy's parser: 0.15 s for a 26 000-row file where
    the loop over rows takes 0.5 s), or None where a row needs the loop: another width (a cut last row,
    ``d m s`` angles), UTC times, a value NumPy does not take, or one out of its range (Q, ns, latitude
    and longitude), which the loop then names with its line."""
    if not rows or (header[0].upper() if header else "GPST") != "GPST":
        return None
    first = rows[0][1].split()
    calendar = "/" in first[0]
    width = (6 if calendar else 2) + len(names)
    if len(first) != width - (4 if calendar else 0):
        return None
    text = "\n".join(line for _, line in rows).encode("utf-8", errors="replace")
    if calendar:
        text = text.translate(_DATE_SEPARATORS)
    try:  # as bytes: a StringIO holds 4 bytes a character (33 MB for an hour's 10 Hz truth)
        a = np.loadtxt(io.BytesIO(text), ndmin=2, comments=None, encoding="utf-8")
    except ValueError:
        return None
    if a.shape != (len(rows), width):
        return None
    if calendar:
        y, mo, d = (a[:, k].astype(np.int64) for k in range(3))
        if not (np.array_equal(a[:, :5], np.floor(a[:, :5])) and np.all((mo >= 1) & (mo <= 12) & (d >= 1) & (d <= 31))):
            return None
        y = np.where(y < 100, y + np.where(y < 80, 2000, 1900), y)
        days = _days_since_gps_epoch(y, mo, d)
        if days is None:
            return None
        seconds = a[:, 3].astype(np.int64) * 3600 + a[:, 4].astype(np.int64) * 60
        t = (days * 86400.0 + seconds) + a[:, 5]  # gps_seconds' sum, in its order
    else:
        t = a[:, 0].astype(np.int64) * SECONDS_PER_WEEK + a[:, 1]
    values = a[:, width - len(names):]
    ok = np.isfinite(values).all(1) & np.isfinite(t)
    col = {n.lower(): k for k, n in enumerate(names)}
    for name, lo, hi in (("q", 0, 255), ("ns", 0, 1 << 16)):
        if name in col and not np.all((values[ok, col[name]] >= lo) & (values[ok, col[name]] <= hi)):
            return None
    if kind == "llh" and not np.all((np.abs(values[ok, 0]) <= 90.0) & (np.abs(values[ok, 1]) <= 360.0)):
        return None
    return t, values


def _days_since_gps_epoch(y: np.ndarray, mo: np.ndarray, d: np.ndarray) -> np.ndarray | None:
    """Whole days from 1980-01-06 to each date (NumPy's calendar), or None if one is no date (30 February):
    the row loop then names it."""
    month = np.asarray(y - 1970, "datetime64[Y]").astype("datetime64[M]") + (mo - 1).astype("timedelta64[M]")
    days = month.astype("datetime64[D]") + (d - 1).astype("timedelta64[D]")
    if not np.array_equal(days.astype("datetime64[M]"), month):  # a day past its month's end
        return None
    return (days - np.datetime64("1980-01-06", "D")).astype(np.int64)


def _dms(tokens: list[str]) -> float:
    d, m, s = (float(x) for x in tokens)
    sign = -1.0 if tokens[0].strip().startswith("-") else 1.0
    return sign * (abs(d) + m / 60.0 + s / 3600.0)

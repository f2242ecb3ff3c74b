"""The reference system's file beside a session: ``reference.csv``.

A dual-antenna carrier-phase reference (the FOI report's Javad HD2,
section 4.2; docs/references.md) is not logged by the vehicle's logger: it records on its own and
its RTK solution is post-processed against a base station, in GPS time. So its
output sits beside the session as a plain text table rather than as a logger
record file: readable by any tool, no system-time stamps to align, and one row
per epoch whether or not the receiver had a solution.

Layout: lines starting with ``#`` are comments; the first other line is the
header naming the columns, in this order::

    gps_week,gps_tow_s,x_m,y_m,z_m,sigma_n_m,sigma_e_m,sigma_d_m,heading_deg,pitch_deg,sigma_heading_deg,sigma_pitch_deg

Position is ECEF (WGS-84) of the IMU's reference point (the reference's lever
arm already applied), heading and pitch those of the antenna baseline along the
body's forward axis, relative to local NED. Sigmas are 1-sigma. An empty field
means no solution: position and attitude drop out independently.
"""

from __future__ import annotations

from dataclasses import dataclass, field, fields
from pathlib import Path

import numpy as np

from .gpstime import SECONDS_PER_WEEK

FILE_NAME = "reference.csv"
MAGIC = "# gpsins reference 1"
COLUMNS = ("gps_week", "gps_tow_s", "x_m", "y_m", "z_m", "sigma_n_m", "sigma_e_m", "sigma_d_m", "heading_deg",
           "pitch_deg", "sigma_heading_deg", "sigma_pitch_deg")


class ReferenceError(ValueError):
    pass


@dataclass
class Reference:
    gps_week: np.ndarray  # (n,) int
    gps_tow_s: np.ndarray  # (n,)
    r_ecef_m: np.ndarray  # (n, 3), NaN where no position
    sigma_ned_m: np.ndarray  # (n, 3)
    heading_rad: np.ndarray  # (n,), NaN where no attitude
    pitch_rad: np.ndarray
    sigma_heading_rad: np.ndarray
    sigma_pitch_rad: np.ndarray
    damaged_lines: list[tuple[int, str]] = field(default_factory=list)  # (line number, why), rows skipped

    @property
    def position_ok(self) -> np.ndarray:
        return np.all(np.isfinite(self.r_ecef_m), axis=1)

    @property
    def attitude_ok(self) -> np.ndarray:
        return np.isfinite(self.heading_rad) & np.isfinite(self.pitch_rad)

    def gps_seconds(self) -> np.ndarray:
        """Continuous GPS time (week * 604800 + tow)."""
        return self.gps_week * SECONDS_PER_WEEK + self.gps_tow_s


def _fmt(x: float, digits: int) -> str:
    return "" if not np.isfinite(x) else f"{x:.{digits}f}"


def write(path: str | Path, gps_week: int, tow_s: np.ndarray, r_ecef_m: np.ndarray, sigma_ned_m: np.ndarray,
          heading_rad: np.ndarray, pitch_rad: np.ndarray, sigma_heading_rad, sigma_pitch_rad,
          comment: str = "") -> None:
    """Write a reference file; NaN values become empty fields. tow_s may run past one week."""
    lines = header_lines(comment) + row_lines(gps_week, tow_s, r_ecef_m, sigma_ned_m, heading_rad, pitch_rad,
                                              sigma_heading_rad, sigma_pitch_rad)
    Path(path).write_text("\n".join(lines) + "\n", encoding="ascii")


def header_lines(comment: str = "") -> list[str]:
    """The file's first lines (a writer appending rows block by block starts with these)."""
    return [MAGIC] + [f"# {c}" for c in comment.splitlines()] + [",".join(COLUMNS)]


def row_lines(gps_week: int, tow_s: np.ndarray, r_ecef_m: np.ndarray, sigma_ned_m: np.ndarray,
              heading_rad: np.ndarray, pitch_rad: np.ndarray, sigma_heading_rad, sigma_pitch_rad) -> list[str]:
    """One text row per epoch (see ``write``)."""
    n = len(tow_s)
    sh = np.broadcast_to(np.degrees(sigma_heading_rad), (n,))
    sp = np.broadcast_to(np.degrees(sigma_pitch_rad), (n,))
    lines = []
    for k in range(n):
        week = gps_week + int(tow_s[k] // SECONDS_PER_WEEK)
        tow = tow_s[k] - SECONDS_PER_WEEK * (week - gps_week)
        has_att = np.isfinite(heading_rad[k]) and np.isfinite(pitch_rad[k])
        row = [str(week), f"{tow:.3f}", *(_fmt(x, 4) for x in r_ecef_m[k]),
               *(_fmt(x, 4) if np.all(np.isfinite(r_ecef_m[k])) else "" for x in sigma_ned_m[k]),
               _fmt(np.degrees(heading_rad[k]), 4), _fmt(np.degrees(pitch_rad[k]), 4),
               _fmt(sh[k], 4) if has_att else "", _fmt(sp[k], 4) if has_att else ""]
        lines.append(",".join(row))
    return lines


ROWS_PER_BLOCK = 1 << 16


def _leading_comment_lines(path: Path) -> int | None:
    """How many comment or blank lines come before the header (None: no header line)."""
    with open(path, "rb") as f:
        for count, line in enumerate(f):
            if line.strip() and not line.startswith(b"#"):
                return count
    return None


def _read_clean(path: Path) -> Reference | None:
    """A file whose every row parses, read by pyarrow's CSV reader (a day at 10 Hz in well under a
    second); None when anything is off, for ``read``'s line-by-line parser to name the lines."""
    import pyarrow as pa
    from pyarrow import csv

    try:
        skip = _leading_comment_lines(path)
        if skip is None:
            return None
        types = {c: (pa.int64() if c == "gps_week" else pa.float64()) for c in COLUMNS}
        table = csv.read_csv(path, read_options=csv.ReadOptions(skip_rows=skip),
                             parse_options=csv.ParseOptions(ignore_empty_lines=True),
                             convert_options=csv.ConvertOptions(column_types=types, include_columns=list(COLUMNS)))
    except (OSError, pa.ArrowInvalid, pa.ArrowKeyError):
        return None
    if tuple(table.column_names) != COLUMNS or table.column("gps_week").null_count \
            or table.column("gps_tow_s").null_count:
        return None
    col = lambda name: table.column(name).to_numpy(zero_copy_only=False).astype(np.float64, copy=False)  # noqa: E731
    tow = col("gps_tow_s")
    if not np.all(np.isfinite(tow)):
        return None
    deg = np.pi / 180.0
    return Reference(table.column("gps_week").to_numpy().astype(np.int64), tow,
                     np.column_stack([col("x_m"), col("y_m"), col("z_m")]),
                     np.column_stack([col("sigma_n_m"), col("sigma_e_m"), col("sigma_d_m")]),
                     col("heading_deg") * deg, col("pitch_deg") * deg, col("sigma_heading_deg") * deg,
                     col("sigma_pitch_deg") * deg, [])


def read(path: str | Path) -> Reference:
    """Read a reference file. A row that does not parse is skipped and listed in damaged_lines;
    a file without the header is an error naming the file."""
    path = Path(path)
    clean = _read_clean(path)
    if clean is not None:
        return clean
    try:
        text = path.read_text(encoding="ascii", errors="replace")
    except OSError as e:
        raise ReferenceError(f"{path}: cannot read ({e.strerror})") from None
    header_seen = False
    rows, blocks, damaged = [], [], []
    for num, line in enumerate(text.splitlines(), start=1):
        if not line.strip() or line.startswith("#"):
            continue
        fields = line.split(",")
        if not header_seen:
            if tuple(f.strip() for f in fields) != COLUMNS:
                raise ReferenceError(f"{path}: line {num}: header must be {','.join(COLUMNS)}")
            header_seen = True
            continue
        if len(fields) != len(COLUMNS):
            damaged.append((num, f"{len(fields)} fields, expected {len(COLUMNS)}"))
            continue
        try:
            week = int(fields[0])
            vals = [float(f) if f.strip() else np.nan for f in fields[1:]]
        except ValueError as e:
            damaged.append((num, str(e)))
            continue
        if not np.isfinite(vals[0]):
            damaged.append((num, "gps_tow_s is empty"))
            continue
        rows.append((week, *vals))
        if len(rows) == ROWS_PER_BLOCK:  # a day at 10 Hz as Python floats would take 400 MB
            blocks.append(np.array(rows, dtype=np.float64))
            rows = []
    if not header_seen:
        raise ReferenceError(f"{path}: no header line ({','.join(COLUMNS)})")
    del text
    blocks.append(np.array(rows, dtype=np.float64).reshape(-1, len(COLUMNS)))
    a = np.concatenate(blocks) if len(blocks) > 1 else blocks[0]
    del blocks
    deg = np.pi / 180.0
    return Reference(a[:, 0].astype(np.int64), a[:, 1], a[:, 2:5], a[:, 5:8], a[:, 8] * deg, a[:, 9] * deg,
                     a[:, 10] * deg, a[:, 11] * deg, damaged)


def load(session_dir: str | Path) -> Reference:
    """The reference beside a session (``SESSION/reference.csv``)."""
    path = Path(session_dir) / FILE_NAME
    if not path.exists():
        raise ReferenceError(f"{path}: no reference file in this session")
    return read(path)


# --- scoring a solution against the reference -------------------------------------------------

WGS84_A = 6378137.0
WGS84_E2 = 6.69437999014e-3


def _lat_lon(r: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Geodetic latitude and longitude (Bowring's closed form: well below 1e-9 rad near the ground)."""
    x, y, z = r[:, 0], r[:, 1], r[:, 2]
    p = np.hypot(x, y)
    b = WGS84_A * np.sqrt(1.0 - WGS84_E2)
    ep2 = WGS84_E2 / (1.0 - WGS84_E2)
    th = np.arctan2(z * WGS84_A, p * b)
    lat = np.arctan2(z + ep2 * b * np.sin(th) ** 3, p - WGS84_E2 * WGS84_A * np.cos(th) ** 3)
    return lat, np.arctan2(y, x)


def _ecef_to_ned(d: np.ndarray, lat: np.ndarray, lon: np.ndarray) -> np.ndarray:
    sl, cl, so, co = np.sin(lat), np.cos(lat), np.sin(lon), np.cos(lon)
    n = -sl * co * d[:, 0] - sl * so * d[:, 1] + cl * d[:, 2]
    e = -so * d[:, 0] + co * d[:, 1]
    dn = -cl * co * d[:, 0] - cl * so * d[:, 1] - sl * d[:, 2]
    return np.stack([n, e, dn], axis=-1)


@dataclass
class ReferenceErrors:
    """Estimate minus reference at the reference's epochs inside the estimate's span."""
    gps_s: np.ndarray  # (k,) continuous GPS seconds
    position_ned_m: np.ndarray  # (k, 3), NaN where the reference has no position
    sigma_ned_m: np.ndarray  # (k, 3) the reference's own sigma
    heading_rad: np.ndarray  # (k,) wrapped to [-pi, pi), NaN where no attitude
    pitch_rad: np.ndarray
    sigma_heading_rad: np.ndarray
    sigma_pitch_rad: np.ndarray

    def summary(self) -> dict:
        """RMS errors and how much of the time the reference could score at all."""
        s = _Summary()
        s.add(self)
        return s.result()


class _Summary:
    """ReferenceErrors.summary's figures, gathered block by block."""

    def __init__(self):
        self.epochs = self.pos = self.att = 0
        self.h2 = self.v2 = self.sig2 = self.head2 = self.pitch2 = 0.0

    def add(self, e: ReferenceErrors) -> None:
        pos = np.all(np.isfinite(e.position_ned_m), axis=1)
        att = np.isfinite(e.heading_rad) & np.isfinite(e.pitch_rad)
        p = e.position_ned_m[pos]
        self.epochs += len(e.gps_s)
        self.pos += int(pos.sum())
        self.att += int(att.sum())
        self.h2 += float(np.sum(p[:, :2] ** 2))
        self.v2 += float(np.sum(p[:, 2] ** 2))
        self.sig2 += float(np.sum(e.sigma_ned_m[pos, :2] ** 2))
        self.head2 += float(np.sum(e.heading_rad[att] ** 2))
        self.pitch2 += float(np.sum(e.pitch_rad[att] ** 2))

    def result(self) -> dict:
        def rms(total, n):
            return float(np.sqrt(total / n)) if n else float("nan")
        return {"epochs": self.epochs, "position_epochs": self.pos, "attitude_epochs": self.att,
                "horizontal_rms_m": rms(self.h2, self.pos), "vertical_rms_m": rms(self.v2, self.pos),
                "heading_rms_deg": float(np.degrees(rms(self.head2, self.att))),
                "pitch_rms_deg": float(np.degrees(rms(self.pitch2, self.att))),
                "reference_horizontal_sigma_m": rms(self.sig2, self.pos)}


COMPARE_BLOCK = 1 << 16  # reference epochs per block: a day at 10 Hz is compared without day-long temporaries


def _compared_blocks(ref: Reference, gps_s: np.ndarray, r_ecef_m: np.ndarray, yaw_rad: np.ndarray,
                     pitch_rad: np.ndarray):
    """compare()'s errors, COMPARE_BLOCK reference epochs at a time."""
    gps_s = np.asarray(gps_s, dtype=np.float64)
    if len(gps_s) < 2 or np.any(np.diff(gps_s) <= 0):
        raise ValueError("estimate times must be at least two and strictly increasing")
    tr = ref.gps_seconds()
    idx = np.flatnonzero((tr >= gps_s[0]) & (tr <= gps_s[-1]))
    yaw_u = _unwrap(np.asarray(yaw_rad, dtype=np.float64))
    for a in range(0, len(idx), COMPARE_BLOCK):
        k = idx[a:a + COMPARE_BLOCK]
        tk = tr[k]
        r = np.stack([np.interp(tk, gps_s, r_ecef_m[:, i]) for i in range(3)], axis=-1)
        r_ref = ref.r_ecef_m[k]
        lat, lon = _lat_lon(np.where(np.isfinite(r_ref), r_ref, r))
        yield ReferenceErrors(tk, _ecef_to_ned(r - r_ref, lat, lon), ref.sigma_ned_m[k],
                              np.mod(np.interp(tk, gps_s, yaw_u) - ref.heading_rad[k] + np.pi, 2.0 * np.pi) - np.pi,
                              np.interp(tk, gps_s, pitch_rad) - ref.pitch_rad[k], ref.sigma_heading_rad[k],
                              ref.sigma_pitch_rad[k])


def compare(ref: Reference, gps_s: np.ndarray, r_ecef_m: np.ndarray, yaw_rad: np.ndarray,
            pitch_rad: np.ndarray) -> ReferenceErrors:
    """Errors of an estimate (continuous GPS seconds, ECEF position, yaw and pitch relative to
    local NED, e.g. a filter's solution) against the reference, the estimate interpolated
    linearly to the reference's epochs (yaw unwrapped first)."""
    blocks = list(_compared_blocks(ref, gps_s, r_ecef_m, yaw_rad, pitch_rad))
    if not blocks:
        z = np.zeros(0)
        return ReferenceErrors(z, np.zeros((0, 3)), np.zeros((0, 3)), z, z, z, z)
    return ReferenceErrors(*(np.concatenate([getattr(b, f.name) for b in blocks]) for f in fields(ReferenceErrors)))


def compare_summary(ref: Reference, gps_s: np.ndarray, r_ecef_m: np.ndarray, yaw_rad: np.ndarray,
                    pitch_rad: np.ndarray) -> dict:
    """``compare(...).summary()`` without the per-epoch arrays (a day's replay scores its reference
    system this way: the arrays would be 100 MB on top of everything else the run holds)."""
    s = _Summary()
    for block in _compared_blocks(ref, gps_s, r_ecef_m, yaw_rad, pitch_rad):
        s.add(block)
    return s.result()


def _unwrap(p: np.ndarray) -> np.ndarray:
    """np.unwrap(p), block by block with the running correction carried (the same sums in the same
    order, so the same numbers) and no series-long temporaries."""
    out = p.copy()
    carry = 0.0
    for a in range(1, len(p), COMPARE_BLOCK):
        b = min(a + COMPARE_BLOCK, len(p))
        dd = p[a:b] - p[a - 1:b - 1]
        ddmod = np.mod(dd + np.pi, 2.0 * np.pi) - np.pi
        ddmod[(ddmod == -np.pi) & (dd > 0)] = np.pi
        corr = ddmod - dd
        corr[np.abs(dd) < np.pi] = 0.0
        c = np.cumsum(np.concatenate(([carry], corr)))[1:]
        out[a:b] += c
        carry = c[-1]
    return out

"""A first data-set TOML for someone's own recording (``gpsins dataset init IMU_FILE GNSS_FILE``).

It reads what it can from the files and writes every key commented, marking what it had to guess:

- the IMU table's separator, header lines and columns: the time is the column that increases; the
  next six varying columns are two sensors of three axes, the accelerometer the three whose median
  norm is near gravity (in g or m/s^2 by that norm), the gyro the others (deg/s when its rates are too
  fast for rad/s);
- the time scale from the time values' size: Unix seconds (GPS or UTC: which one cannot be read off the
  numbers; the data-set doctor measures it), GPS seconds since 1980, or seconds of week;
- the GNSS file's format from its content: an RTKLIB .pos header, UBX sync bytes, a RINEX header.

Nothing about the mounting, the lever arm or the vehicle can be read from the files: those are left
at the identity, zero and "none", each marked, and `gpsins check` says whether the mounting fits.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np

from ..formats import imu_csv, rinex, rtklib_pos, ubx
from ..formats.gpstime import SECONDS_PER_WEEK, UNIX_TO_GPS_S

UNIX_2000_S = 946684800.0  # any Unix time of a recording made this century is above this
ROWS_READ = 2000


class InitError(ValueError):
    pass


def _table(path: Path) -> tuple[np.ndarray, str, int]:
    """The first rows as numbers, the separator and the number of header lines."""
    lines = path.read_text(encoding="utf-8", errors="replace").splitlines()[:ROWS_READ + 50]
    delimiter = "," if sum(x.count(",") for x in lines[:20]) >= 20 else None
    skip = 0
    for line in lines:
        parts = [p for p in (line.split(delimiter) if delimiter else line.split()) if p.strip()]
        try:
            [float(p) for p in parts]
            break
        except ValueError:
            skip += 1
    rows = []
    for line in lines[skip:skip + ROWS_READ]:
        parts = [p for p in (line.split(delimiter) if delimiter else line.split()) if p.strip()]
        try:
            rows.append([float(p) for p in parts])
        except ValueError:
            continue
    width = min((len(r) for r in rows), default=0)
    if width < 7:
        raise InitError(f"{path}: fewer than 7 numeric columns in its first rows: a time and six axes are needed")
    return np.array([r[:width] for r in rows]), "," if delimiter else "whitespace", skip


def _time_scale(t0: float, gnss_start_abs: float | None) -> tuple[str, int | None]:
    """The time scale under which the IMU's first time lies nearest the GNSS file's first epoch
    (GPS seconds since 1980), and the GPS week for seconds of week."""
    if gnss_start_abs is None:
        return ("gpst_unix" if t0 > UNIX_2000_S else "gps_sow"), None
    week = int(gnss_start_abs // SECONDS_PER_WEEK)
    candidates = {"gpst_unix": t0 - UNIX_TO_GPS_S, "gps_abs": t0, "gps_sow": week * SECONDS_PER_WEEK + t0}
    name = min(candidates, key=lambda k: abs(candidates[k] - gnss_start_abs))
    return name, (week if name == "gps_sow" else None)


def imu_guess(path: Path, gnss_start_abs: float | None = None) -> dict:
    """Columns, units, time scale (against the GNSS file's first epoch) and table layout guessed
    from an IMU text table."""
    a, delimiter, skip = _table(path)
    steps = np.diff(a, axis=0)
    increasing = [j for j in range(a.shape[1]) if (steps[:, j] > 0).all()]
    if not increasing:
        raise InitError(f"{path}: no column increases in every row: no time column")
    t_col = increasing[0]
    rest = [j for j in range(a.shape[1]) if j != t_col and np.ptp(a[:, j]) > 0]
    if len(rest) < 6:
        raise InitError(f"{path}: fewer than six varying columns beside the time")
    # The first six varying columns are the two sensors, three axes each (in either order): the
    # accelerometer's norm is gravity's, whatever its unit.
    triples = [rest[0:3], rest[3:6]]
    norms = [float(np.median(np.linalg.norm(a[:, c], axis=1))) for c in triples]
    k = int(np.argmin([min(abs(n - 1.0), abs(n - imu_csv.G0) / imu_csv.G0) for n in norms]))
    acc = triples[k]
    accel_unit = "g" if abs(norms[k] - 1.0) < abs(norms[k] - imu_csv.G0) else "m/s^2"
    gyro = [j for j in rest if j not in acc][:3]
    # A hand or a car turns at up to about 2 rad/s; in deg/s its rates read 57 times larger.
    gyro_unit = "deg/s" if np.percentile(np.abs(a[:, gyro]), 99) > 3.0 else "rad/s"
    t0 = float(a[0, t_col])
    time, week = _time_scale(t0, gnss_start_abs)
    names = ["-"] * a.shape[1]
    names[t_col] = "t"
    for n, j in zip(("ax", "ay", "az"), acc):
        names[j] = n
    for n, j in zip(("gx", "gy", "gz"), gyro):
        names[j] = n
    while names and names[-1] == "-":
        names.pop()
    rate = 1.0 / float(np.median(steps[:, t_col]))
    return {"columns": names, "accel_unit": accel_unit, "gyro_unit": gyro_unit, "time": time, "week": week,
            "delimiter": delimiter, "skip_rows": skip, "rate_hz": rate, "accel_norm": norms[k]}


def gnss_format(path: Path) -> str:
    head = path.read_bytes()[:4096]
    if head[:2] == b"\xb5\x62" or b"\xb5\x62" in head[:512]:
        return "ubx"
    text = head.decode("ascii", errors="replace")
    if "RINEX VERSION / TYPE" in text:
        if "OBSERVATION" not in text.upper().split("RINEX VERSION / TYPE")[0]:
            raise InitError(f"{path}: a RINEX file that is not an observation file (give the .obs; its "
                            f"navigation file goes in [gnss] nav)")
        return "rinex"
    if text.lstrip().startswith("%") and "GPST" in text:
        return "rtklib-pos"
    raise InitError(f"{path}: not an RTKLIB .pos, a UBX stream or a RINEX observation file")


def gnss_start_abs(path: Path, fmt: str) -> float | None:
    """The GNSS file's first epoch (GPS seconds since 1980), read by the project's own reader."""
    if fmt == "rtklib-pos":
        t = rtklib_pos.read(path).t_abs
    elif fmt == "ubx":
        u = ubx.read(path)
        t = u.fixes.t_abs if len(u.fixes) else u.pseudoranges.t_abs
    else:
        t = rinex.read_obs(path).gps_l1().t_abs
    return float(t[0]) if len(t) else None


def template(imu_file: str | Path, gnss_file: str | Path, directory: str | Path) -> str:
    """The commented data-set TOML for these two files, paths relative to ``directory``."""
    imu_file, gnss_file, directory = Path(imu_file), Path(gnss_file), Path(directory)
    fmt = gnss_format(gnss_file)
    g = imu_guess(imu_file, gnss_start_abs(gnss_file, fmt))

    def rel(p: Path) -> str:
        try:
            return str(p.resolve().relative_to(directory.resolve()))
        except ValueError:
            return str(p.resolve())

    time_note = ("GUESSED: Unix seconds near the GNSS file's start; \"gpst_unix\" if they count GPS time, "
                 "\"utc_unix\" if UTC (gpsins check measures which)") if g["time"] == "gpst_unix" else \
        "GUESSED: the scale that puts the IMU's start nearest the GNSS file's"
    lines = [
        "# A data set written by `gpsins dataset init`: check the lines marked GUESSED and SET, then",
        "# `gpsins check` this file (the data-set doctor) and `gpsins replay` it. Keys: docs/dataset.md.",
        f'name = "{imu_file.stem}"',
        "",
        "[imu]",
        f'file = "{rel(imu_file)}"',
        'format = "csv"',
        f"columns = {g['columns']}   # GUESSED: t increases; the accelerometer's norm is "
        f"{g['accel_norm']:.3f} {g['accel_unit']}; the next three the gyro",
        f'time = "{g["time"]}"   # {time_note}',
        f'accel_unit = "{g["accel_unit"]}"   # GUESSED from the norm at gravity',
        f'gyro_unit = "{g["gyro_unit"]}"   # GUESSED from how fast the rates are',
    ]
    if g["delimiter"] != ",":
        lines.append('delimiter = " "   # GUESSED: whitespace-separated')
    if g["skip_rows"]:
        lines.append(f"skip_rows = {g['skip_rows']}   # header lines")
    if g["time"] == "gps_sow":
        lines.append(f"week = {g['week'] if g['week'] is not None else 0}   # GUESSED: the GNSS file's week")
    lines += [
        "time_offset_s = 0.0   # the IMU's delay against GNSS time, if its maker states one",
        "imu_to_body_ypr_deg = [0.0, 0.0, 0.0]   # SET: the IMU axes as the body (forward-right-down) axes "
        "turned by yaw, pitch, roll",
        "",
        "[gnss]",
        f'file = "{rel(gnss_file)}"',
        f'format = "{fmt}"   # read off the file',
    ]
    if fmt == "rinex":
        lines.append('nav = "SET.nav"   # SET: the RINEX navigation file (ephemerides)')
    if fmt == "rtklib-pos":
        lines.append("# geoid_height_m = 0.0   # SET if the .pos heights are above the geoid")
    lines += [
        "antenna_m = [0.0, 0.0, 0.0]   # SET: the antenna from the IMU in body axes, m",
        "# antenna_sigma_m = 0.05   # how well antenna_m is known (1-sigma, m): replay then fits it to the data",
        "",
        "[vehicle]",
        'kind = "none"   # SET: "car" for a road vehicle whose body axes are its own (non-holonomic constraint)',
        "",
        "[scoring]",
        '# outages = "60:15:60"   # FIRST:LENGTH:PERIOD[:END] s of GNSS left out, to score the drift',
        "# reference = \"REFERENCE.pos\"   # an RTK solution to score against",
        "",
    ]
    return "\n".join(lines)

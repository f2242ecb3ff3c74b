"""RINEX 2 readers (GPS navigation and observation files) for the GNSS models.

Times are GPS seconds since the GPS epoch (1980-01-06), as the C++ core takes them.
Errors name the file and the line.
"""

from __future__ import annotations

import datetime as dt
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from . import _core

GPS_EPOCH = dt.datetime(1980, 1, 6)
URA_TABLE_M = (2.4, 3.4, 4.85, 6.85, 9.65, 13.65, 24.0, 48.0, 96.0, 192.0, 384.0, 768.0, 1536.0, 3072.0, 6144.0)


class RinexError(ValueError):
    pass


def gpst_text(t_abs) -> list[str]:
    """RTKLIB's GPST epoch text, 'YYYY/MM/DD hh:mm:ss.sss', for seconds since the GPS epoch."""
    return [(GPS_EPOCH + dt.timedelta(seconds=float(x))).strftime("%Y/%m/%d %H:%M:%S.%f")[:-3]
            for x in np.atleast_1d(t_abs)]


def gps_seconds(y: int, mo: int, d: int, h: int, mi: int, s: float) -> float:
    year = y + (2000 if y < 80 else 1900) if y < 100 else y
    t = dt.datetime(year, mo, d, h, mi) - GPS_EPOCH
    return t.days * 86400.0 + t.seconds + s


def _num(text: str) -> float:
    text = text.strip().replace("D", "E").replace("d", "e")
    return float(text) if text else 0.0


def _fields(line: str, start: int, n: int, width: int = 19) -> list[float]:
    return [_num(line[start + k * width:start + (k + 1) * width]) for k in range(n)]


@dataclass
class NavFile:
    ephemerides: list
    alpha: list[float] = field(default_factory=list)
    beta: list[float] = field(default_factory=list)
    leap_s: int | None = None

    def store(self) -> "_core.gnss.EphemerisStore":
        s = _core.gnss.EphemerisStore()
        for e in self.ephemerides:
            s.add(e)
        return s


def read_nav(path: str | Path) -> NavFile:
    path = Path(path)
    lines = path.read_text(encoding="ascii", errors="replace").splitlines()
    nav = NavFile([])
    i = 0
    while i < len(lines) and "END OF HEADER" not in lines[i]:
        label = lines[i][60:].strip()
        if label == "ION ALPHA":
            nav.alpha = [_num(lines[i][2 + 12 * k:14 + 12 * k]) for k in range(4)]
        elif label == "ION BETA":
            nav.beta = [_num(lines[i][2 + 12 * k:14 + 12 * k]) for k in range(4)]
        elif label == "LEAP SECONDS":
            nav.leap_s = int(lines[i][:6])
        elif label == "RINEX VERSION / TYPE" and not lines[i][20:21] in ("N", "n"):
            raise RinexError(f"{path}:{i + 1}: not a GPS navigation file")
        i += 1
    if i == len(lines):
        raise RinexError(f"{path}: no END OF HEADER")
    i += 1
    while i + 7 < len(lines) + 1 and i < len(lines):
        if not lines[i].strip():
            i += 1
            continue
        block = lines[i:i + 8]
        if len(block) < 8:
            raise RinexError(f"{path}:{i + 1}: truncated ephemeris record")
        try:
            head = block[0]
            prn = int(head[0:2])
            y, mo, d, h, mi = (int(head[3 + 3 * k:5 + 3 * k]) for k in range(5))
            sec = float(head[17:22])
            af0, af1, af2 = _fields(head, 22, 3)
            o = [_fields(b.ljust(80), 3, 4) for b in block[1:]]
        except ValueError as e:
            raise RinexError(f"{path}:{i + 1}: {e}") from None
        toc = gps_seconds(y, mo, d, h, mi, sec)
        e = _core.gnss.Ephemeris()
        e.prn = prn
        e.af0, e.af1, e.af2 = af0, af1, af2
        e.iode, e.crs, e.delta_n, e.m0 = int(o[0][0]), o[0][1], o[0][2], o[0][3]
        e.cuc, e.e, e.cus, e.sqrt_a = o[1]
        e.toe_s, e.cic, e.omega0, e.cis = o[2]
        e.i0, e.crc, e.omega, e.omega_dot = o[3]
        e.idot = o[4][0]
        e.week = int(o[4][2])
        ura = o[5][0]
        e.ura_index = next((k for k, v in enumerate(URA_TABLE_M) if ura <= v), 15)
        e.health, e.tgd_s, e.iodc = int(o[5][1]), o[5][2], int(o[5][3])
        e.fit_interval_long = o[6][1] > 4.0
        # toc as seconds of the toe's week (a record can straddle the week change).
        e.toc_s = toc - e.week * 604800.0
        nav.ephemerides.append(e)
        i += 8
    return nav


@dataclass
class ObsFile:
    approx_xyz: np.ndarray
    types: list[str]
    epochs: list[tuple[float, list[int], np.ndarray]]  # (t_abs, PRNs, (n, types) values, NaN = missing)
    interval_s: float | None = None

    def column(self, name: str) -> int:
        try:
            return self.types.index(name)
        except ValueError:
            raise RinexError(f"observation type {name} not in {self.types}") from None


def read_obs(path: str | Path, systems: str = "G") -> ObsFile:
    path = Path(path)
    lines = path.read_text(encoding="ascii", errors="replace").splitlines()
    types: list[str] = []
    xyz = np.zeros(3)
    interval = None
    i = 0
    while i < len(lines) and "END OF HEADER" not in lines[i]:
        label = lines[i][60:].strip()
        if label == "# / TYPES OF OBSERV":
            if not types:
                count = int(lines[i][:6])
            types += lines[i][6:60].split()
            types = types[:count]
        elif label == "APPROX POSITION XYZ":
            xyz = np.array([float(v) for v in lines[i][:42].split()])
        elif label == "INTERVAL":
            interval = float(lines[i][:10])
        i += 1
    if not types:
        raise RinexError(f"{path}: no # / TYPES OF OBSERV")
    i += 1
    epochs = []
    per_line = 5
    while i < len(lines):
        head = lines[i]
        if not head.strip():
            i += 1
            continue
        try:
            flag = int(head[28:29].strip() or 0)
            n = int(head[29:32])
            if flag > 1:  # an event: n special records (header lines, comments) follow
                i += 1 + n
                continue
            y, mo, d, h, mi = (int(head[1 + 3 * k:3 + 3 * k]) for k in range(5))
            sec = float(head[15:26])
        except ValueError as e:
            raise RinexError(f"{path}:{i + 1}: bad epoch line ({e})") from None
        sats = head[32:68]
        j = i + 1
        while len(sats) < 3 * n:
            sats += lines[j][32:68]
            j += 1
        names = [sats[3 * k:3 * k + 3] for k in range(n)]
        rows = (len(types) + per_line - 1) // per_line
        values = np.full((n, len(types)), np.nan)
        for k in range(n):
            text = "".join(lines[j + k * rows + r].ljust(80) for r in range(rows))
            for c in range(len(types)):
                field_ = text[16 * c:16 * c + 14]
                if field_.strip():
                    values[k, c] = float(field_)
        i = j + n * rows
        keep = [k for k, s in enumerate(names) if s[0] in (systems + " ")]
        epochs.append((gps_seconds(y, mo, d, h, mi, sec), [int(names[k][1:]) for k in keep], values[keep]))
    return ObsFile(xyz, types, epochs, interval)

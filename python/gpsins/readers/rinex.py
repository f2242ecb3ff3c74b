"""RINEX 2 and 3 readers: GPS navigation files and observation files.

Navigation: the GPS records (RINEX 3 mixed files: the other systems' records are
skipped by their length), the Klobuchar coefficients (ION ALPHA/BETA, or GPSA/GPSB)
and the leap seconds. Observation: every epoch's GPS values of every type, RINEX 3
types keeping their three-character codes ("C1C"); ``ObsFile.gps_l1()`` gives the
L1 C/A pseudoranges with Doppler and C/N0 when present.

Times are GPS seconds since the GPS epoch, as the C++ core takes them. Errors name
the file and the line.
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

import numpy as np

from .. import _core
from .common import (GPS_EPOCH, Navigation, Pseudoranges, ReaderError, gps_seconds, gpst_text,  # noqa: F401
                     read_text_lines)

URA_TABLE_M = (2.4, 3.4, 4.85, 6.85, 9.65, 13.65, 24.0, 48.0, 96.0, 192.0, 384.0, 768.0, 1536.0, 3072.0, 6144.0)
NAV_LINES_V3 = {"G": 8, "E": 8, "C": 8, "J": 8, "I": 8, "R": 4, "S": 4}  # lines per record by system
L1_ALIASES = {"C1": ("C1C", "C1"), "P1": ("C1P", "C1W", "P1"), "D1": ("D1C", "D1"), "S1": ("S1C", "S1"),
              "L1": ("L1C", "L1")}
L2_CODES = ("P2", "C2W", "C2", "C2L", "C2S", "C2X")  # semi-codeless P(Y) first: what TGD is defined for


class RinexError(ReaderError):
    pass


NavFile = Navigation  # the name this module's readers had before RINEX 3


def _num(text: str) -> float:
    text = text.strip().replace("D", "E").replace("d", "e")
    return float(text) if text else 0.0


def _fields(line: str, start: int, n: int, width: int = 19) -> list[float]:
    return [_num(line[start + k * width:start + (k + 1) * width]) for k in range(n)]


def _version(path, lines: list[str]) -> tuple[float, str, str]:
    """(version, file type letter, system letter) from the first header line."""
    if not lines or "RINEX VERSION / TYPE" not in lines[0]:
        raise RinexError(path, "not a RINEX file (no RINEX VERSION / TYPE)", line=1)
    try:
        version = float(lines[0][:9])
    except ValueError:
        raise RinexError(path, f"bad version {lines[0][:9]!r}", line=1, field="RINEX VERSION") from None
    return version, lines[0][20:21].upper(), (lines[0][40:41].strip() or "G").upper()


def read_nav(path: str | Path) -> Navigation:
    path = Path(path)
    lines = read_text_lines(path)
    version, kind, system = _version(path, lines)
    v3 = version >= 3.0
    if kind != "N" or (v3 and system not in ("G", "M")):
        raise RinexError(path, "not a GPS navigation file", line=1)
    if version >= 4.0:  # records open with "> EPH" lines: another layout
        raise RinexError(path, f"RINEX {version:g} navigation files are not read (RINEX 2 and 3 are)", line=1)
    nav = Navigation([])
    i = 0
    while i < len(lines) and "END OF HEADER" not in lines[i]:
        label = lines[i][60:].strip()
        try:
            if label == "ION ALPHA":
                nav.alpha = [_num(lines[i][2 + 12 * k:14 + 12 * k]) for k in range(4)]
            elif label == "ION BETA":
                nav.beta = [_num(lines[i][2 + 12 * k:14 + 12 * k]) for k in range(4)]
            elif label == "IONOSPHERIC CORR" and lines[i][:4] in ("GPSA", "GPSB"):
                values = [_num(lines[i][5 + 12 * k:17 + 12 * k]) for k in range(4)]
                if lines[i][:4] == "GPSA":
                    nav.alpha = values
                else:
                    nav.beta = values
            elif label == "LEAP SECONDS":
                nav.leap_s = int(lines[i][:6])
        except ValueError as e:
            raise RinexError(path, str(e), line=i + 1, field=label) from None
        i += 1
    if i == len(lines):
        raise RinexError(path, "no END OF HEADER")
    i += 1
    col = 4 if v3 else 3  # the broadcast orbit lines' first value
    while i < len(lines):
        if not lines[i].strip():
            i += 1
            continue
        sys_ = lines[i][0] if v3 else "G"
        n_lines = NAV_LINES_V3.get(sys_, 8) if v3 else 8
        if sys_ != "G":
            i += n_lines
            continue
        block = lines[i:i + 8]
        if len(block) < 8:
            raise RinexError(path, "truncated ephemeris record", line=i + 1)
        try:
            head = block[0]
            if v3:
                prn = int(head[1:3])
                y, mo, d, h, mi, s = int(head[4:8]), *(int(head[9 + 3 * k:11 + 3 * k]) for k in range(5))
                sec = float(s)
                af0, af1, af2 = _fields(head, 23, 3)
            else:
                prn = int(head[0:2])
                y, mo, d, h, mi = (int(head[3 + 3 * k:5 + 3 * k]) for k in range(5))
                sec = float(head[17:22])
                af0, af1, af2 = _fields(head, 22, 3)
            o = [_fields(b.ljust(80), col, 4) for b in block[1:]]
        except ValueError as e:
            raise RinexError(path, str(e), line=i + 1, field="ephemeris record") from None
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
    types: list[str]  # GPS observation types: RINEX 2 "C1", RINEX 3 "C1C"
    epochs: list[tuple[float, list[int], np.ndarray]]  # (t_abs, PRNs, (n, types) values, NaN = missing)
    interval_s: float | None = None
    version: float = 2.11
    source: str = ""

    def find(self, name: str) -> int | None:
        """Column of a type; RINEX 2 names find their RINEX 3 codes and back ("C1" <-> "C1C")."""
        for alias in (name, *L1_ALIASES.get(name, ()), *(k for k, v in L1_ALIASES.items() if name in v)):
            if alias in self.types:
                return self.types.index(alias)
        return None

    def column(self, name: str) -> int:
        c = self.find(name)
        if c is None:
            raise RinexError(self.source or "<obs>", f"observation type {name} not in {self.types}")
        return c

    def gps_l2(self) -> Pseudoranges:
        """GPS L2 pseudoranges, the partner of ``gps_l1`` for a dual-frequency ionosphere: the first of P2 (RINEX 3
        C2W), C2, C2L, C2S, C2X the file has; empty if none."""
        col = next((c for c in (self.find(n) for n in L2_CODES) if c is not None), None)
        return Pseudoranges.empty(self.source) if col is None else self._code(col, None, None)

    def gps_l1(self) -> Pseudoranges:
        """GPS L1 C/A pseudoranges with Doppler and C/N0 where the file has them (satellites without a
        pseudorange in an epoch are left out)."""
        return self._code(self.column("C1"), self.find("D1"), self.find("S1"))

    def _code(self, pr: int, dop: int | None, snr: int | None) -> Pseudoranges:
        """One code's rows, with the Doppler and C/N0 columns given (None: NaN)."""
        rows = []
        for t, prns, v in self.epochs:
            ok = np.isfinite(v[:, pr])
            n = int(ok.sum())
            if n == 0:
                continue
            rows.append(np.column_stack([np.full(n, t), np.asarray(prns)[ok], v[ok, pr],
                                         v[ok, dop] if dop is not None else np.full(n, np.nan),
                                         v[ok, snr] if snr is not None else np.full(n, np.nan)]))
        a = np.concatenate(rows) if rows else np.zeros((0, 5))
        return Pseudoranges(a[:, 0], a[:, 1].astype(int), a[:, 2], a[:, 3], a[:, 4], np.full(len(a), np.nan),
                            self.source)


def _obs_header(path, lines):
    version, kind, _ = _version(path, lines)
    if kind != "O":
        raise RinexError(path, "not an observation file", line=1)
    types: list[str] = []
    count = 0
    xyz = np.zeros(3)
    interval = None
    i = 0
    sys_now = ""
    while i < len(lines) and "END OF HEADER" not in lines[i]:
        line, label = lines[i], lines[i][60:].strip()
        try:
            if label == "# / TYPES OF OBSERV":  # RINEX 2
                if not types:
                    count = int(line[:6])
                types = (types + line[6:60].split())[:count]
            elif label == "SYS / # / OBS TYPES":  # RINEX 3: one system per block, continuation lines blank
                if line[0] != " ":
                    sys_now = line[0]
                    if sys_now == "G":
                        count = int(line[3:6])
                if sys_now == "G":
                    types = (types + line[7:60].split())[:count]
            elif label == "APPROX POSITION XYZ":
                xyz = np.array([float(v) for v in line[:42].split()])
            elif label == "INTERVAL":
                interval = float(line[:10])
        except ValueError as e:
            raise RinexError(path, str(e), line=i + 1, field=label) from None
        i += 1
    if i == len(lines):
        raise RinexError(path, "no END OF HEADER")
    if not types:
        raise RinexError(path, "no GPS observation types (# / TYPES OF OBSERV or SYS / # / OBS TYPES)")
    return version, types, xyz, interval, i + 1


def _value(text: str, path, line: int) -> float:
    if not text.strip():
        return np.nan
    try:
        return float(text)
    except ValueError:
        raise RinexError(path, f"bad value {text!r}", line=line, field="observation") from None


def read_obs(path: str | Path, systems: str = "G") -> ObsFile:
    """Observation file, RINEX 2 or 3; only GPS ("G", or blank in RINEX 2) satellites are kept."""
    path = Path(path)
    lines = read_text_lines(path)
    version, types, xyz, interval, i = _obs_header(path, lines)
    epochs = _epochs_v3(path, lines, i, types) if version >= 3.0 else _epochs_v2(path, lines, i, types, systems)
    return ObsFile(xyz, types, epochs, interval, version, path.name)


def _epochs_v2(path, lines, i, types, systems):
    epochs = []
    per_line = 5
    rows = (len(types) + per_line - 1) // per_line
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
            raise RinexError(path, f"bad epoch line ({e})", line=i + 1) from None
        sats = head[32:68]
        j = i + 1
        while len(sats) < 3 * n:
            if j >= len(lines):
                raise RinexError(path, "truncated satellite list", line=i + 1)
            sats += lines[j][32:68]
            j += 1
        names = [sats[3 * k:3 * k + 3] for k in range(n)]
        if j + n * rows > len(lines):
            raise RinexError(path, "truncated epoch", line=i + 1)
        values = np.full((n, len(types)), np.nan)
        for k in range(n):
            text = "".join(lines[j + k * rows + r].ljust(80) for r in range(rows))
            for c in range(len(types)):
                values[k, c] = _value(text[16 * c:16 * c + 14], path, j + k * rows + c // per_line + 1)
        i = j + n * rows
        keep = [k for k, s in enumerate(names) if s[0] in (systems + " ")]
        epochs.append((gps_seconds(y, mo, d, h, mi, sec), [int(names[k][1:]) for k in keep], values[keep]))
    return epochs


def _epochs_v3(path, lines, i, types):
    epochs = []
    while i < len(lines):
        head = lines[i]
        if not head.strip():
            i += 1
            continue
        if head[0] != ">":
            raise RinexError(path, "expected an epoch line starting with '>'", line=i + 1)
        try:
            flag = int(head[31:32].strip() or 0)
            n = int(head[32:35])
            if flag > 1:
                i += 1 + n
                continue
            y, mo, d, h, mi = int(head[2:6]), *(int(head[7 + 3 * k:9 + 3 * k]) for k in range(4))
            sec = float(head[18:29])
        except ValueError as e:
            raise RinexError(path, f"bad epoch line ({e})", line=i + 1) from None
        if i + 1 + n > len(lines):
            raise RinexError(path, "truncated epoch", line=i + 1)
        prns, rows = [], []
        for k in range(i + 1, i + 1 + n):
            line = lines[k]
            if line[:1] != "G":
                continue
            try:
                prns.append(int(line[1:3]))
            except ValueError:
                raise RinexError(path, f"bad satellite {line[:3]!r}", line=k + 1) from None
            rows.append([_value(line[3 + 16 * c:17 + 16 * c], path, k + 1) for c in range(len(types))])
        epochs.append((gps_seconds(y, mo, d, h, mi, sec), prns, np.array(rows, float).reshape(-1, len(types))))
        i += 1 + n
    return epochs

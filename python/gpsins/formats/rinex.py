"""RINEX 2 and 3 readers: GPS navigation files and observation files.

Navigation: the GPS records (RINEX 3 mixed files: the other systems' records are
skipped by their length), the Klobuchar coefficients (ION ALPHA/BETA, or GPSA/GPSB)
and the leap seconds. Observation: every epoch's GPS values of every type, RINEX 3
types keeping their three-character codes ("C1C"); ``ObsFile.gps_l1()`` gives the
L1 C/A pseudoranges with Doppler and C/N0 when present.

Times are GPS seconds since the GPS epoch, as the C++ core takes them. Errors name
the file, the line and the field; a value written as nan or inf drops its ephemeris (or
Klobuchar coefficients) or is a missing observation, counted in ``skipped``.
"""

from __future__ import annotations

from collections import Counter
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from .. import _core
from .gpstime import SECONDS_PER_WEEK, gps_seconds
from .common import Navigation, Pseudoranges, ReaderError, read_text_lines

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
    iono_bad = False
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
        iono_bad |= not all(np.isfinite(nav.alpha + nav.beta))
        i += 1
    if i == len(lines):
        raise RinexError(path, "no END OF HEADER", line=len(lines) + 1, field="END OF HEADER")
    if iono_bad:  # the ephemerides are still good; the filter goes without Klobuchar
        nav.alpha, nav.beta = [], []
        nav.skipped["RINEX Klobuchar coefficients with a value written as nan or inf (not used)"] = 1
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
            raise RinexError(path, f"truncated ephemeris record ({len(block)} of 8 lines)", line=i + 1,
                             field="ephemeris record")
        e = _ephemeris(path, block, i + 1, v3, col, nav.skipped)
        if e is not None:
            nav.ephemerides.append(e)
        i += 8
    return nav


# The values of a GPS navigation record's lines after the first, four to a line.
ORBIT_FIELDS = (("IODE", "Crs", "Delta n", "M0"), ("Cuc", "e", "Cus", "sqrt(A)"), ("Toe", "Cic", "OMEGA0", "Cis"),
                ("i0", "Crc", "omega", "OMEGA DOT"), ("IDOT", "codes on L2", "GPS week", "L2 P data flag"),
                ("SV accuracy", "SV health", "TGD", "IODC"), ("transmission time", "fit interval", "spare", "spare"))
NON_FINITE_EPHEMERIDES = "RINEX ephemerides with a value written as nan or inf (dropped)"


def _ephemeris(path, block: list[str], line: int, v3: bool, col: int, skipped):
    """One GPS record (8 lines from ``line``) as a core Ephemeris; None (counted) when a value is nan or inf."""
    head = block[0]
    try:
        if v3:
            prn = int(head[1:3])
            y, mo, d, h, mi, s = int(head[4:8]), *(int(head[9 + 3 * k:11 + 3 * k]) for k in range(5))
            sec = float(s)
            clock = head[23:]
        else:
            prn = int(head[0:2])
            y, mo, d, h, mi = (int(head[3 + 3 * k:5 + 3 * k]) for k in range(5))
            sec = float(head[17:22])
            clock = head[22:]
        toc = gps_seconds(y, mo, d, h, mi, sec) if np.isfinite(sec) else np.nan
    except (ValueError, OverflowError) as e:
        raise RinexError(path, f"bad PRN or epoch ({e})", line=line, field="PRN / EPOCH / SV CLK") from None
    if not 1 <= prn <= 32:
        raise RinexError(path, f"PRN {prn} is no GPS satellite (1-32)", line=line, field="PRN")
    af = _values(path, clock, 3, line, ("SV clock bias", "SV clock drift", "SV clock drift rate"))
    o = [_values(path, b.ljust(80)[col:], 4, line + k, names) for k, (b, names) in enumerate(zip(block[1:],
                                                                                              ORBIT_FIELDS), 1)]
    if not (np.isfinite(toc) and np.isfinite(af).all() and np.isfinite(o).all()):
        skipped[NON_FINITE_EPHEMERIDES] += 1
        return None
    for (k, j, lo, hi) in ((1, 0, 0, 1023), (5, 2, 0, 65535), (6, 1, 0, 63), (6, 3, 0, 1023)):
        if not lo <= o[k - 1][j] <= hi:
            raise RinexError(path, f"{o[k - 1][j]!r} is not a {ORBIT_FIELDS[k - 1][j]} ({lo} to {hi})",
                             line=line + k, field=ORBIT_FIELDS[k - 1][j])
    e = _core.gnss.Ephemeris()
    e.prn = prn
    e.af0, e.af1, e.af2 = af
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
    e.toc_s = toc - e.week * SECONDS_PER_WEEK
    return e


def _values(path, text: str, n: int, line: int, names, width: int = 19) -> list[float]:
    """n D19.12 values from a navigation line's text."""
    out = []
    for k in range(n):
        try:
            out.append(_num(text[k * width:(k + 1) * width]))
        except ValueError:
            raise RinexError(path, f"{text[k * width:(k + 1) * width].strip()!r} is not a number", line=line,
                             field=names[k]) from None
    return out


@dataclass
class ObsFile:
    approx_xyz: np.ndarray
    types: list[str]  # GPS observation types: RINEX 2 "C1", RINEX 3 "C1C"
    epochs: list[tuple[float, list[int], np.ndarray]]  # (t_abs, PRNs, (n, types) values, NaN = missing)
    interval_s: float | None = None
    version: float = 2.11
    source: str = ""
    skipped: Counter = field(default_factory=Counter)  # what the reader left out, by reason

    def find(self, name: str) -> int | None:
        """Column of a type; RINEX 2 names find their RINEX 3 codes and back ("C1" <-> "C1C")."""
        for alias in (name, *L1_ALIASES.get(name, ()), *(k for k, v in L1_ALIASES.items() if name in v)):
            if alias in self.types:
                return self.types.index(alias)
        return None

    def column(self, name: str) -> int:
        c = self.find(name)
        if c is None:
            raise RinexError(self.source or "<obs>", f"observation type {name} not in {self.types}",
                             field="# / TYPES OF OBSERV" if self.version < 3 else "SYS / # / OBS TYPES")
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
                if xyz.shape != (3,) or not np.isfinite(xyz).all():
                    raise ValueError(f"{line[:42].strip()!r} is not three coordinates")
            elif label == "INTERVAL":
                interval = float(line[:10])
                if not (np.isfinite(interval) and interval >= 0):
                    raise ValueError(f"{line[:10].strip()!r} is not an interval")
        except ValueError as e:
            raise RinexError(path, str(e), line=i + 1, field=label) from None
        i += 1
    if i == len(lines):
        raise RinexError(path, "no END OF HEADER", line=len(lines) + 1, field="END OF HEADER")
    if not types or count < 0:
        raise RinexError(path, "no GPS observation types (# / TYPES OF OBSERV or SYS / # / OBS TYPES)",
                         line=i + 1, field="# / TYPES OF OBSERV" if version < 3 else "SYS / # / OBS TYPES")
    return version, types, xyz, interval, i + 1


NON_FINITE_OBSERVATIONS = "RINEX observations written as nan or inf (taken as missing)"
EPOCHS_NOT_INCREASING = "RINEX epochs whose time does not increase (dropped)"


def _value(text: str, path, line: int, obs_type: str, sat: str, skipped) -> float:
    if not text.strip():
        return np.nan
    try:
        x = float(text)
    except ValueError:
        raise RinexError(path, f"bad value {text.strip()!r}", line=line, field=f"{obs_type} of {sat.strip()}") from None
    if not np.isfinite(x):
        skipped[NON_FINITE_OBSERVATIONS] += 1
        return np.nan
    return x


def _epoch_count(path, text: str, line: int) -> int:
    n = int(text)
    if n < 0:
        raise RinexError(path, f"{n} satellites", line=line, field="number of satellites")
    return n


def read_obs(path: str | Path, systems: str = "G") -> ObsFile:
    """Observation file, RINEX 2 or 3; only GPS ("G", or blank in RINEX 2) satellites are kept. Values written
    as nan or inf are taken as missing, epochs whose time does not increase dropped; both counted in
    ``skipped``."""
    path = Path(path)
    lines = read_text_lines(path)
    version, types, xyz, interval, i = _obs_header(path, lines)
    skipped = Counter()
    epochs = _epochs_v3(path, lines, i, types, skipped) if version >= 3.0 else \
        _epochs_v2(path, lines, i, types, systems, skipped)
    keep, last = [], -np.inf
    for ep in epochs:
        if ep[0] > last:
            keep.append(ep)
            last = ep[0]
    if len(keep) < len(epochs):
        skipped[EPOCHS_NOT_INCREASING] = len(epochs) - len(keep)
    return ObsFile(xyz, types, keep, interval, version, path.name, skipped)


def _epochs_v2(path, lines, i, types, systems, skipped):
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
            n = _epoch_count(path, head[29:32], i + 1)
            if flag > 1:  # an event: n special records (header lines, comments) follow
                i += 1 + n
                continue
            y, mo, d, h, mi = (int(head[1 + 3 * k:3 + 3 * k]) for k in range(5))
            sec = float(head[15:26])
            t = gps_seconds(y, mo, d, h, mi, sec)
        except (ValueError, OverflowError) as e:
            raise RinexError(path, f"bad epoch line ({e})", line=i + 1, field="EPOCH/SAT") from None
        sats = head[32:68]
        j = i + 1
        while len(sats) < 3 * n:
            if j >= len(lines):
                raise RinexError(path, "truncated satellite list", line=i + 1, field="satellite list")
            sats += lines[j][32:68]
            j += 1
        names = [sats[3 * k:3 * k + 3] for k in range(n)]
        if j + n * rows > len(lines):
            raise RinexError(path, f"truncated epoch ({n} satellites, {rows} lines each)", line=i + 1,
                             field="observations")
        values = np.full((n, len(types)), np.nan)
        for k in range(n):
            text = "".join(lines[j + k * rows + r].ljust(80) for r in range(rows))
            for c in range(len(types)):
                values[k, c] = _value(text[16 * c:16 * c + 14], path, j + k * rows + c // per_line + 1, types[c],
                                      names[k], skipped)
        keep = [k for k, s in enumerate(names) if s[0] in (systems + " ")]
        try:
            prns = [int(names[k][1:]) for k in keep]
        except ValueError:
            bad = next(names[k] for k in keep if not names[k][1:].strip().isdigit())
            raise RinexError(path, f"bad satellite {bad!r}", line=i + 1, field="satellite list") from None
        i = j + n * rows
        if np.isfinite(t):
            epochs.append((t, prns, values[keep]))
        else:
            skipped["RINEX epochs with a time written as nan or inf (dropped)"] += 1
    return epochs


def _epochs_v3(path, lines, i, types, skipped):
    epochs = []
    while i < len(lines):
        head = lines[i]
        if not head.strip():
            i += 1
            continue
        if head[0] != ">":
            raise RinexError(path, "expected an epoch line starting with '>'", line=i + 1, field="EPOCH")
        try:
            flag = int(head[31:32].strip() or 0)
            n = _epoch_count(path, head[32:35], i + 1)
            if flag > 1:
                i += 1 + n
                continue
            y, mo, d, h, mi = int(head[2:6]), *(int(head[7 + 3 * k:9 + 3 * k]) for k in range(4))
            sec = float(head[18:29])
            t = gps_seconds(y, mo, d, h, mi, sec)
        except (ValueError, OverflowError) as e:
            raise RinexError(path, f"bad epoch line ({e})", line=i + 1, field="EPOCH") from None
        if i + 1 + n > len(lines):
            raise RinexError(path, f"truncated epoch ({n} satellites)", line=i + 1, field="observations")
        prns, rows = [], []
        for k in range(i + 1, i + 1 + n):
            line = lines[k]
            if line[:1] != "G":
                continue
            try:
                prns.append(int(line[1:3]))
            except ValueError:
                raise RinexError(path, f"bad satellite {line[:3]!r}", line=k + 1, field="satellite") from None
            rows.append([_value(line[3 + 16 * c:17 + 16 * c], path, k + 1, types[c], line[:3], skipped)
                         for c in range(len(types))])
        i += 1 + n
        if np.isfinite(t):
            epochs.append((t, prns, np.array(rows, float).reshape(-1, len(types))))
        else:
            skipped["RINEX epochs with a time written as nan or inf (dropped)"] += 1
    return epochs

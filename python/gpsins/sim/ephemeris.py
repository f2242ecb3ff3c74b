"""Broadcast GPS ephemerides for the simulator: RINEX 2 navigation files,
satellite position and clock (IS-GPS-200), and the subframe words of
Superstar II ID 22 (encode and decode).

This is the simulator's own NumPy code; the filter's GNSS models live in the
C++ core and are checked against it and against RTKLIB's numbers.
Times are continuous GPS seconds (week * 604800 + seconds of week).
"""

from __future__ import annotations

import math
from dataclasses import dataclass, fields
from pathlib import Path

import numpy as np

from ..formats.gpstime import SECONDS_PER_WEEK

MU = 3.986005e14  # IS-GPS-200 Earth gravitational parameter, m^3/s^2
OMEGA_E = 7.2921151467e-5  # IS-GPS-200 Earth rotation rate, rad/s
F_REL = -4.442807633e-10  # relativistic clock constant, s/sqrt(m)
GPS_PI = 3.1415926535898  # the value IS-GPS-200 uses to convert semicircles
C = 299792458.0


class EphemerisError(ValueError):
    """A navigation file or subframe that cannot be read; names the file/line or field."""


@dataclass(frozen=True)
class Ephemeris:
    prn: int
    week: int  # GPS week of toe (full, not mod 1024)
    toc: float  # s of week
    af0: float
    af1: float
    af2: float
    iode: int
    crs: float
    delta_n: float  # rad/s
    m0: float  # rad
    cuc: float
    e: float
    cus: float
    sqrt_a: float
    toe: float  # s of week
    cic: float
    omega0: float  # rad
    cis: float
    i0: float
    crc: float
    omega: float
    omega_dot: float  # rad/s
    idot: float  # rad/s
    l2_codes: int
    l2p_flag: int
    ura_index: int
    health: int
    tgd: float
    iodc: int
    fit_flag: int = 0

    @property
    def t_oe(self) -> float:
        """toe as continuous GPS seconds."""
        return self.week * SECONDS_PER_WEEK + self.toe

    @property
    def t_oc(self) -> float:
        # toc is in the same week as toe up to a week crossing between them
        t = self.week * SECONDS_PER_WEEK + self.toc
        return t + SECONDS_PER_WEEK * round((self.t_oe - t) / SECONDS_PER_WEEK)


def _num(s: str) -> float:
    s = s.strip().replace("D", "E").replace("d", "e")
    return float(s) if s else 0.0


def gps_seconds(y: int, mo: int, d: int, h: int, mi: int, sec: float) -> float:
    days = (np.datetime64(f"{y:04d}-{mo:02d}-{d:02d}") - np.datetime64("1980-01-06")).astype(int)
    return float(days) * 86400.0 + h * 3600.0 + mi * 60.0 + sec


@dataclass
class NavFile:
    ephemerides: list[Ephemeris]
    ion_alpha: tuple[float, float, float, float] | None
    ion_beta: tuple[float, float, float, float] | None
    leap_seconds: int | None


def read_rinex2_nav(path: str | Path) -> NavFile:
    path = Path(path)
    lines = path.read_text(encoding="ascii", errors="replace").splitlines()
    alpha = beta = None
    leap = None
    k = 0
    for k, line in enumerate(lines):  # noqa: B007 (k, the header's last line, is read after)
        label = line[60:].strip()
        if label == "ION ALPHA":
            alpha = tuple(_num(line[2 + 12 * j:14 + 12 * j]) for j in range(4))
        elif label == "ION BETA":
            beta = tuple(_num(line[2 + 12 * j:14 + 12 * j]) for j in range(4))
        elif label == "LEAP SECONDS":
            leap = int(line[:6])
        elif label == "END OF HEADER":
            break
    else:
        raise EphemerisError(f"{path}: no END OF HEADER")
    ephs = []
    body = lines[k + 1:]
    for r in range(0, len(body) - 7, 8):
        rec = body[r:r + 8]
        try:
            prn = int(rec[0][0:2])
            yy = int(rec[0][3:5])
            t = gps_seconds(yy + (2000 if yy < 80 else 1900), int(rec[0][6:8]), int(rec[0][9:11]),
                             int(rec[0][12:14]), int(rec[0][15:17]), float(rec[0][17:22]))
            v = [_num(rec[0][22 + 19 * j:41 + 19 * j]) for j in range(3)]
            for line in rec[1:]:
                v += [_num(line[3 + 19 * j:22 + 19 * j]) for j in range(4)]
        except ValueError as e:
            raise EphemerisError(f"{path}: line {k + 2 + r}: {e}") from None
        week = int(v[21])
        toe = v[11]
        ephs.append(Ephemeris(prn=prn, week=week, toc=t - week * SECONDS_PER_WEEK, af0=v[0], af1=v[1], af2=v[2],
                              iode=int(v[3]), crs=v[4], delta_n=v[5], m0=v[6], cuc=v[7], e=v[8], cus=v[9],
                              sqrt_a=v[10], toe=toe, cic=v[12], omega0=v[13], cis=v[14], i0=v[15], crc=v[16],
                              omega=v[17], omega_dot=v[18], idot=v[19], l2_codes=int(v[20]), l2p_flag=int(v[22]),
                              ura_index=ura_index(v[23]), health=int(v[24]), tgd=v[25], iodc=int(v[26]),
                              fit_flag=int(v[28] > 4.0) if len(v) > 28 else 0))
    return NavFile(ephs, alpha, beta, leap)


_URA_M = (2.4, 3.4, 4.85, 6.85, 9.65, 13.65, 24.0, 48.0, 96.0, 192.0, 384.0, 768.0, 1536.0, 3072.0, 6144.0)


def ura_index(metres: float) -> int:
    for i, m in enumerate(_URA_M):
        if metres <= m:
            return i
    return 15


def select(ephs: list[Ephemeris], prn: int, t: float) -> Ephemeris | None:
    """Healthy ephemeris of `prn` with toe nearest t, within 4 h."""
    best = None
    for e in ephs:
        if e.prn == prn and e.health == 0 and abs(e.t_oe - t) <= 7200.0 + 1.0:
            if best is None or abs(e.t_oe - t) < abs(best.t_oe - t):
                best = e
    return best


def _kepler(eph: Ephemeris, t: np.ndarray):
    a = eph.sqrt_a ** 2
    tk = t - eph.t_oe
    n = math.sqrt(MU / a ** 3) + eph.delta_n
    m = eph.m0 + n * tk
    ecc = m.copy()
    for _ in range(30):
        step = (ecc - eph.e * np.sin(ecc) - m) / (1.0 - eph.e * np.cos(ecc))
        ecc = ecc - step
        if np.max(np.abs(step)) < 1e-15:
            break
    return a, tk, n, ecc


def sat_position(eph: Ephemeris, t: np.ndarray | float) -> np.ndarray:
    """ECEF position (..., 3) at GPS time(s) t in the ECEF frame of time t."""
    t = np.asarray(t, dtype=np.float64)
    a, tk, _, ecc = _kepler(eph, np.atleast_1d(t).astype(np.float64))
    nu = np.arctan2(math.sqrt(1.0 - eph.e ** 2) * np.sin(ecc), np.cos(ecc) - eph.e)
    phi = nu + eph.omega
    s2, c2 = np.sin(2 * phi), np.cos(2 * phi)
    u = phi + eph.cus * s2 + eph.cuc * c2
    r = a * (1.0 - eph.e * np.cos(ecc)) + eph.crs * s2 + eph.crc * c2
    i = eph.i0 + eph.idot * tk + eph.cis * s2 + eph.cic * c2
    lam = eph.omega0 + (eph.omega_dot - OMEGA_E) * tk - OMEGA_E * eph.toe
    xp, yp = r * np.cos(u), r * np.sin(u)
    out = np.stack([xp * np.cos(lam) - yp * np.cos(i) * np.sin(lam),
                    xp * np.sin(lam) + yp * np.cos(i) * np.cos(lam), yp * np.sin(i)], axis=-1)
    return out.reshape(t.shape + (3,))


def sat_clock(eph: Ephemeris, t: np.ndarray | float, with_tgd: bool = True) -> np.ndarray:
    """Satellite clock offset (s) at GPS time t: polynomial + relativistic term (- TGD for L1 users)."""
    t = np.asarray(t, dtype=np.float64)
    _, _, _, ecc = _kepler(eph, np.atleast_1d(t))
    dt = np.atleast_1d(t) - eph.t_oc
    clk = eph.af0 + eph.af1 * dt + eph.af2 * dt ** 2 + F_REL * eph.e * eph.sqrt_a * np.sin(ecc)
    if with_tgd:
        clk = clk - eph.tgd
    return clk.reshape(t.shape)


# --- subframe words (IS-GPS-200 20.3.3.3 and 20.3.3.4), parity removed ------------------------

# (field, subframe, [(word, first bit, bits), ...] most significant part first, scale, signed, semicircles)
_LAYOUT = [
    ("week", 1, [(3, 1, 10)], 1.0, False, False),
    ("l2_codes", 1, [(3, 11, 2)], 1.0, False, False),
    ("ura_index", 1, [(3, 13, 4)], 1.0, False, False),
    ("health", 1, [(3, 17, 6)], 1.0, False, False),
    ("iodc", 1, [(3, 23, 2), (8, 1, 8)], 1.0, False, False),
    ("l2p_flag", 1, [(4, 1, 1)], 1.0, False, False),
    ("tgd", 1, [(7, 17, 8)], 2.0 ** -31, True, False),
    ("toc", 1, [(8, 9, 16)], 2.0 ** 4, False, False),
    ("af2", 1, [(9, 1, 8)], 2.0 ** -55, True, False),
    ("af1", 1, [(9, 9, 16)], 2.0 ** -43, True, False),
    ("af0", 1, [(10, 1, 22)], 2.0 ** -31, True, False),
    ("iode", 2, [(3, 1, 8)], 1.0, False, False),
    ("crs", 2, [(3, 9, 16)], 2.0 ** -5, True, False),
    ("delta_n", 2, [(4, 1, 16)], 2.0 ** -43, True, True),
    ("m0", 2, [(4, 17, 8), (5, 1, 24)], 2.0 ** -31, True, True),
    ("cuc", 2, [(6, 1, 16)], 2.0 ** -29, True, False),
    ("e", 2, [(6, 17, 8), (7, 1, 24)], 2.0 ** -33, False, False),
    ("cus", 2, [(8, 1, 16)], 2.0 ** -29, True, False),
    ("sqrt_a", 2, [(8, 17, 8), (9, 1, 24)], 2.0 ** -19, False, False),
    ("toe", 2, [(10, 1, 16)], 2.0 ** 4, False, False),
    ("fit_flag", 2, [(10, 17, 1)], 1.0, False, False),
    ("cic", 3, [(3, 1, 16)], 2.0 ** -29, True, False),
    ("omega0", 3, [(3, 17, 8), (4, 1, 24)], 2.0 ** -31, True, True),
    ("cis", 3, [(5, 1, 16)], 2.0 ** -29, True, False),
    ("i0", 3, [(5, 17, 8), (6, 1, 24)], 2.0 ** -31, True, True),
    ("crc", 3, [(7, 1, 16)], 2.0 ** -5, True, False),
    ("omega", 3, [(7, 17, 8), (8, 1, 24)], 2.0 ** -31, True, True),
    ("omega_dot", 3, [(9, 1, 24)], 2.0 ** -43, True, True),
    ("iode", 3, [(10, 1, 8)], 1.0, False, False),
    ("idot", 3, [(10, 9, 14)], 2.0 ** -43, True, True),
]


def encode_subframes(eph: Ephemeris) -> list[list[int]]:
    """Words 3..10 of subframes 1-3 (24 bits each) carrying `eph` at broadcast resolution."""
    words = [[0] * 8 for _ in range(3)]
    for name, sf, parts, scale, signed, semi in _LAYOUT:
        value = getattr(eph, name)
        if name == "week":
            value %= 1024
        if semi:
            value = value / GPS_PI
        nbits = sum(p[2] for p in parts)
        n = int(round(value / scale))
        lo, hi = (-(1 << (nbits - 1)), (1 << (nbits - 1)) - 1) if signed else (0, (1 << nbits) - 1)
        if not lo <= n <= hi:
            raise EphemerisError(f"PRN {eph.prn}: {name} = {getattr(eph, name)!r} does not fit {nbits} bits")
        n &= (1 << nbits) - 1
        left = nbits
        for word, first, bits in parts:
            left -= bits
            chunk = (n >> left) & ((1 << bits) - 1)
            words[sf - 1][word - 3] |= chunk << (24 - (first - 1) - bits)
    return words


def decode_subframes(prn: int, words: list[list[int]], week_hint: int) -> Ephemeris:
    """Inverse of :func:`encode_subframes`; the 10-bit week is resolved near week_hint."""
    values: dict[str, float] = {}
    for name, sf, parts, scale, signed, semi in _LAYOUT:
        nbits = sum(p[2] for p in parts)
        n = 0
        for word, first, bits in parts:
            n = n << bits | (words[sf - 1][word - 3] >> (24 - (first - 1) - bits)) & ((1 << bits) - 1)
        if signed and n >= 1 << (nbits - 1):
            n -= 1 << nbits
        v = n * scale
        values[name] = v * GPS_PI if semi else v
    if values["iode"] != values["iodc"] % 256:
        raise EphemerisError(f"PRN {prn}: IODE {values['iode']:.0f} does not match IODC {values['iodc']:.0f}")
    week = int(values["week"]) + 1024 * round((week_hint - values["week"]) / 1024)
    ints = {"week", "l2_codes", "ura_index", "health", "iodc", "l2p_flag", "iode", "fit_flag"}
    kw = {f.name: (int(values[f.name]) if f.name in ints else values[f.name]) for f in fields(Ephemeris)
          if f.name not in ("prn", "week")}
    return Ephemeris(prn=prn, week=week, **kw)


def quantised(eph: Ephemeris) -> Ephemeris:
    """The ephemeris exactly as a receiver decodes it from the broadcast words."""
    return decode_subframes(eph.prn, encode_subframes(eph), eph.week)

"""Galileo I/NAV (E1-B) pages as u-blox RXM-SFRBX hands them over, to broadcast ephemerides.

Galileo OS SIS ICD, sections 4.3 and 5.1. SFRBX gives one nominal page in 8 words of
32 bits, MSB first: the even page part in words 0-3, the odd part in words 4-7, each
part starting with its even/odd bit and its page type bit (1: alert page, skipped).
The 128-bit data word is the even part's bits 2-113 followed by the odd part's bits
2-17; the CRC-24Q covers the even part's bits 0-113 and the odd part's bits 0-81 and
stands in the odd part's bits 82-105. Word types 1-4 carry one issue of navigation
data (IODnav) of the ephemeris and clock, word type 5 the group delays, health, the
GST week and time of week. The orbit is GPS's form with Galileo's mu; the satellite
gets the id ``GALILEO_ID_OFFSET + SVID`` in the core.

Only what the tight filter needs is decoded: word types 1-5 (the ionosphere of word
type 5, NeQuick's, is not used; 6 and 10, GST-UTC and GPS-Galileo time, neither:
the filter eliminates the receiver's Galileo time offset with its own).
"""

from __future__ import annotations

from collections import Counter

from .. import _core
from .gpstime import SECONDS_PER_WEEK

GALILEO_ID_OFFSET = 32  # the core's gnss::kGalileoIdOffset
GST_WEEK_TO_GPS_WEEK = 1024  # the GST week count starts with GPS week 1024 (1999-08-22)
_PI = 3.1415926535898  # the semicircle of the ICDs


def _crc24q_table() -> list[int]:
    table = []
    for byte in range(256):
        c = byte << 16
        for _ in range(8):
            c = (c << 1) ^ (0x1864CFB if c & 0x800000 else 0)
        table.append(c & 0xFFFFFF)
    return table


_CRC_TABLE = _crc24q_table()


def crc24q(data: bytes) -> int:
    """CRC-24Q (polynomial 0x1864CFB, initial value 0, MSB first) of a byte string."""
    c = 0
    for b in data:
        c = ((c << 8) & 0xFFFFFF) ^ _CRC_TABLE[((c >> 16) ^ b) & 0xFF]
    return c


def _bits(x: int, pos: int, n: int) -> int:
    """Bits pos..pos+n-1 (0 = MSB) of a 128-bit integer (a page part, a data word)."""
    return (x >> (128 - pos - n)) & ((1 << n) - 1)


def _signed(v: int, n: int) -> int:
    return v - (1 << n) if v >> (n - 1) else v


def page_word(words32: list[int]) -> tuple[int | None, str]:
    """The 128-bit data word of one SFRBX I/NAV page, or None and why it was dropped."""
    even = (words32[0] << 96) | (words32[1] << 64) | (words32[2] << 32) | words32[3]
    odd = (words32[4] << 96) | (words32[5] << 64) | (words32[6] << 32) | words32[7]
    if _bits(even, 0, 1) != 0 or _bits(odd, 0, 1) != 1:
        return None, "even/odd parts out of order"
    if _bits(even, 1, 1) or _bits(odd, 1, 1):
        return None, "alert pages"
    covered = (_bits(even, 0, 114) << 82) | _bits(odd, 0, 82)  # 196 bits; 4 leading zeros pad to 25 bytes
    if crc24q(covered.to_bytes(25, "big")) != _bits(odd, 82, 24):
        return None, "CRC failures"
    return (_bits(even, 2, 112) << 16) | _bits(odd, 2, 16), ""


def sisa_to_ura_index(sisa: int) -> int:
    """The GPS URA index (the core's table, 2.4 m up) of the first value at least the SISA's metres
    (OS SIS ICD 5.1.12); 15 (unknown) for 'no accuracy prediction'."""
    if sisa < 50:
        m = sisa * 0.01
    elif sisa < 75:
        m = 0.5 + (sisa - 50) * 0.02
    elif sisa < 100:
        m = 1.0 + (sisa - 75) * 0.04
    elif sisa < 126:
        m = 2.0 + (sisa - 100) * 0.16
    else:
        return 15
    return next(i for i in range(15) if _core.gnss.ura_m(i) >= m)


class InavCollector:
    """Collects I/NAV words per satellite; each IODnav with word types 1-4 and a word type 5 becomes one
    ephemeris."""

    def __init__(self):
        self.words: dict[int, dict[int, int]] = {}  # svid -> word type -> latest data word
        self.sets: dict[tuple[int, int], dict[int, int]] = {}  # (svid, IODnav) -> word types 1-5
        self.bgd_e1_e5a_s: dict[int, float] = {}  # core id -> BGD(E1, E5a) of its latest complete set
        self.stats = Counter()

    def add(self, svid: int, words32: list[int]) -> None:
        self.stats["Galileo I/NAV pages"] += 1
        word, why = page_word(words32)
        if word is None:
            self.stats[f"{why} (page dropped)"] += 1
            return
        wtype = word >> 122
        if not 1 <= wtype <= 5:
            return
        got = self.words.setdefault(svid, {})
        got[wtype] = word
        iods = {_bits(got[k], 6, 10) for k in (1, 2, 3, 4) if k in got}
        if len(got) == 5 and len(iods) == 1:  # word types 1-5, the first four of one IODnav
            self.sets[(svid, iods.pop())] = dict(got)

    def ephemerides(self) -> list:
        out = []
        for (svid, _), words in sorted(self.sets.items()):
            eph = decode(svid, words)
            if eph is None:
                self.stats["inconsistent sets"] += 1
            else:
                out.append(eph)
                self.bgd_e1_e5a_s[eph.prn] = bgd_e1_e5a_s(words)
        self.stats["complete Galileo ephemerides"] = len(out)
        return out


def bgd_e1_e5a_s(w: dict[int, int]) -> float:
    """BGD(E1, E5a) of word type 5 (seconds): the group delay a user of the E1/E5a pair needs."""
    return _signed(_bits(w[5], 47, 10), 10) * 2.0 ** -32


def decode(svid: int, w: dict[int, int]):
    """An ``_core.gnss.Ephemeris`` from word types 1-5 of one IODnav (OS SIS ICD tables 60-63, 67), or None."""
    b = (lambda k, pos, n: _bits(w[k], pos, n))
    s = (lambda k, pos, n: _signed(b(k, pos, n), n))
    if b(4, 16, 6) != svid:
        return None
    e = _core.gnss.Ephemeris()
    e.prn = GALILEO_ID_OFFSET + svid
    e.iode = e.iodc = b(1, 6, 10)
    e.toe_s = b(1, 16, 14) * 60.0
    e.m0 = s(1, 30, 32) * 2.0 ** -31 * _PI
    e.e = b(1, 62, 32) * 2.0 ** -33
    e.sqrt_a = b(1, 94, 32) * 2.0 ** -19
    e.omega0 = s(2, 16, 32) * 2.0 ** -31 * _PI
    e.i0 = s(2, 48, 32) * 2.0 ** -31 * _PI
    e.omega = s(2, 80, 32) * 2.0 ** -31 * _PI
    e.idot = s(2, 112, 14) * 2.0 ** -43 * _PI
    e.omega_dot = s(3, 16, 24) * 2.0 ** -43 * _PI
    e.delta_n = s(3, 40, 16) * 2.0 ** -43 * _PI
    e.cuc, e.cus = s(3, 56, 16) * 2.0 ** -29, s(3, 72, 16) * 2.0 ** -29
    e.crc, e.crs = s(3, 88, 16) * 2.0 ** -5, s(3, 104, 16) * 2.0 ** -5
    e.ura_index = sisa_to_ura_index(b(3, 120, 8))
    e.cic, e.cis = s(4, 22, 16) * 2.0 ** -29, s(4, 38, 16) * 2.0 ** -29
    e.toc_s = b(4, 54, 14) * 60.0
    e.af0, e.af1, e.af2 = s(4, 68, 31) * 2.0 ** -34, s(4, 99, 21) * 2.0 ** -46, s(4, 120, 6) * 2.0 ** -59
    e.tgd_s = s(5, 57, 10) * 2.0 ** -32  # BGD(E1, E5b): I/NAV's clock is for the E1/E5b pair
    hs, dvs = b(5, 69, 2), b(5, 72, 1)  # E1-B signal health and data validity
    e.health = (hs << 1) | dvs
    week, tow = b(5, 73, 12) + GST_WEEK_TO_GPS_WEEK, b(5, 85, 20)
    # toe and toc are of the week they fall in: within half a week of the time of word type 5.
    e.week = week + round((tow - e.toe_s) / SECONDS_PER_WEEK)
    return e if e.sqrt_a > 0 else None

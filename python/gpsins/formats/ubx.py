"""u-blox UBX streams: RXM-RAWX measurements, RXM-SFRBX GPS LNAV subframes and Galileo I/NAV pages, NAV-PVT fixes.

A lean parser of our own rather than pyubx2: pyubx2 builds a Python object with
named attributes per frame and took 3.1 s for the walk's 134 s capture (about
80 s for an hour at 4 Hz, far longer than the filter's run on that hour); this
one finds frames with ``bytes.find``, checks each Fletcher checksum with two
NumPy reductions, and decodes each message type in one NumPy view of all its
frames (benchmarks/bench_readers.py). pyubx2 stays the independent reference in
the tests.

Damage: a stretch of bytes between good frames (bad checksum, impossible
length, truncated frame, garbage) is skipped, counted and listed with its
offset; every good frame is kept. ``ReaderError`` only when the file cannot be
read or holds no UBX frame at all.

GPS L1 C/A subframes from SFRBX (10 words of 30 bits each, right-aligned in 32
bits, data bits already un-inverted by the receiver) are parity-checked
(IS-GPS-200 20.3.5.2), sorted by subframe ID and, once subframes 1-3 of one
IODE are in, decoded by the core's IS-GPS-200 decoder from their words 3-10
(24 data bits each: the form the Superstar II's ID 22 has). Subframe 4 page 18
gives the Klobuchar coefficients. Galileo E1-B I/NAV pages go to galileo_inav.py; its satellites
take the core's ids 33-68 in ``pseudoranges`` and ``navigation``.
"""

from __future__ import annotations

import re
import struct
from collections import Counter
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from .. import _core
from .galileo_inav import GALILEO_ID_OFFSET, InavCollector
from .gpstime import SECONDS_PER_WEEK
from .common import Fixes, Navigation, Pseudoranges, ReaderError, read_bytes

SYNC = b"\xb5\x62"
MAX_PAYLOAD = 8192  # longer "lengths" are taken as a false sync
NAMES = {(0x02, 0x15): "RXM-RAWX", (0x02, 0x13): "RXM-SFRBX", (0x01, 0x07): "NAV-PVT"}
GNSS_GPS, GNSS_SBAS, GNSS_GALILEO, GNSS_BEIDOU, GNSS_QZSS, GNSS_GLONASS = 0, 1, 2, 3, 5, 6

SYSTEMS = ("gps", "galileo")  # what the core's satellite ids cover
# RAWX signal ids (UBX interface description, "GNSS signal identifiers")
SIG_GPS_L2CL, SIG_GPS_L2CM, SIG_GALILEO_E5AI, SIG_GALILEO_E5AQ = 3, 4, 3, 4


def system_of(sat_id):
    """"gps" or "galileo" of the core's satellite ids (vectorised)."""
    return np.where(np.asarray(sat_id) > GALILEO_ID_OFFSET, "galileo", "gps")


def sat_name(sat_id: int) -> str:
    """G05, E07: the RINEX name of a core satellite id."""
    return f"E{sat_id - GALILEO_ID_OFFSET:02d}" if sat_id > GALILEO_ID_OFFSET else f"G{sat_id:02d}"


RAWX_HEAD = struct.Struct("<dHbBBB2x")
RAWX_MEAS = np.dtype([("pr_m", "<f8"), ("cp_cycles", "<f8"), ("doppler_hz", "<f4"), ("gnss", "u1"), ("sv", "u1"),
                      ("sig", "u1"), ("freq", "u1"), ("lock_ms", "<u2"), ("cn0_dbhz", "u1"), ("pr_std", "u1"),
                      ("cp_std", "u1"), ("do_std", "u1"), ("trk", "u1"), ("_res", "u1")])
NAV_PVT = np.dtype([("itow_ms", "<u4"), ("year", "<u2"), ("month", "u1"), ("day", "u1"), ("hour", "u1"),
                    ("minute", "u1"), ("second", "u1"), ("valid", "u1"), ("t_acc_ns", "<u4"), ("nano", "<i4"),
                    ("fix_type", "u1"), ("flags", "u1"), ("flags2", "u1"), ("num_sv", "u1"), ("lon", "<i4"),
                    ("lat", "<i4"), ("height_mm", "<i4"), ("hmsl_mm", "<i4"), ("h_acc_mm", "<u4"),
                    ("v_acc_mm", "<u4"), ("vel_n", "<i4"), ("vel_e", "<i4"), ("vel_d", "<i4"), ("g_speed", "<i4"),
                    ("head_mot", "<i4"), ("s_acc", "<u4"), ("head_acc", "<u4"), ("pdop", "<u2"),
                    ("flags3", "<u2"), ("_res", "<u4"), ("head_veh", "<i4"), ("mag_dec", "<i2"),
                    ("mag_acc", "<u2")])
assert RAWX_MEAS.itemsize == 32 and NAV_PVT.itemsize == 92


@dataclass
class Damage:
    offset: int  # first byte skipped
    length: int  # bytes skipped
    reason: str  # why the first frame candidate in it failed


@dataclass
class UbxFile:
    """Everything read from one UBX stream."""

    rawx_t_abs: np.ndarray  # (k,) receiver time of each measurement's epoch, GPS s since the GPS epoch
    rawx: np.ndarray  # (k,) RAWX_MEAS records of all systems and signals
    pseudoranges: Pseudoranges  # GPS L1 C/A and Galileo E1 (ids 33-68), pseudorange valid
    fixes: Fixes  # NAV-PVT with a valid fix
    pvt: np.ndarray  # (m,) NAV_PVT records, all of them
    pvt_t_abs: np.ndarray  # (m,)
    navigation: Navigation  # GPS and Galileo ephemerides decoded from SFRBX, Klobuchar
    counts: Counter  # frames by message name ("CLS-ID" hex when not decoded here)
    damage: list[Damage] = field(default_factory=list)
    subframes: Counter = field(default_factory=Counter)  # GPS LNAV subframe and Galileo I/NAV page statistics
    source: str = ""
    skipped: Counter = field(default_factory=Counter)  # decoded values left out (non-finite, impossible), by reason

    def signal(self, gnss: int = GNSS_GPS, sig: int = 0) -> Pseudoranges:
        """One system's signal from RAWX with a valid pseudorange (``prn`` is the system's own satellite number);
        GPS L1 C/A is ``pseudoranges``. Galileo E1 C is ``signal(GNSS_GALILEO, 0)``."""
        sel = (self.rawx["gnss"] == gnss) & (self.rawx["sig"] == sig) & ((self.rawx["trk"] & 1) == 1)
        m = self.rawx[sel]
        return Pseudoranges(self.rawx_t_abs[sel], m["sv"].astype(int), m["pr_m"].astype(float),
                            m["doppler_hz"].astype(float), m["cn0_dbhz"].astype(float), m["lock_ms"] * 1e-3,
                            self.source)

    def second_frequency(self) -> Pseudoranges:
        """Each satellite's second code with the core's ids, the partner of ``pseudoranges`` for a dual-frequency
        ionosphere: GPS L2C (CL, else CM) and Galileo E5a (the Q pilot, else I)."""
        def first_tracked(gnss, sigs):
            for sig in sigs:
                p = self.signal(gnss, sig)
                if len(p):
                    return p
            return Pseudoranges.empty(self.source)
        return _with_galileo(first_tracked(GNSS_GPS, (SIG_GPS_L2CL, SIG_GPS_L2CM)),
                             first_tracked(GNSS_GALILEO, (SIG_GALILEO_E5AQ, SIG_GALILEO_E5AI)))

    def damage_summary(self) -> str:
        if not self.damage:
            return ""
        d = self.damage[0]
        return (f"{self.source}: skipped {len(self.damage)} damaged stretch(es), {sum(x.length for x in self.damage)} "
                f"bytes; first at offset {d.offset} ({d.reason})")


# Row 0 all ones (CK_A, the sum); row 1 ..., 3, 2, 1 (CK_B, the sum of running sums: byte i of m counts m - i times).
_WEIGHTS = np.vstack([np.ones(MAX_PAYLOAD + 4, np.int64), np.arange(MAX_PAYLOAD + 4, 0, -1, dtype=np.int64)])


def _fletcher(a: np.ndarray, lo: int, hi: int) -> tuple[int, int]:
    """UBX's 8-bit Fletcher checksum of bytes [lo, hi), both bytes from one matrix-vector product."""
    ck = _WEIGHTS[:, _WEIGHTS.shape[1] - (hi - lo):] @ a[lo:hi]
    return int(ck[0]) & 0xFF, int(ck[1]) & 0xFF


_NMEA = re.compile(rb"\$[A-Z]{2}[A-Z0-9]{2,4},[\x20-\x7e]*?\*[0-9A-F]{2}\r\n")


def _foreign(data: bytes, start: int, end: int, reason: str, damage: list, other: Counter) -> None:
    """Bytes between UBX frames: whole NMEA sentences (receivers interleave them) are counted, the rest is damage."""
    pos = start
    for m in _NMEA.finditer(data, start, end):
        if m.start() > pos:
            damage.append(Damage(pos, m.start() - pos, reason))
        other["NMEA sentences"] += 1
        pos = m.end()
    if end > pos:
        damage.append(Damage(pos, end - pos, reason))


def split_frames(data: bytes, other: Counter | None = None):
    """Good frames as (offset, class, id, payload start, payload length) and the damaged stretches;
    ``other`` counts what else is in the stream (NMEA sentences)."""
    other = Counter() if other is None else other
    a = np.frombuffer(data, np.uint8)
    n = len(data)
    frames, damage = [], []
    pos = 0  # end of the last good frame
    scan = 0
    first_fail = None
    find = data.find
    while True:
        p = find(SYNC, scan)
        if p < 0 or p + 8 > n:
            if p >= 0 and first_fail is None:
                first_fail = (p, "truncated frame header at the end")
            break
        length = data[p + 4] | (data[p + 5] << 8)
        end = p + 8 + length
        reason = None
        if length > MAX_PAYLOAD:
            reason = f"impossible length {length}"
        elif end > n:
            reason = f"truncated frame ({n - p} of {length + 8} bytes)"
        else:
            hi = p + 6 + length
            ck_a, ck_b = _fletcher(a, p + 2, hi)  # over class, id, length and payload
            if ck_a != data[hi] or ck_b != data[hi + 1]:
                reason = f"bad checksum of class {data[p + 2]:#04x} id {data[p + 3]:#04x}"
        if reason is not None:
            if first_fail is None:
                first_fail = (p, reason)
            scan = p + 1
            continue
        if p > pos:
            _foreign(data, pos, p, first_fail[1] if first_fail else "bytes outside any frame", damage, other)
        first_fail = None
        frames.append((p, data[p + 2], data[p + 3], p + 6, length))
        pos = scan = end
    if pos < n:
        _foreign(data, pos, n, first_fail[1] if first_fail else "bytes outside any frame", damage, other)
    return frames, damage


def _days_from_civil(y, m, d):
    """Days since 1970-01-01 of proleptic Gregorian dates (vectorised)."""
    y = y - (m <= 2)
    era = np.floor_divide(y, 400)
    yoe = y - era * 400
    doy = (153 * (m + np.where(m > 2, -3, 9)) + 2) // 5 + d - 1
    doe = yoe * 365 + yoe // 4 - yoe // 100 + doy
    return era * 146097 + doe - 719468


def _decode_rawx(data: bytes, frames, skipped: Counter) -> tuple[np.ndarray, np.ndarray, list[int], list[int]]:
    heads, blocks, t_rows = [], [], []
    for start, length in frames:
        if length < 16:
            continue
        tow, week, leap, n, rec_stat, _ = RAWX_HEAD.unpack_from(data, start)
        if length < 16 + 32 * n:
            continue
        if not 0.0 <= tow < SECONDS_PER_WEEK + 1.0:  # a good checksum over a bad double (NaN, inf, garbage)
            skipped["RXM-RAWX epochs with an impossible time of week (dropped)"] += 1
            continue
        heads.append((week, leap if rec_stat & 1 else None))
        blocks.append(data[start + 16:start + 16 + 32 * n])
        t_rows.append(np.full(n, week * SECONDS_PER_WEEK + tow))
    meas = np.frombuffer(b"".join(blocks), RAWX_MEAS) if blocks else np.zeros(0, RAWX_MEAS)
    t = np.concatenate(t_rows) if t_rows else np.zeros(0)
    bad = ((meas["trk"] & 1) == 1) & ~np.isfinite(meas["pr_m"])
    if bad.any():
        skipped["RXM-RAWX pseudoranges written as NaN or inf (dropped)"] = int(bad.sum())
        meas, t = meas[~bad], t[~bad]
    if not np.isfinite(meas["doppler_hz"]).all():
        meas = meas.copy()
        odd = ~np.isfinite(meas["doppler_hz"])
        skipped["RXM-RAWX Dopplers written as NaN or inf (taken as absent)"] = int(odd.sum())
        meas["doppler_hz"][odd] = np.nan
    weeks = [w for w, _ in heads]
    leaps = [x for _, x in heads if x is not None]
    return t, meas, weeks, leaps


def _decode_pvt(data: bytes, frames) -> tuple[np.ndarray, np.ndarray]:
    blocks = [data[s:s + 92] for s, n in frames if n >= 92]
    pvt = np.frombuffer(b"".join(blocks), NAV_PVT) if blocks else np.zeros(0, NAV_PVT)
    if not len(pvt):
        return pvt, np.zeros(0)
    # GPS time of week from iTOW (ms, rounded); the full time from the UTC date and time with its nanoseconds,
    # shifted by the whole seconds that make it agree with iTOW (the leap seconds: no table needed).
    days = _days_from_civil(pvt["year"].astype(np.int64), pvt["month"].astype(np.int64), pvt["day"].astype(np.int64))
    utc = (days - 3657) * 86400.0 + pvt["hour"] * 3600.0 + pvt["minute"] * 60.0 + pvt["second"] + pvt["nano"] * 1e-9
    tow = pvt["itow_ms"] * 1e-3
    week = np.floor((utc + 18.0 - tow + SECONDS_PER_WEEK / 2) / SECONDS_PER_WEEK)
    t_itow = week * SECONDS_PER_WEEK + tow
    t = utc + np.round(t_itow - utc)
    date_ok = (pvt["valid"] & 3) == 3
    t = np.where(date_ok, t, np.nan)
    return pvt, t


def pvt_fixes(pvt: np.ndarray, t: np.ndarray, source: str = "") -> Fixes:
    """NAV-PVT epochs with a valid 2D/3D fix as Fixes.

    Q from the carrier solution (fixed 1, float 2), else DGPS 4 when differential, else single 5.
    Sigmas: hAcc is a horizontal (radial) 1-sigma estimate, split evenly over north and east (hAcc/sqrt 2);
    vAcc for down; sAcc (3D speed) split over three axes (sAcc/sqrt 3).
    """
    ok = ((pvt["flags"] & 1) == 1) & np.isin(pvt["fix_type"], (2, 3, 4)) & np.isfinite(t) & \
        ((pvt["flags3"] & 1) == 0)
    p = pvt[ok]
    llh = np.column_stack([np.radians(p["lat"] * 1e-7), np.radians(p["lon"] * 1e-7), p["height_mm"] * 1e-3])
    r = _core.geodetic_to_ecef(llh) if len(p) else np.zeros((0, 3))
    carr = (p["flags"] >> 6) & 3
    q = np.where(carr == 2, 1, np.where(carr == 1, 2, np.where(p["flags"] & 2, 4, 5)))
    h = p["h_acc_mm"] * 1e-3 / np.sqrt(2.0)
    sig = np.column_stack([h, h, p["v_acc_mm"] * 1e-3])
    v = np.column_stack([p["vel_n"], p["vel_e"], p["vel_d"]]) * 1e-3
    sv = np.repeat((p["s_acc"] * 1e-3 / np.sqrt(3.0))[:, None], 3, axis=1)
    return Fixes(t[ok], np.asarray(r).reshape(-1, 3), sig, q.astype(int), p["num_sv"].astype(int), v, sv, source)


# --- GPS LNAV subframes ---------------------------------------------------------------------------------------

# IS-GPS-200 table 20-XIV: the source data bits (d1 = MSB) in each parity bit D25..D30, and whether D29* or
# D30* of the previous word takes part.
_PARITY_BITS = ((1, 2, 3, 5, 6, 10, 11, 12, 13, 14, 17, 18, 20, 23),
                (2, 3, 4, 6, 7, 11, 12, 13, 14, 15, 18, 19, 21, 24),
                (1, 3, 4, 5, 7, 8, 12, 13, 14, 15, 16, 19, 20, 22),
                (2, 4, 5, 6, 8, 9, 13, 14, 15, 16, 17, 20, 21, 23),
                (1, 3, 5, 6, 7, 9, 10, 14, 15, 16, 17, 18, 21, 22, 24),
                (3, 5, 6, 8, 9, 10, 11, 13, 15, 19, 22, 23, 24))
_PARITY_MASKS = tuple(sum(1 << (24 - b) for b in bits) for bits in _PARITY_BITS)
_PARITY_PREV = ((1, 0), (0, 1), (1, 0), (0, 1), (0, 1), (1, 0))  # (D29*, D30*)


def lnav_parity_ok(word30: int, d29: int, d30: int) -> bool:
    """IS-GPS-200 parity of one 30-bit word whose 24 data bits are the source (un-inverted) bits."""
    data = (word30 >> 6) & 0xFFFFFF
    par = 0
    for mask, (u29, u30) in zip(_PARITY_MASKS, _PARITY_PREV):
        bit = (bin(data & mask).count("1") + (d29 & u29) + (d30 & u30)) & 1
        par = (par << 1) | bit
    return par == word30 & 0x3F


def _signed(v: int, n: int) -> int:
    return v - (1 << n) if v >> (n - 1) else v


def klobuchar_from_page18(w: list[int]) -> tuple[list[float], list[float]]:
    """Subframe 4 page 18 (words 3-10 as 24-bit data): ionospheric alpha and beta (IS-GPS-200 20.3.3.5.1.7)."""
    a0, a1 = _signed((w[0] >> 8) & 0xFF, 8), _signed(w[0] & 0xFF, 8)
    a2, a3, b0 = _signed(w[1] >> 16, 8), _signed((w[1] >> 8) & 0xFF, 8), _signed(w[1] & 0xFF, 8)
    b1, b2, b3 = _signed(w[2] >> 16, 8), _signed((w[2] >> 8) & 0xFF, 8), _signed(w[2] & 0xFF, 8)
    return ([a0 * 2.0 ** -30, a1 * 2.0 ** -27, a2 * 2.0 ** -24, a3 * 2.0 ** -24],
            [b0 * 2.0 ** 11, b1 * 2.0 ** 14, b2 * 2.0 ** 16, b3 * 2.0 ** 16])


class LnavCollector:
    """Collects GPS LNAV subframes per satellite and decodes each consistent set 1-3 once."""

    def __init__(self):
        self.pending: dict[int, dict[int, list[int]]] = {}
        self.sets: dict[tuple[int, int, int], list[list[int]]] = {}  # (prn, iode, toe word) -> subframes 1-3
        self.alpha: list[float] = []
        self.beta: list[float] = []
        self.stats = Counter()

    def add(self, prn: int, words30: list[int]) -> None:
        """One subframe: ten 30-bit words as received (bits 29..0)."""
        self.stats["GPS L1 C/A subframes"] += 1
        # The receiver hands over each word with all 30 bits complemented when the previous transmitted D30 was 1
        # (data bits and parity bits alike). Against those source data bits the parity holds with
        # D29* = D29 xor D30 of the previous word as handed over, and D30* = 0 (checked on the walk's capture).
        prev = 0  # word 10 of the previous subframe ends in two zero bits
        for w in words30:
            if not lnav_parity_ok(w, ((prev >> 1) ^ prev) & 1, 0):
                self.stats["parity failures (subframe dropped)"] += 1
                return
            prev = w
        data = [(w >> 6) & 0xFFFFFF for w in words30]
        if data[0] >> 16 != 0x8B:
            self.stats["no preamble (subframe dropped)"] += 1
            return
        sfid = (data[1] >> 2) & 7
        body = data[2:]
        if sfid in (1, 2, 3):
            sats = self.pending.setdefault(prn, {})
            sats[sfid] = body
            if len(sats) == 3:
                iodc8, iode2, iode3 = sats[1][5] >> 16, sats[2][0] >> 16, sats[3][7] >> 16
                if iodc8 == iode2 == iode3:
                    self.sets[(prn, iode2, sats[2][7] >> 8)] = [sats[1], sats[2], sats[3]]
        elif sfid == 4 and (body[0] >> 16) & 0x3F == 56:
            self.alpha, self.beta = klobuchar_from_page18(body)

    def ephemerides(self, week_hint: int) -> list:
        out = []
        for (prn, _, _), words in sorted(self.sets.items()):
            try:
                out.append(_core.gnss.decode_subframes(words, prn, week_hint))
            except ValueError:
                self.stats["inconsistent sets"] += 1
        self.stats["complete ephemerides"] = len(out)
        return out


def read(path: str | Path) -> UbxFile:
    path = Path(path)
    return parse(read_bytes(path), path.name, path)


def parse(data: bytes, source: str = "<bytes>", path=None) -> UbxFile:
    counts = Counter()
    frames, damage = split_frames(data, counts)
    if not frames:
        raise ReaderError(path or source, "no UBX frame (sync B5 62 with a good checksum) in "
                          f"{len(data)} bytes", offset=0)
    by_type: dict[tuple[int, int], list[tuple[int, int]]] = {}
    for _, cls, mid, start, length in frames:
        by_type.setdefault((cls, mid), []).append((start, length))
        counts[NAMES.get((cls, mid), f"{cls:02X}-{mid:02X}")] += 1

    skipped = Counter()
    t_meas, meas, weeks, leaps = _decode_rawx(data, by_type.get((0x02, 0x15), []), skipped)
    pvt, t_pvt = _decode_pvt(data, by_type.get((0x01, 0x07), []))
    week_hint = int(np.median(weeks)) if weeks else (int(np.nanmedian(t_pvt) // SECONDS_PER_WEEK)
                                                      if np.isfinite(t_pvt).any() else None)

    lnav, inav = LnavCollector(), InavCollector()
    for start, length in by_type.get((0x02, 0x13), []):
        if length < 8:
            continue
        gnss, sv, sig, _freq, n_words = data[start:start + 5]
        if gnss == GNSS_GPS and sig == 0 and n_words == 10 and length >= 8 + 40 and 1 <= sv <= 32:
            words = struct.unpack_from("<10I", data, start + 8)
            lnav.add(sv, [w & 0x3FFFFFFF for w in words])
        elif gnss == GNSS_GALILEO and sig in (0, 1) and n_words == 8 and length >= 8 + 32 and 1 <= sv <= 36:
            inav.add(sv, list(struct.unpack_from("<8I", data, start + 8)))  # E1-B (M8 receivers give sigId 0)
    ephs = lnav.ephemerides(week_hint) if week_hint is not None else []
    if week_hint is None and lnav.sets:
        lnav.stats["sets without a GPS week (no RAWX/NAV-PVT)"] = len(lnav.sets)
    ephs += inav.ephemerides()
    nav = Navigation(ephs, lnav.alpha, lnav.beta, int(np.median(leaps)) if leaps else None, inav.bgd_e1_e5a_s)

    out = UbxFile(t_meas, meas, Pseudoranges.empty(source), pvt_fixes(pvt, t_pvt, source), pvt, t_pvt, nav, counts,
                  damage, lnav.stats + inav.stats, source, skipped)
    e1 = out.signal(GNSS_GALILEO, 0)  # the pilot E1 C where tracked, else E1 B
    out.pseudoranges = _with_galileo(out.signal(GNSS_GPS, 0), e1 if len(e1) else out.signal(GNSS_GALILEO, 1))
    return out


def _with_galileo(gps: Pseudoranges, gal: Pseudoranges) -> Pseudoranges:
    """GPS L1 C/A and Galileo E1 in one table, Galileo with the core's ids; each epoch's GPS rows first (the
    filter takes at most 32 a epoch)."""
    if not len(gal):
        return gps
    t = np.concatenate([gps.t_abs, gal.t_abs])
    system = np.concatenate([np.zeros(len(gps), int), np.ones(len(gal), int)])
    order = np.lexsort((system, t))
    cat = (lambda a, b: np.concatenate([a, b])[order])
    return Pseudoranges(t[order], cat(gps.prn, gal.prn + GALILEO_ID_OFFSET), cat(gps.pr_m, gal.pr_m),
                        cat(gps.doppler_hz, gal.doppler_hz), cat(gps.cn0_dbhz, gal.cn0_dbhz),
                        cat(gps.lock_s, gal.lock_s), gps.source)

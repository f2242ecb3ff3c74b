"""What a simulated u-blox receiver sends: UBX RXM-RAWX, RXM-SFRBX, NAV-PVT,
NAV-TIMEGPS, ESF-RAW (an F9R-like receiver with its own IMU) and NMEA GGA,
each with its emission time, from the simulator's truth and receiver model.

The contents are the same simulation the Superstar II messages carry
(pseudoranges, carrier, C/N0, the receiver's own fix, the ephemerides), in
u-blox's encoding; nothing here uses the filter or the C++ core.

Assumptions of the emulated receiver (documented, not u-blox facts):
- NAV-PVT accuracy estimates: hAcc = UERE_M * HDOP, vAcc = UERE_M * VDOP,
  sAcc from the simulated velocity noise.
- ESF-RAW: rates in the IMU's body axes (forward, right, down), the mean over
  each sampling interval (increment / period); sTtag counts microseconds
  (modulo 2^32). One ESF-RAW carries the samples of one measurement interval.
- SFRBX words: the ten 30-bit words with the 24 source data bits and the
  IS-GPS-200 parity as the project's UBX reader checks them (verified on a
  real F9P capture).
"""

from __future__ import annotations

import math
import struct
from typing import Iterator

import numpy as np

from gpsins_logger import ubx

from ..formats.messages import TimedMessage, TimedSample
from . import ephemeris
from .messages import imu_samples
from ..formats.gpstime import MILLISECONDS_PER_WEEK, SECONDS_PER_WEEK

UERE_M = 3.0
MEASUREMENT_DELAY_S = 0.020
FIX_DELAY_S = 0.060
ESF_DELAY_S = 0.002
EPHEMERIS_PERIOD_S = 30.0
GYRO_LSB_DEG_S = 2.0 ** -12
ACCEL_LSB_MPS2 = 2.0 ** -10
ESF_TYPES = (14, 13, 5, 16, 17, 18)  # gyro x, y, z; accel x, y, z
L1_HZ = 1575.42e6
GPS_EPOCH = np.datetime64("1980-01-06T00:00:00", "ns")

_PARITY_BITS = ((1, 2, 3, 5, 6, 10, 11, 12, 13, 14, 17, 18, 20, 23),
                (2, 3, 4, 6, 7, 11, 12, 13, 14, 15, 18, 19, 21, 24),
                (1, 3, 4, 5, 7, 8, 12, 13, 14, 15, 16, 19, 20, 22),
                (2, 4, 5, 6, 8, 9, 13, 14, 15, 16, 17, 20, 21, 23),
                (1, 3, 5, 6, 7, 9, 10, 14, 15, 16, 17, 18, 21, 22, 24),
                (3, 5, 6, 8, 9, 10, 11, 13, 15, 19, 22, 23, 24))
_PARITY_PREV = ((1, 0), (0, 1), (1, 0), (0, 1), (0, 1), (1, 0))


def _parity(data: int, d29: int, d30: int) -> int:
    par = 0
    for bits, (u29, u30) in zip(_PARITY_BITS, _PARITY_PREV):
        x = sum((data >> (24 - b)) & 1 for b in bits) + (d29 & u29) + (d30 & u30)
        par = (par << 1) | (x & 1)
    return par


def lnav_words(data24: list[int]) -> list[int]:
    """Ten 24-bit data words -> ten 30-bit words with parity (as the UBX reader checks them)."""
    out, prev = [], 0
    for d in data24:
        w = d << 6 | _parity(d, ((prev >> 1) ^ prev) & 1, 0)
        out.append(w)
        prev = w
    return out


def lnav_subframe(sfid: int, tow_next_s: float, body: list[int]) -> list[int]:
    """A whole subframe: TLM (preamble 8B), HOW (TOW count of the next subframe, ID), words 3-10."""
    tlm = 0x8B << 16
    how = ((int(round(tow_next_s / 6.0)) % 100800) << 7 | sfid << 2)
    return lnav_words([tlm, how, *body])


def page18(alpha, beta) -> list[int]:
    """Subframe 4 page 18 words 3-10 carrying the Klobuchar coefficients (the rest zero)."""
    a = [round(alpha[0] / 2.0 ** -30), round(alpha[1] / 2.0 ** -27), round(alpha[2] / 2.0 ** -24),
         round(alpha[3] / 2.0 ** -24)]
    b = [round(beta[0] / 2.0 ** 11), round(beta[1] / 2.0 ** 14), round(beta[2] / 2.0 ** 16), round(beta[3] / 2.0 ** 16)]
    u8 = lambda v: int(v) & 0xFF  # noqa: E731
    w = [0] * 8
    w[0] = (1 << 22) | (56 << 16) | u8(a[0]) << 8 | u8(a[1])  # data ID 01, SV ID 56 = page 18
    w[1] = u8(a[2]) << 16 | u8(a[3]) << 8 | u8(b[0])
    w[2] = u8(b[1]) << 16 | u8(b[2]) << 8 | u8(b[3])
    return w


def sfrbx(prn: int, words30: list[int]) -> bytes:
    head = struct.pack("<BBBBBBBB", 0, prn, 0, 0, len(words30), 0, 2, 0)
    return ubx.encode_frame(ubx.RXM_SFRBX, head + struct.pack(f"<{len(words30)}I", *words30))


def _std_code(sigma: float, lsb: float) -> int:
    """RAWX std fields: 4 bits; pr as 0.01 * 2^n m, cp/do linear in their LSB."""
    return int(min(15, max(0, round(sigma / lsb))))


def rawx(tow: float, week: int, leap: int, meas: list[tuple]) -> bytes:
    """meas: (prn, pseudorange m, carrier cycles, doppler Hz, cn0, lock ms)."""
    body = bytearray(struct.pack("<dHbBBB2x", tow, week, leap, len(meas), 0x01, 1))
    for prn, pr, cp, do, cn0, lock in meas:
        pr_std = int(min(15, max(0, math.ceil(math.log2(max(1.0, 0.5 / 0.01))))))
        body += struct.pack("<ddfBBBBHBBBBBx", pr, cp, do, 0, prn, 0, 0, min(int(lock), 64500),
                            int(max(0, min(255, round(cn0)))), pr_std, _std_code(0.02, 0.004), 5, 0x07)
    return ubx.encode_frame(ubx.RXM_RAWX, bytes(body))


def _utc(week: int, tow: float, leap: int):
    ns = int(round((week * SECONDS_PER_WEEK + tow - leap) * 1e9))
    whole = GPS_EPOCH + np.timedelta64(ns - ns % 1_000_000_000, "ns")
    day = whole.astype("datetime64[D]")
    y, mo, d = (int(x) for x in str(day).split("-"))
    sod = int((whole - day) / np.timedelta64(1, "s"))
    return y, mo, d, sod // 3600, sod % 3600 // 60, sod % 60, ns % 1_000_000_000


def nav_pvt(f, week: int, leap: int, speed_sigma: float) -> bytes:
    y, mo, d, hh, mm, ss, nano = _utc(week, f.tow_s, leap)
    if f.mode:
        lat, lon, h = f.llh
        fix_type = 3 if f.mode == 2 else 2
        flags = 0x01
        vn, ve, vd = f.v_ned
        h_acc, v_acc = UERE_M * f.hdop, UERE_M * f.vdop if f.mode == 2 else 50.0
        pdop = math.hypot(f.hdop, f.vdop)
    else:
        lat = lon = h = vn = ve = vd = 0.0
        fix_type, flags, h_acc, v_acc, pdop = 0, 0, 1e5, 1e5, 99.99
    gspeed = math.hypot(vn, ve)
    head = math.degrees(math.atan2(ve, vn)) % 360.0
    itow = int(round(f.tow_s * 1000)) % MILLISECONDS_PER_WEEK
    body = struct.pack("<IHBBBBBBIiBBBBiiiiIIiiiiiIIHH4xiHH", itow, y, mo, d, hh,
                       mm, ss, 0x07, 20, nano, fix_type, flags, 0xE0, f.sats, round(math.degrees(lon) * 1e7),
                       round(math.degrees(lat) * 1e7), round(h * 1e3), round(h * 1e3), round(min(h_acc, 4e6) * 1e3),
                       round(min(v_acc, 4e6) * 1e3), round(vn * 1e3), round(ve * 1e3), round(vd * 1e3),
                       round(gspeed * 1e3), round(head * 1e5), round(speed_sigma * 1e3), round(5.0 * 1e5),
                       min(9999, round(pdop * 100)), 0, 0, 0, 0)
    return ubx.encode_frame(ubx.NAV_PVT, body)


def nav_timegps(tow: float, week: int, leap: int) -> bytes:
    itow = int(round(tow * 1000))
    ftow = int(round((tow * 1000 - itow) * 1e6))
    body = struct.pack("<IihbBI", itow % MILLISECONDS_PER_WEEK, ftow, week, leap, 0x07, 20)
    return ubx.encode_frame(ubx.NAV_TIMEGPS, body)


def esf_raw(rates: np.ndarray, accel: np.ndarray, tags: np.ndarray) -> bytes:
    body = bytearray(4)
    for w, a, tag in zip(rates, accel, tags):
        values = [*(np.degrees(w) / GYRO_LSB_DEG_S), *(a / ACCEL_LSB_MPS2)]
        for typ, v in zip(ESF_TYPES, values):
            c = int(max(-(1 << 23), min((1 << 23) - 1, round(float(v)))))
            body += struct.pack("<II", (c & 0xFFFFFF) | typ << 24, int(tag) & 0xFFFFFFFF)
    return ubx.encode_frame(ubx.ESF_RAW, bytes(body))


def gga(f, leap: int, week: int) -> bytes:
    """An NMEA GGA sentence of the fix (u-blox receivers send NMEA on the same port by default)."""
    _, _, _, hh, mm, ss, nano = _utc(week, f.tow_s, leap)
    if f.mode:
        lat, lon = math.degrees(f.llh[0]), math.degrees(f.llh[1])
        pos = (f"{int(abs(lat)):02d}{abs(lat) % 1 * 60:08.5f},{'N' if lat >= 0 else 'S'},"
               f"{int(abs(lon)):03d}{abs(lon) % 1 * 60:08.5f},{'E' if lon >= 0 else 'W'},1,{f.sats:02d},"
               f"{f.hdop:.2f},{f.llh[2]:.1f},M,0.0,M,,")
    else:
        pos = ",,,,0,00,99.99,,,,,,"
    body = f"GPGGA,{hh:02d}{mm:02d}{ss:02d}.{nano // 10_000_000:02d},{pos}"
    cs = 0
    for ch in body.encode("ascii"):
        cs ^= ch
    return f"${body}*{cs:02X}\r\n".encode("ascii")


def _lock_ms(tracked: np.ndarray, dt: float) -> np.ndarray:
    run = np.zeros(tracked.shape)
    for k in range(1, tracked.shape[0]):
        run[k] = np.where(tracked[k] & tracked[k - 1], run[k - 1] + dt * 1000.0, 0.0)
    return run


def messages(sim, sensors: bool = True) -> list[TimedMessage]:
    """Every message the receiver can send, at its highest rates, in time order. msg_id is the
    UBX name ("RXM-RAWX", ...) or "NMEA"; tow_s is set for RAWX (rate decimation)."""
    g, sc = sim.gnss, sim.scenario
    leap = sc.gnss.leap_seconds
    out: list[TimedMessage] = []
    dt = 1.0 / sc.gnss.measurement_rate_hz
    lock = _lock_ms(g.tracked, dt)
    doppler = g.doppler_hz()
    for k in range(len(g.t)):
        meas = [(int(j + 1), float(g.pseudorange_m[k, j]), float(g.carrier_cycles[k, j]),
                 float(doppler[k, j]) if np.isfinite(doppler[k, j]) else 0.0, float(g.cn0_dbhz[k, j]),
                 float(lock[k, j])) for j in np.flatnonzero(g.tracked[k])]
        t = float(g.t[k]) + MEASUREMENT_DELAY_S
        out.append(TimedMessage(t, "RXM-RAWX", rawx(float(g.tow_rx[k]), g.week, leap, meas), float(g.tow_rx[k])))
    speed_sigma = 0.05 * math.sqrt(3.0)
    sent_eph: dict[int, float] = {}
    for f in g.fixes:
        t = f.t + FIX_DELAY_S
        out.append(TimedMessage(t, "NAV-PVT", nav_pvt(f, g.week, leap, speed_sigma * min(f.hdop, 10.0))))
        out.append(TimedMessage(t, "NAV-TIMEGPS", nav_timegps(f.tow_s, g.week, leap)))
        out.append(TimedMessage(t, "NMEA", gga(f, leap, g.week)))
        # Subframes 1-3 of each tracked satellite as they would arrive: a set every 30 s.
        for prn in f.prns:
            if f.t - sent_eph.get(prn, -math.inf) >= EPHEMERIS_PERIOD_S and prn in g.ephemerides:
                body = ephemeris.encode_subframes(g.ephemerides[prn])
                for sf in range(3):
                    words = lnav_subframe(sf + 1, f.tow_s + 6.0 * (sf + 1), body[sf])
                    out.append(TimedMessage(t, "RXM-SFRBX", sfrbx(prn, words)))
                out.append(TimedMessage(t, "RXM-SFRBX", sfrbx(prn, lnav_subframe(
                    4, f.tow_s + 24.0, page18(g.ion_alpha, g.ion_beta)))))
                sent_eph[prn] = f.t
    if sensors:
        out += esf_messages(sim)
    out.sort(key=lambda m: m.t)
    return out


def esf_messages(sim) -> list[TimedMessage]:
    """ESF-RAW batches: the IMU samples of each measurement interval in one message."""
    period = np.median(np.diff(sim.imu_t)) if len(sim.imu_t) > 1 else 1.0 / sim.imu_rate_hz
    rates = sim.imu_dtheta / period
    accel = sim.imu_dv / period
    # The sensor's time tag: its own sample count in microseconds of its nominal period.
    tags = np.round(np.arange(1, len(sim.imu_t) + 1) * 1e6 / sim.imu_rate_hz).astype(np.int64) % (1 << 32)
    interval = 1.0 / sim.scenario.gnss.measurement_rate_hz
    batch = np.floor(sim.imu_t / interval).astype(np.int64)
    cut = np.flatnonzero(np.diff(batch)) + 1
    out = []
    for a, b in zip(np.concatenate([[0], cut]), np.concatenate([cut, [len(batch)]])):
        if b > a:
            out.append(TimedMessage(float(sim.imu_t[b - 1]) + ESF_DELAY_S, "ESF-RAW",
                                    esf_raw(rates[a:b], accel[a:b], tags[a:b])))
    return out


class UbloxSimSource:
    """A simulation as a u-blox receiver's messages (``messages`` above) for the pty emulators; the
    IMU samples stay available for a BP3010 on another port."""

    def __init__(self, simulation, sensors: bool = True):
        self.sim = simulation
        self.duration_s = float(simulation.scenario.duration_s)
        self._messages = messages(simulation, sensors)

    def gps_messages(self) -> Iterator[TimedMessage]:
        return iter(self._messages)

    def imu_samples(self, rate_hz: int, t0: float = 0.0) -> Iterator[TimedSample]:
        return imu_samples(self.sim, rate_hz, t0)

"""Decoded measurements of a logger session whose GPS receiver is a u-blox (UBX records).

The same stage as :mod:`measurements` for the Superstar II, with the same
result type, so alignment and the filters run unchanged:

- GPS time for the alignment: each RXM-RAWX's receiver time of week against
  its stamp (the measurement epoch, as ID 23 is for the Superstar II); a
  session without RAWX uses NAV-PVT's epochs (loose mode only).
- Loose: NAV-PVT fixes with a valid fix. The filter weighs a fix by
  ``fix_uere_m * HDOP / sqrt 2`` per horizontal axis and ``fix_uere_m * VDOP``
  down; NAV-PVT gives the receiver's own hAcc and vAcc, so HDOP and VDOP are
  set to hAcc / fix_uere_m and vAcc / fix_uere_m: the filter then uses the
  receiver's estimates exactly.
- Tight: RAWX GPS L1 C/A pseudoranges with the ephemerides decoded from the
  SFRBX LNAV subframes and the Klobuchar coefficients of subframe 4 page 18.
- IMU: ESF-RAW (the receiver's own sensors: rates in deg/s * 2^-12 and
  accelerations in m/s^2 * 2^-10, each sample's sensor time tag), or a BP3010
  on another port when the session has one. The sensor time tag plays the
  BP3010 counter's part: a sample's index is its tag's distance from the
  previous one in units of the median tag step, so a dropped message leaves a
  gap of the right length, and the alignment sees an 8-bit counter made of it.
  Increments are rate x sampling period (the rates are the interval's means).
"""

from __future__ import annotations

import struct
from collections import Counter
from dataclasses import dataclass
from pathlib import Path

import numpy as np
from gpsins_logger import ubx

from . import logs
from . import layouts
from ..formats.gpstime import SECONDS_PER_WEEK
from .measurements import Decoded, read_counting_damage, valid_imu
from ..formats import ubx as ubx_reader
from ..formats import common

ESF_GYRO = {14: 0, 13: 1, 5: 2}
ESF_ACCEL = {16: 0, 17: 1, 18: 2}
GYRO_LSB_RAD_S = np.radians(2.0 ** -12)
ACCEL_LSB_MPS2 = 2.0 ** -10


def is_ublox(directory: str | Path) -> bool:
    """Does the session's GPS sensor record a u-blox receiver?"""
    import json

    try:
        side = json.loads((Path(directory) / "session.json").read_text(encoding="utf-8"))
        return side["sensors"]["gps"]["device"] == "ublox"
    except (OSError, ValueError, KeyError, TypeError):
        return False


@dataclass
class Klobuchar:
    alpha: tuple
    beta: tuple


@dataclass
class UbloxGps:
    """The GPS side, in the shape replay expects (see measurements.GpsMeasurements)."""

    week: int
    tow: np.ndarray  # (n,) RAWX receiver time of week, s (continuing past a week end)
    stamps: np.ndarray  # (n,) the RAWX records' stamps
    fixes: np.ndarray  # (m, 10) [t, r xyz, v xyz, hdop, vdop, mode]
    fix_sats: np.ndarray
    pseudoranges: np.ndarray  # (k, 5) [t, prn, pr, cn0, lock ms]
    ephemerides: list
    iono: Klobuchar | None
    leap_s: int | None
    ubx: ubx_reader.UbxFile | None = None

    def pseudorange_table(self) -> np.ndarray:
        return self.pseudoranges

    def decoded_ephemerides(self, skipped: Counter | None = None) -> list:
        return list(self.ephemerides)


def decode_gps(files: logs.SensorFiles, skipped: Counter, fix_uere_m: float = 3.0) -> UbloxGps:
    rawx_t, rawx_stamps, pvt_stamps = [], [], []
    for fr, st in files.iter_frames():
        if (fr[2], fr[3]) == ubx.RXM_RAWX and len(fr) >= 8 + 16:
            tow, week = struct.unpack_from("<dH", fr, 6)
            rawx_t.append(week * SECONDS_PER_WEEK + tow)
            rawx_stamps.append(st)
        elif (fr[2], fr[3]) == ubx.NAV_PVT and len(fr) >= 8 + 92:
            pvt_stamps.append(st)
    try:
        u = ubx_reader.parse(b"".join(s.frame_data.tobytes() for s in files.scans), "gps records")
    except common.ReaderError as e:
        raise layouts.LogError(f"no usable UBX records in the session ({e})") from None
    if rawx_t:
        t_abs, t_stamps = np.array(rawx_t), np.array(rawx_stamps)
    else:
        # Without RAWX the clock is fitted on NAV-PVT's epochs (with a valid date and time):
        # loose mode only, and --gps-latency is NAV-PVT's delay after the epoch.
        ok = np.isfinite(u.pvt_t_abs)
        if ok.sum() < 3:
            raise layouts.LogError("no RXM-RAWX and fewer than 3 NAV-PVT with a valid time in the session: GPS time "
                                   "is unknown (enable RXM-RAWX or NAV-PVT)")
        t_abs, t_stamps = u.pvt_t_abs[ok], np.array(pvt_stamps)[ok]
        skipped["gps: no RXM-RAWX; GPS time from NAV-PVT epochs, no pseudoranges"] += 1
    week = int(t_abs[0] // SECONDS_PER_WEEK)
    t0 = week * SECONDS_PER_WEEK
    tow = t_abs - t0

    f = u.fixes
    ok = ((u.pvt["flags"] & 1) == 1) & np.isin(u.pvt["fix_type"], (2, 3, 4)) & np.isfinite(u.pvt_t_abs) & \
        ((u.pvt["flags3"] & 1) == 0)
    fix_type = u.pvt["fix_type"][ok]
    dropped = len(u.pvt) - len(f)
    if dropped:
        skipped["gps: NAV-PVT without a valid fix"] += dropped
    h_acc = f.sigma_ned_m[:, 0] * np.sqrt(2.0)
    v_acc = f.sigma_ned_m[:, 2]
    fixes = np.column_stack([f.t_abs - t0, f.r_ecef, f.v_ecef(), np.maximum(h_acc / fix_uere_m, 0.01),
                             np.maximum(v_acc / fix_uere_m, 0.01), np.where(fix_type == 2, 3, 2)]).reshape(-1, 10)
    for k, v in u.subframes.items():
        if "dropped" in k or "inconsistent" in k:
            skipped[f"gps: {k}"] += v
    nav = u.navigation
    iono = Klobuchar(tuple(nav.alpha), tuple(nav.beta)) if len(nav.alpha) == 4 else None
    return UbloxGps(week, tow, t_stamps, fixes, f.ns.astype(int), u.pseudoranges.table(t0),
                    nav.ephemerides, iono, nav.leap_s, u)


@dataclass
class EsfSamples:
    tags: np.ndarray  # (n,) sensor time tags (uint32)
    stamps: np.ndarray  # (n,) stamp of the ESF-RAW that carried each sample
    rate_rad_s: np.ndarray  # (n, 3)
    accel_mps2: np.ndarray  # (n, 3)


def esf_samples(files: logs.SensorFiles, skipped: Counter) -> EsfSamples | None:
    """Complete samples (three gyro and three accelerometer axes sharing a time tag) from ESF-RAW."""
    tags, stamps, rates, accel = [], [], [], []
    for fr, st in files.iter_frames():
        if (fr[2], fr[3]) != ubx.ESF_RAW:
            continue
        n = (len(fr) - 8 - 4) // 8
        if n <= 0:
            continue
        blocks = np.frombuffer(fr, dtype="<u4", count=2 * n, offset=10).reshape(n, 2)
        typ = blocks[:, 0] >> 24
        val = (blocks[:, 0] & 0xFFFFFF).astype(np.int64)
        val = np.where(val >= 1 << 23, val - (1 << 24), val)
        sample: dict[int, dict[int, int]] = {}
        for t, ty, v in zip(blocks[:, 1], typ, val):
            sample.setdefault(int(t), {})[int(ty)] = int(v)
        for t, vals in sample.items():
            if not all(k in vals for k in (*ESF_GYRO, *ESF_ACCEL)):
                skipped["imu: ESF-RAW samples without all six axes"] += 1
                continue
            tags.append(t)
            stamps.append(st)
            rates.append([vals[k] for k in ESF_GYRO])
            accel.append([vals[k] for k in ESF_ACCEL])
    if not tags:
        return None
    return EsfSamples(np.array(tags, dtype=np.int64), np.array(stamps), np.array(rates) * GYRO_LSB_RAD_S,
                      np.array(accel) * ACCEL_LSB_MPS2)


def esf_imu_log(e: EsfSamples, gps_s_per_stamp_s: float = 1.0) -> layouts.ImuLog:
    """The ESF samples as an IMU log: increments, and a counter made of the time tags.
    The sampling rate is counted against GPS time (the stamps' span scaled by
    gps_s_per_stamp_s: 1 on a vehicle, the speed on a faster-than-real-time
    emulation) and rounded to whole Hz."""
    step_raw = np.diff(e.tags) % (1 << 32)
    step = float(np.median(step_raw[step_raw > 0])) if np.any(step_raw > 0) else 1.0
    steps = np.round(step_raw / step).astype(np.int64)
    n = np.concatenate([[0], np.cumsum(steps)])
    span = float(e.stamps[-1] - e.stamps[0]) * gps_s_per_stamp_s
    rate = max(1, int(round(n[-1] / span))) if span > 0 else 1
    period = 1.0 / rate
    return layouts.ImuLog(e.stamps, e.rate_rad_s * period, e.accel_mps2 * period,
                          np.full(len(n), 1, np.uint8), (n & 0xFF).astype(np.uint8), rate)


def decode_session(directory: str | Path, fix_uere_m: float = 3.0) -> Decoded:
    session, skipped = read_counting_damage(directory, imu_frames=False)
    gps_files = session.sensors.get("gps")
    if gps_files is None or not gps_files.count:
        raise layouts.LogError(f"{directory}: no GPS records")
    gps = decode_gps(gps_files, skipped, fix_uere_m)
    if "imu" in session.sensors and session.sensors["imu"].count:
        imu = valid_imu(session, skipped)  # a BP3010 on its own port
    else:
        esf = esf_samples(gps_files, skipped)
        if esf is None:
            raise layouts.LogError(f"{directory}: no IMU: neither an imu sensor nor ESF-RAW records")
        # GPS seconds per stamp second from the RAWX epochs (their delays are small against the span).
        ratio = float((gps.tow[-1] - gps.tow[0]) / (gps.stamps[-1] - gps.stamps[0])) if len(gps.tow) > 1 else 1.0
        imu = esf_imu_log(esf, ratio if np.isfinite(ratio) and ratio > 0 else 1.0)
    return Decoded(gps, imu, skipped, session.sidecar, Path(directory))

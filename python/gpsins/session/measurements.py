"""Decoded measurements of a logger session: the stage between records on disk
and time alignment.

GPS: measurement blocks (ID 23: time of week, stamp, pseudoranges), the
receiver's fixes (ID 21 time, week and ECEF position/velocity paired with the
ID 20 that carries HDOP, VDOP and the navigation mode), ephemeris subframes
(ID 22), Klobuchar coefficients (ID 75) and the GPS week (ID 21/49).
IMU: increments, status, counters and stamps; frames whose valid bit is clear
or that flag a range or test failure are left out and counted.

Nothing good is dropped silently: every skipped record is counted in
``skipped`` with the reason.
"""

from __future__ import annotations

from array import array
from collections import Counter
from dataclasses import dataclass, field, replace
from pathlib import Path

import numpy as np
from gpsins_logger import bp3010, superstar2 as ss2

from . import logs
from . import layouts
from .. import timing
from ..nav.inputs import PseudorangeColumns
from ..formats.gpstime import SECONDS_PER_WEEK

FIX_PAIR_TOLERANCE_S = 0.05  # an ID 20 and its ID 21 describe the same epoch (times to 1 ms)
# A receiver measures on its epoch grid: the gpsd Superstar II sample's times of week sit 3 us off whole
# seconds; clock slews move them by a millisecond at most.
TOW_GRID_TOLERANCE_S = 2e-3
TOW_DAMAGED = "gps: measurement blocks whose time of week does not fit between its neighbours (damaged)"
GPS_EPOCH = np.datetime64("1980-01-06T00:00:00", "ms")


@dataclass
class GpsMeasurements:
    week: int  # week of the first measurement block; times below count from its start
    tow: np.ndarray  # (n,) receiver time of each ID 23, s (continuing past the week end)
    stamps: np.ndarray  # (n,) system stamps
    pseudoranges: PseudorangeColumns  # [t, prn, pseudorange m, C/N0 dB-Hz, lock count]: GPS satellites of every block
    fixes: np.ndarray  # (m, 10) [t, r xyz, v xyz, hdop, vdop, mode], t in the same time base
    fix_sats: np.ndarray  # (m,) satellites used
    ephemerides: list[tuple[float, ss2.EphemerisWords]]  # (receive time, words)
    iono: ss2.IonoUtc | None
    leap_s: int | None
    # Where GPS time went back (a receiver restart): (GPS record index of the first block after,
    # system time between the two blocks, time of week before, after).
    restarts: list[tuple[int, float, float, float]] = field(default_factory=list)

    def pseudorange_table(self) -> np.ndarray:
        """(k, 5) [t, prn, pseudorange m, C/N0 dB-Hz, lock count]: GPS satellites of every block."""
        return self.pseudoranges[:]

    def decoded_ephemerides(self, skipped: Counter | None = None) -> list:
        """The ID 22 subframes decoded (IS-GPS-200) by the core; inconsistent sets are counted and left out."""
        from .. import _core

        out = []
        for _, w in self.ephemerides:
            try:
                out.append(_core.gnss.decode_subframes(w.subframes, w.prn, self.week))
            except ValueError:
                if skipped is not None:
                    skipped["gps: ephemerides with inconsistent IODE/IODC"] += 1
        return out


@dataclass
class Decoded:
    gps: GpsMeasurements
    imu: layouts.ImuLog  # valid frames only
    skipped: Counter = field(default_factory=Counter)
    sidecar: dict = field(default_factory=dict)
    directory: Path | None = None


def bad_imu(status: np.ndarray) -> np.ndarray:
    bad = bp3010.STATUS_GYRO_OVERRANGE | bp3010.STATUS_ACCEL_OVERRANGE | bp3010.STATUS_BIT_FAILURE
    return ((status & bp3010.STATUS_VALID) == 0) | ((status & bad) != 0)


class _Observations:
    """The GPS observations of the measurement blocks as they are decoded: gathered as flat doubles
    (block index, prn, pseudorange, C/N0, lock count), moved every ``CHUNK`` rows into columns of the
    protocol's own exact types (C/N0 in quarter dB-Hz and the lock count are bytes, so float32 holds
    them exactly). A day's 8 million observations then take 25 bytes each, and no whole float table
    is ever built."""

    CHUNK = 1 << 16

    def __init__(self):
        self._rows = array("d")
        self._parts: list[list] = []

    def add(self, block: int, prn: int, pseudorange_m: float, cn0_dbhz: float, lock: int) -> None:
        self._rows.extend((block, prn, pseudorange_m, cn0_dbhz, lock))
        if len(self._rows) >= 5 * self.CHUNK:
            self._flush()

    def _flush(self) -> None:
        a = np.frombuffer(self._rows, dtype=np.float64).reshape(-1, 5)
        self._parts.append([a[:, 0].astype(np.uint32), a[:, 1].astype(np.uint8), a[:, 2].copy(),
                            a[:, 3].astype(np.float32), a[:, 4].astype(np.float32)])
        del a
        self._rows = array("d")

    def columns(self, block_times: np.ndarray) -> PseudorangeColumns:
        """The observations by columns, each block's index replaced by its time."""
        self._flush()
        parts, self._parts = self._parts, []
        cols = []
        for j in range(5):  # one column at a time, each part's piece dropped once copied
            cols.append(np.concatenate([p[j] for p in parts]))
            for p in parts:
                p[j] = None
        cols[0] = block_times[cols[0]]
        return PseudorangeColumns(*cols)


PER_EPOCH = (ss2.ID_MEASUREMENTS, ss2.ID_NAV_USER, ss2.ID_NAV_ECEF, ss2.ID_RECEIVER_STATUS)


def decode_gps(files: logs.SensorFiles, skipped: Counter, rows: tuple[int, int] | None = None) -> GpsMeasurements:
    """The GPS records decoded; ``rows``: only the epochs (measurements, fixes, week) of records
    rows[0] to rows[1] - 1 (one stretch of a restarted receiver), the ephemerides and ionosphere of all."""
    tows, tstamps, block_rows = array("d"), array("d"), array("q")
    obs = _Observations()
    nav_user: list[tuple[float, ss2.NavUser]] = []
    nav_ecef: list[tuple[float, ss2.NavEcef]] = []
    ephs, iono, leap = [], None, None
    weeks = []  # (index in blocks when seen, week)
    for row, (fr, st) in enumerate(files.iter_frames()):
        try:
            msg_id, payload = ss2.decode_frame(fr)
            if rows is not None and msg_id in PER_EPOCH and not rows[0] <= row < rows[1]:
                continue
            if msg_id == ss2.ID_MEASUREMENTS:
                m = ss2.Measurements.decode(payload)
                k = len(tows)
                for o in m.observations:
                    if not o.sbas:
                        obs.add(k, o.prn, m.pseudorange_m(o), o.cn0_dbhz, o.lock_count)
                tows.append(m.tow_s)
                tstamps.append(st)
                block_rows.append(row)
            elif msg_id == ss2.ID_NAV_USER:
                nav_user.append((st, ss2.NavUser.decode(payload)))
            elif msg_id == ss2.ID_NAV_ECEF:
                e = ss2.NavEcef.decode(payload)
                nav_ecef.append((st, e))
                weeks.append((len(tows), e.week))
            elif msg_id == ss2.ID_RECEIVER_STATUS:
                weeks.append((len(tows), ss2.ReceiverStatus.decode(payload).week))
            elif msg_id == ss2.ID_EPHEMERIS:
                ephs.append((st, ss2.EphemerisWords.decode(payload)))
            elif msg_id == ss2.ID_IONO_UTC:
                iono = ss2.IonoUtc.decode(payload)
                leap = iono.leap_s
            elif msg_id == ss2.ID_LEAP:
                leap = ss2.LeapSeconds.decode(payload).leap_s
        except ss2.ProtocolError:
            skipped["gps frames that do not decode"] += 1
    if not tows:
        raise layouts.LogError("no GPS measurement blocks (ID 23) in the session: GPS time is unknown")
    if not weeks:
        raise layouts.LogError("no GPS week in the session (ID 21 or 49)")
    tow, stamps = np.frombuffer(tows, dtype=np.float64), np.frombuffer(tstamps, dtype=np.float64)
    good = ~implausible_tows(tow, stamps)
    if not good.all():
        skipped[TOW_DAMAGED] += int((~good).sum())
    tow, stamps, block_rows = tow[good], stamps[good], np.frombuffer(block_rows, dtype=np.int64)[good]
    back = np.flatnonzero(_wrap_week(np.diff(tow)) < -TOW_GRID_TOLERANCE_S)
    restarts = [(int(block_rows[k + 1]), 0.5 * (stamps[k] + stamps[k + 1]), float(tow[k]), float(tow[k + 1]))
                for k in back]
    # Time of week continues past a week rollover (tow drops by a week).
    rollovers = np.concatenate([[0], np.cumsum(np.diff(tow) < -SECONDS_PER_WEEK / 2)])
    tow = tow + SECONDS_PER_WEEK * rollovers
    # The week of the first block: what most week messages say, less the rollovers before them.
    good_before = np.concatenate([[0], np.cumsum(good)])[[i for i, _ in weeks]]
    vals, counts = np.unique(np.array([w for _, w in weeks]) - rollovers[np.maximum(good_before - 1, 0)],
                             return_counts=True)
    week = int(vals[np.argmax(counts)])
    block_t = np.full(len(good), np.nan)
    block_t[good] = tow
    prs = obs.columns(block_t)
    if not good.all():
        prs = prs[np.isfinite(prs.t)]

    # Pair each ID 21 with the ID 20 of the same epoch, by GPS time (stamps can jump with the clock).
    fixes, sats = [], []
    ecef_t = np.array([(e.week - week) * SECONDS_PER_WEEK + e.tow_s for _, e in nav_ecef]).reshape(-1)
    user_t = _nav_user_times(nav_user, nav_ecef, ecef_t, leap, week, skipped)
    order = np.argsort(user_t, kind="stable")
    for (_st, e), t in zip(nav_ecef, ecef_t):
        j = np.searchsorted(user_t[order], t)
        near = [order[i] for i in (j - 1, j) if 0 <= i < len(order)]
        k = min(near, key=lambda i: abs(user_t[i] - t)) if near else -1
        if k < 0 or not abs(user_t[k] - t) <= FIX_PAIR_TOLERANCE_S:
            skipped["ID 21 fixes without an ID 20 of the same epoch (no HDOP/VDOP/mode)"] += 1
            continue
        u = nav_user[k][1]
        mode = u.nav_mode if u.has_fix and np.any([e.x_m, e.y_m, e.z_m]) else 0
        mode = {4: 2, 5: 3}.get(mode, mode)
        fixes.append([t, e.x_m, e.y_m, e.z_m, e.vx_mps, e.vy_mps, e.vz_mps, max(u.hdop, 0.1), max(u.vdop, 0.1),
                      mode])
        sats.append(u.sats_used)
    return GpsMeasurements(week, tow, stamps.copy(), prs, np.array(fixes).reshape(-1, 10),
                           np.array(sats, dtype=int), ephs, iono, leap, restarts)


def _wrap_week(x: np.ndarray) -> np.ndarray:
    return (x + SECONDS_PER_WEEK / 2) % SECONDS_PER_WEEK - SECONDS_PER_WEEK / 2


def implausible_tows(tow: np.ndarray, stamps: np.ndarray) -> np.ndarray:
    """Measurement blocks damaged in a way their checksum let through: a time of week that does not
    fit between its two neighbours on the receiver's epoch grid, while those two agree with each
    other. Left in, such a time moves the week or the track. A damaged stamp (time on the grid) is
    the alignment's to catch; a lasting change (a receiver restart, a clock step) is no single record.
    The first and last block have one pair of neighbours: off the grid against it, or off it in time
    minus stamp by more than any host delay."""
    n = len(tow)
    bad = np.zeros(n, bool)
    step = _wrap_week(np.diff(tow))
    if n < 3 or not (step > 0).any():
        return bad
    epoch = float(np.median(step[step > 0]))

    def on_grid(x):  # a whole positive number of epochs
        m = np.round(x / epoch)
        return (m >= 1) & (np.abs(x - m * epoch) <= TOW_GRID_TOLERANCE_S)

    grid = on_grid(step)  # block k to k + 1
    neighbours_agree = on_grid(_wrap_week(tow[2:] - tow[:-2]))  # block k - 1 to k + 1
    bad[1:-1] = neighbours_agree & ~(grid[:-1] & grid[1:])
    de = np.abs(np.diff(_wrap_week(tow - stamps - (tow[0] - stamps[0]))))
    bad[0] = grid[1] and not bad[1] and (not grid[0] or de[0] > timing.LATE_S)
    bad[-1] = grid[-2] and not bad[-2] and (not grid[-1] or de[-1] > timing.LATE_S)
    return bad


def utc_seconds(u: ss2.NavUser) -> float:
    """UTC of an ID 20 as seconds since the GPS epoch (no leap seconds); NaN if its date is not valid."""
    try:
        day = np.datetime64(f"{u.year:04d}-{u.month:02d}-{u.day:02d}", "ms")
    except ValueError:
        return float("nan")
    if not (0 <= u.hour < 24 and 0 <= u.minute < 60 and 0 <= u.second < 61):
        return float("nan")
    return float((day - GPS_EPOCH) / np.timedelta64(1, "s")) + 3600.0 * u.hour + 60.0 * u.minute + u.second


def _nav_user_times(nav_user: list, nav_ecef: list, ecef_t: np.ndarray, leap: int | None, week: int,
                    skipped: Counter) -> np.ndarray:
    """GPS time of each ID 20 in the fixes' time base. Without a leap-second count from the
    receiver (ID 75/113): the whole number of seconds that lines most ID 20s up with the ID 21
    nearest by stamp (the receiver sends the pair together; a clock step mispairs only a few)."""
    utc = np.array([utc_seconds(u) for _, u in nav_user]).reshape(-1) - week * SECONDS_PER_WEEK
    if np.isnan(utc).any():
        skipped["ID 20 with an invalid date (not paired)"] += int(np.isnan(utc).sum())
    if leap is None and len(utc) and len(ecef_t):
        ustamps = np.array([st for st, _ in nav_user])
        k = np.clip(np.searchsorted(ustamps, [st for st, _ in nav_ecef]), 0, len(ustamps) - 1)
        diff = np.round(ecef_t - utc[k])
        vals, counts = np.unique(diff[np.isfinite(diff)], return_counts=True)
        leap = int(vals[np.argmax(counts)]) if len(vals) else 0
    return utc + (leap or 0)


def read_counting_damage(directory: str | Path, imu_frames: bool = True) -> tuple[logs.SessionLog, Counter]:
    """A session's record files, and what the readers skipped in them, by reason
    (imu_frames: see :func:`logs.read_session`)."""
    session = logs.read_session(directory, imu_frames)
    skipped: Counter = Counter()
    for name, sensor in session.sensors.items():
        st = sensor.stats()
        if st["discarded_bytes"]:
            skipped[f"{name}: bytes between frames (garbage or damaged frames)"] += st["discarded_bytes"]
        if st.get("bad_stamps"):
            skipped[f"{name}: records with impossible stamps (their bytes are counted above)"] += st["bad_stamps"]
        if st["truncated_tail_bytes"]:
            skipped[f"{name}: truncated last record, bytes"] += st["truncated_tail_bytes"]
    return session, skipped


def decode_session(directory: str | Path) -> Decoded:
    """The session decoded for replay, whole; its IMU is decoded as it is read (no frames kept)."""
    return _decode(directory, split=False)[0]


def decode_stretches(directory: str | Path) -> list[Decoded]:
    """The session decoded for replay, one Decoded per stretch between receiver restarts (GPS time
    going back): each stretch is on one time line and replays on its own; the IMU records are cut
    at the system time between the blocks on either side of a restart."""
    return _decode(directory, split=True)


def _decode(directory: str | Path, split: bool) -> list[Decoded]:
    session, skipped = read_counting_damage(directory, imu_frames=False)
    if "gps" not in session.sensors or not session.sensors["gps"].count:
        raise layouts.LogError(f"{directory}: no GPS records")
    if "imu" not in session.sensors or not session.sensors["imu"].count:
        raise layouts.LogError(f"{directory}: no IMU records")
    files = session.sensors["gps"]
    gps = decode_gps(files, Counter(skipped) if split else skipped)
    if not split or not gps.restarts:
        return [Decoded(gps, valid_imu(session, skipped), skipped, session.sidecar, Path(directory))]
    imu = valid_imu(session, skipped)
    rows = [0, *(r[0] for r in gps.restarts), files.count]
    cuts = [-np.inf, *(r[1] for r in gps.restarts), np.inf]
    out = []
    for j in range(len(rows) - 1):
        part = Counter(skipped)
        inside = (imu.stamps >= cuts[j]) & (imu.stamps < cuts[j + 1])
        piece = replace(imu, **{name: getattr(imu, name)[inside] for name in ("stamps", "dtheta", "dv", "status",
                                                                             "counter")})
        stretch = decode_gps(files, part, (rows[j], rows[j + 1]))
        stretch.restarts = gps.restarts  # the session's, for the record
        out.append(Decoded(stretch, piece, part, session.sidecar, Path(directory)))
    return out


def valid_imu(session: logs.SessionLog, skipped: Counter) -> layouts.ImuLog:
    """The session's IMU samples without the frames flagged invalid, over range or failing
    their test (counted). The session lets go of its IMU, so no second copy is held."""
    imu = session.imu()
    del session.sensors["imu"]
    bad = bad_imu(imu.status)
    if bad.any():
        skipped["imu: frames flagged invalid, over range or test failure"] += int(bad.sum())
    moved = out_of_place_imu(imu.counter, imu.stamps, imu.rate_hz) & ~bad
    if moved.any():
        skipped[IMU_MOVED] += int(moved.sum())
    if (bad | moved).any():
        imu.keep(~(bad | moved))
    return imu


IMU_MOVED = "imu: records out of place (counter and stamp from elsewhere in the file)"
IMU_DROPS_MAX = 16  # frames a counter step may skip and still be the next frame of the same stretch
IMU_MOVED_RUN = 4  # longest run of out-of-place records looked for


def out_of_place_imu(counter: np.ndarray, stamps: np.ndarray, rate_hz: float) -> np.ndarray:
    """Runs of up to IMU_MOVED_RUN records whose frame counter breaks the sequence on both sides
    while the records around the run follow each other (a counter step of at most IMU_DROPS_MAX
    more than the run and stamps less than 3/4 of a counter period apart): records moved in the
    file (bytes copied from elsewhere with their stamps). Left in, the counter would count 256
    frames too many after them; a real gap moves the counter once, and its stamps show it."""
    c = np.asarray(counter, dtype=np.int64)
    n = len(c)
    moved = np.zeros(n, bool)
    if n < 3:
        return moved
    step = np.diff(c) % 256
    step[step == 0] = 256
    breaks = step > IMU_DROPS_MAX  # between record k and k + 1
    span = 0.75 * 256 / rate_hz
    for r in range(1, IMU_MOVED_RUN + 1):
        i = np.arange(1, n - r)  # first of the run; i - 1 and i + r around it
        ok = breaks[i - 1] & breaks[i + r - 1]
        bracket = (c[i + r] - c[i - 1]) % 256
        ok &= (bracket >= 1) & (bracket <= r + 1 + IMU_DROPS_MAX) & (np.abs(stamps[i + r] - stamps[i - 1]) < span)
        for k in i[ok]:
            moved[k:k + r] = True
    return moved

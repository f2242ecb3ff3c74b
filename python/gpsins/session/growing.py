"""A Superstar II / BP3010 session as the logger writes it, read and decoded incrementally for
``gpsins live``: each ``read()`` reads only the bytes the record files gained since the last one
(``session.stream.RecordTail``: the block reader's own chain of records, damaged records skipped and counted as
it skips them, parts picked up as the sidecar lists them), decodes only the new records (the same
decoding as ``measurements.decode_gps`` and ``measurements.valid_imu``) and keeps the columns the
alignment and the filter take: GPS times of week and stamps, fixes (ID 21 paired with its ID 20),
pseudoranges, ephemerides; IMU stamps, counters, increments and which frames are valid.

The tests that need neighbours on both sides (a record's stamp against its neighbours', a time of week
off the receiver's grid, IMU records moved in the file) are made on the newest records against the few
before them; the newest record is judged on the side it has, as the whole-session readers judge a
file's last record, and a later record can still show it damaged (it is then left out of what is not
yet fed, and counted).
"""

from __future__ import annotations

import json
import math
import os
import time
from collections import Counter
from pathlib import Path

import numpy as np
from gpsins_logger import bp3010
from gpsins_logger import superstar2 as ss2

from . import measurements
from . import layouts
from . import stamps
from . import stream as log_stream
from ..formats.gpstime import SECONDS_PER_WEEK

CONTEXT_BLOCKS = 8  # measurement blocks before the newest that the time-of-week test sees
IMU_CONTEXT = 16  # IMU records before the new ones that the moved-record test sees


class NotSuperstar(layouts.LogError):
    """The session's GPS is not a Superstar II (a u-blox session is read whole each round)."""


class _Column:
    """A growing 1-D or 2-D column (amortised doubling); ``a`` is the filled part."""

    def __init__(self, dtype, width: tuple = ()):
        self._a = np.empty((1024, *width), dtype)
        self.n = 0

    def extend(self, v) -> None:
        v = np.asarray(v)
        if self.n + len(v) > len(self._a):
            bigger = np.empty((max(2 * len(self._a), self.n + len(v)), *self._a.shape[1:]), self._a.dtype)
            bigger[:self.n] = self._a[:self.n]
            self._a = bigger
        self._a[self.n:self.n + len(v)] = v
        self.n += len(v)

    @property
    def a(self) -> np.ndarray:
        return self._a[:self.n]


class GpsStream:
    """The Superstar II records decoded as they come (see ``measurements.decode_gps``)."""

    def __init__(self, skipped: Counter):
        self.skipped = skipped
        self.tow, self.stamps = _Column(np.float64), _Column(np.float64)
        self.block_ok = _Column(bool)  # the time-of-week test so far (the newest judged on one side)
        self._obs: list[np.ndarray] = []  # per block: (k, 4) [prn, pseudorange, C/N0, lock]
        self._nav_user: list[tuple[float, ss2.NavUser]] = []
        self._user_utc = _Column(np.float64)  # UTC seconds since the GPS epoch (NaN: invalid date)
        self._nav_ecef: list[tuple[float, ss2.NavEcef]] = []
        self._paired = 0  # ID 21s paired (or given up) so far
        self.fixes = _Column(np.float64, (10,))
        self.fix_sats: list[int] = []
        self.ephemerides: list[tuple[float, ss2.EphemerisWords]] = []
        self.iono: ss2.IonoUtc | None = None
        self.leap_s: int | None = None
        self._weeks: Counter = Counter()
        self._rollovers = 0

    @property
    def week(self) -> int | None:
        return self._weeks.most_common(1)[0][0] if self._weeks else None

    def add(self, scan: layouts.Scan) -> bool:
        """Decode the new records; True when a fix (ID 21) came."""
        fix = False
        for fr, st in scan.iter_frames():
            try:
                msg_id, payload = ss2.decode_frame(fr)
                if msg_id == ss2.ID_MEASUREMENTS:
                    m = ss2.Measurements.decode(payload)
                    tow = m.tow_s + SECONDS_PER_WEEK * self._rollovers
                    if self.tow.n and tow - self.tow.a[-1] < -SECONDS_PER_WEEK / 2:  # past the week's end
                        self._rollovers += 1
                        tow += SECONDS_PER_WEEK
                    self._obs.append(np.array([(o.prn, m.pseudorange_m(o), o.cn0_dbhz, o.lock_count)
                                               for o in m.observations if not o.sbas], dtype=float).reshape(-1, 4))
                    self.tow.extend([tow])
                    self.stamps.extend([st])
                    self._judge_tows()
                elif msg_id == ss2.ID_NAV_USER:
                    u = ss2.NavUser.decode(payload)
                    self._nav_user.append((st, u))
                    self._user_utc.extend([measurements.utc_seconds(u)])
                elif msg_id == ss2.ID_NAV_ECEF:
                    e = ss2.NavEcef.decode(payload)
                    self._nav_ecef.append((st, e))
                    self._weeks[e.week] += 1
                    fix = True
                elif msg_id == ss2.ID_RECEIVER_STATUS:
                    self._weeks[ss2.ReceiverStatus.decode(payload).week] += 1
                elif msg_id == ss2.ID_EPHEMERIS:
                    self.ephemerides.append((st, ss2.EphemerisWords.decode(payload)))
                elif msg_id == ss2.ID_IONO_UTC:
                    self.iono = ss2.IonoUtc.decode(payload)
                    self.leap_s = self.iono.leap_s
                elif msg_id == ss2.ID_LEAP:
                    self.leap_s = ss2.LeapSeconds.decode(payload).leap_s
            except ss2.ProtocolError:
                self.skipped["gps frames that do not decode"] += 1
        if self._nav_ecef[self._paired:]:
            self._pair()
        return fix

    def _judge_tows(self) -> None:
        """``measurements.implausible_tows`` over the newest blocks: each block is judged again while
        it is among the last two (then with neighbours on both sides), earlier judgements stand."""
        n = self.tow.n
        a = max(0, n - CONTEXT_BLOCKS)
        bad = measurements.implausible_tows(self.tow.a[a:], self.stamps.a[a:])
        self.block_ok.extend([True])
        ok = self.block_ok.a
        for k in range(max(a, n - 2), n):
            ok[k] = not bad[k - a]

    def good_blocks(self) -> np.ndarray:
        return np.flatnonzero(self.block_ok.a)

    def newest(self) -> float | None:
        """The time of week of the newest block that passes the test."""
        good = np.flatnonzero(self.block_ok.a)
        return float(self.tow.a[good[-1]]) if len(good) else None

    def pseudoranges(self, t_after: float, t_upto: float) -> np.ndarray:
        """(k, 5) [t, prn, pseudorange m, C/N0 dB-Hz, lock count] of the good blocks in (t_after, t_upto]."""
        tow, ok = self.tow.a, self.block_ok.a
        k = np.flatnonzero(ok & (tow > t_after) & (tow <= t_upto))
        rows = [np.column_stack([np.full(len(self._obs[j]), tow[j]), self._obs[j]]) for j in k]
        if not rows:
            return np.zeros((0, 5))
        out = np.concatenate(rows)
        out[:, 3] = out[:, 3].astype(np.float32)  # as the decoder's columns keep them
        out[:, 4] = out[:, 4].astype(np.float32)
        return out

    def _leap(self) -> int:
        if self.leap_s is not None:
            return self.leap_s
        week = self.week
        utc = self._user_utc.a - week * SECONDS_PER_WEEK
        ecef_t = np.array([(e.week - week) * SECONDS_PER_WEEK + e.tow_s for _, e in self._nav_ecef])
        if not len(utc) or not len(ecef_t):
            return 0
        ustamps = np.array([st for st, _ in self._nav_user])
        k = np.clip(np.searchsorted(ustamps, [st for st, _ in self._nav_ecef]), 0, len(ustamps) - 1)
        diff = np.round(ecef_t - utc[k])
        vals, counts = np.unique(diff[np.isfinite(diff)], return_counts=True)
        return int(vals[np.argmax(counts)]) if len(vals) else 0

    def _pair(self) -> None:
        """Each new ID 21 with the ID 20 of the same epoch (by GPS time, as ``decode_gps`` pairs them);
        one whose ID 20 has not come yet waits, unless a later ID 20 has come (then it has none)."""
        week = self.week
        user_t = self._user_utc.a - week * SECONDS_PER_WEEK + self._leap()
        order = np.argsort(user_t, kind="stable")
        sorted_t = user_t[order]
        newest_user = np.nanmax(user_t) if len(user_t) and np.isfinite(user_t).any() else -math.inf
        while self._paired < len(self._nav_ecef):
            _, e = self._nav_ecef[self._paired]
            t = (e.week - week) * SECONDS_PER_WEEK + e.tow_s
            j = np.searchsorted(sorted_t, t)
            near = [order[i] for i in (j - 1, j) if 0 <= i < len(order)]
            k = min(near, key=lambda i: abs(user_t[i] - t)) if near else -1
            if k < 0 or not abs(user_t[k] - t) <= measurements.FIX_PAIR_TOLERANCE_S:
                if newest_user <= t + measurements.FIX_PAIR_TOLERANCE_S:
                    return  # its ID 20 may still come
                self.skipped["ID 21 fixes without an ID 20 of the same epoch (no HDOP/VDOP/mode)"] += 1
                self._paired += 1
                continue
            u = self._nav_user[k][1]
            mode = u.nav_mode if u.has_fix and np.any([e.x_m, e.y_m, e.z_m]) else 0
            mode = {4: 2, 5: 3}.get(mode, mode)
            self.fixes.extend([[t, e.x_m, e.y_m, e.z_m, e.vx_mps, e.vy_mps, e.vz_mps, max(u.hdop, 0.1),
                                max(u.vdop, 0.1), mode]])
            self.fix_sats.append(u.sats_used)
            self._paired += 1


class ImuStream:
    """The BP3010 records decoded as they come; ``valid`` as ``measurements.valid_imu`` decides it."""

    def __init__(self, rate_hz: int, skipped: Counter):
        self.rate_hz, self.lsb, self.skipped = rate_hz, layouts.bp3010_lsb(rate_hz), skipped
        self.stamps, self.counter, self.status = _Column(np.float64), _Column(np.uint8), _Column(np.uint8)
        self.dtheta, self.dv = _Column(np.int16, (3,)), _Column(np.int16, (3,))
        self.valid = _Column(bool)
        self._bad = _Column(bool)

    @property
    def n(self) -> int:
        return self.stamps.n

    def add(self, scan: layouts.Scan) -> int:
        """Decode the new records; returns how many."""
        m = scan.count
        if not m:
            return 0
        body = scan.frame_data.reshape(-1, bp3010.FRAME_LEN)[:, 1:15]
        dth, dv = np.empty((m, 3), np.int16), np.empty((m, 3), np.int16)
        st, ct = np.empty(m, np.uint8), np.empty(m, np.uint8)
        log_stream.decode_bp3010(body, dth, dv, st, ct)
        n0 = self.n
        self.stamps.extend(scan.stamps)
        self.dtheta.extend(dth)
        self.dv.extend(dv)
        self.status.extend(st)
        self.counter.extend(ct)
        bad = measurements.bad_imu(st)
        if bad.any():
            self.skipped["imu: frames flagged invalid, over range or test failure"] += int(bad.sum())
        self._bad.extend(bad)
        self.valid.extend(~bad)
        # Moved records: the test over the new records and the last few before them; records before the
        # new ones keep the judgement they had unless this one finds them moved.
        a = max(0, n0 - IMU_CONTEXT)
        moved = measurements.out_of_place_imu(self.counter.a[a:], self.stamps.a[a:], self.rate_hz) & ~self._bad.a[a:]
        if moved.any():
            valid = self.valid.a
            idx = a + np.flatnonzero(moved)
            fresh = idx[valid[idx]]
            if len(fresh):
                self.skipped[measurements.IMU_MOVED] += len(fresh)
                valid[fresh] = False
        return m


class SessionStream:
    """A growing Superstar II / BP3010 session: ``read()`` takes in what the logger wrote since."""

    def __init__(self, directory: str | Path):
        self.directory = Path(directory)
        self.sidecar: dict = {}
        self._side_stat = None
        self._clock_stat = None
        self._limits = stamps.StampLimits()
        self.tails: dict[str, list[log_stream.RecordTail]] = {"gps": [], "imu": []}
        self.skipped: Counter = Counter()
        self.gps = GpsStream(self.skipped)
        self.imu: ImuStream | None = None

    def _refresh(self) -> None:
        side = self.directory / "session.json"
        try:
            st = os.stat(side)
        except OSError:
            return
        key = (st.st_mtime_ns, st.st_size, st.st_ino)
        if key != self._side_stat:
            try:
                sidecar = json.loads(side.read_text(encoding="utf-8"))
            except (OSError, ValueError):
                return  # being replaced: the next round reads it
            if isinstance(sidecar, dict) and isinstance(sidecar.get("sensors", {}), dict):
                self.sidecar, self._side_stat = sidecar, key
                self._clock_stat = None  # the span may have changed (a stop pair)
        try:
            cst = os.stat(self.directory / "clock.csv")
            ckey = (cst.st_mtime_ns, cst.st_size)
        except OSError:
            ckey = None
        if ckey != self._clock_stat or self._clock_stat is None:
            self._limits = stamps.stamp_limits(self.directory, self.sidecar)
            self._clock_stat = ckey
        for name in ("gps", "imu"):
            info = self.sidecar.get("sensors", {}).get(name)
            if not isinstance(info, dict):
                continue
            if name == "gps" and info.get("device") != "superstar2":
                raise NotSuperstar(f"{self.directory}: incremental reading is for Superstar II sessions")
            if name == "imu" and self.imu is None:
                self.imu = ImuStream(int(info.get("rate_hz", bp3010.NOMINAL_RATE_HZ)), self.skipped)
            files = info.get("files", [])
            tails = self.tails[name]
            for fname in files[len(tails):]:
                tails.append(log_stream.RecordTail(self.directory / fname, info["device"], self._limits))

    def limits(self) -> stamps.StampLimits:
        """The session's span now; while the logger runs, a stamp it gave is no later than this clock."""
        lim = self._limits
        if self.finished:
            return lim
        return stamps.StampLimits(lim.lo, max(lim.hi, time.time() + layouts.SPAN_MARGIN_S), lim.back_s)

    @property
    def finished(self) -> bool:
        return self.sidecar.get("state") == "stopped"

    def read(self, imu: bool = False) -> dict:
        """Take in what is new: {"fix": a fix came, "gps": GPS records, "imu": IMU records}. The IMU files
        are read when GPS records came (or ``imu``): IMU samples wait for GPS time, and reading them
        at every look would cost a block read for one or two records."""
        self._refresh()
        lim = self.limits()
        got = {"fix": False, "gps": 0, "imu": 0}
        for tail in self.tails["gps"]:
            s = tail.read(lim)
            if s.count:
                got["gps"] += s.count
                got["fix"] |= self.gps.add(s)
        if not (got["gps"] or imu):
            return got
        for tail in self.tails["imu"]:
            s = tail.read(lim)
            if s.count and self.imu is not None:
                got["imu"] += self.imu.add(s)
        return got

    def damage(self) -> Counter:
        """What was skipped so far, by reason (as ``measurements.read_counting_damage`` counts it)."""
        out = Counter(self.skipped)
        for name, tails in self.tails.items():
            bad = sum(t.bad_stamps for t in tails)
            if bad:
                out[f"{name}: records with impossible stamps"] += bad
        return out

"""The follower of a growing session: each round reads what the record files gained, times the new IMU
samples, and feeds the streaming filter (see ``live.service``).
"""

from __future__ import annotations

import json
import math
import threading
import time
from pathlib import Path

import numpy as np

from .. import timing
from ..timing import alignment
from ..nav import runs as flt
from ..session import growing, measurements_ubx
from ..session import layouts
from ..formats import gpstime
from ..nav import config as nav_config
from ..nav import inputs as nav_inputs
from .outputs import DEFAULT_LEAP_S


FIX_WAIT_S = 2.5  # measurements this long past the last fix: no fix is coming for them (an outage)
REFIT_S = 0.25  # the whole clock fit again after this much new IMU data (s) ...
# ... or this share of the session, whichever is more: a fit costs time in proportion to the session, so
# the fits of a long one cost a constant share of a core
REFIT_SHARE = 0.02
# The clock map may move the samples already fed this much (s) before the filter is fed them again at their
# new times: the robust alignment's own accuracy (tests/test_timing.py), a sixteenth of a 64 Hz sample.
# While the session is short (the first FINE_REFEED_SAMPLES, 5 min at 64 Hz: a refeed then takes at most
# 0.07 s of a loose filter, the round's NMEA that much later) also FINE_REFEED_S: the fits of a drive's first
# minutes move its samples by tens of microseconds, which the filter carries on as a millimetre (a host
# that stalls now and then: 1.5 mm from the replay at the end of a 60 s drive, 0.2 mm with these).
REFEED_S = 1e-3
FINE_REFEED_S, FINE_REFEED_SAMPLES = 1e-5, 20_000
MAX_UNSETTLED = 8
# The clock map is said to have settled (``clock_settled``, the status's) once its GPS time messages span
# this long: under two busy loops at 4x a map of the first seconds was 1.6 ms off the whole session's, one
# of 10-20 s 0.04 ms.
SETTLE_SPAN_S = 10.0
INLINE_FIT_S = 0.005  # a due fit that took less than this last time is made before feeding, not after


class Follower:
    """The streaming filter over a growing session; ``poll()`` feeds what is new and returns the
    solution of the new epochs (or None)."""

    def __init__(self, session: str | Path, *, mode: str = "loose", config=None, overrides: dict | None = None,
                 gps_latency_s: float = 0.0, imu_latency_s: float = 0.0, hold_s: float = 0.0):
        from ..replay.inputs import DEFAULT_GPS_LATENCY_S, DEFAULT_IMU_LATENCY_S

        if mode not in ("loose", "tight"):
            raise ValueError(f"--mode {mode!r}: loose or tight")
        self.session, self.mode = Path(session), mode
        self.cfg = nav_config.load_config(config, {**(overrides or {}), "mode": mode})
        if flt.needs_heading_search(self.cfg):
            raise ValueError("live: a hand-held platform's heading search needs the whole recording; give "
                             "initial_yaw_deg")
        self.gps_latency_s = gps_latency_s or DEFAULT_GPS_LATENCY_S
        self.imu_latency_s = imu_latency_s or DEFAULT_IMU_LATENCY_S
        self.filter = None
        self.week: int | None = None
        self.leap_s = DEFAULT_LEAP_S
        self.t_fed = self.fix_fed = self.pr_fed = -math.inf
        self.n_imu = self.n_fix = self.n_pr = 0
        self.ephemerides_seen: set = set()
        self.warnings: list[str] = []
        self.counters: dict = {}
        self.scale_factors = False
        # IMU samples held back this long behind the newest GPS time: their clock map then has GPS
        # blocks on both sides and changes little in later rounds (the price: that much later).
        self.hold_s = hold_s
        # A Superstar II session is read incrementally (live_stream); a u-blox one whole each round.
        self.stream: growing.SessionStream | None = growing.SessionStream(self.session)
        self.raw_fed = -1  # the last IMU record (index among all read) fed or passed over
        self.last_fed = -1  # the last IMU record fed
        self._fit: dict | None = None
        self._refit_now = False
        self._eph_done = 0
        self.refits = 0
        self.refeeds = 0  # the filter fed again because the clock map moved what it had been fed
        # A fit is settled when it agrees with the one before within REFEED_S where both have samples:
        # samples are fed only on a settled map (one fit, or fits from GPS stamps a stall held back,
        # may be seconds off).
        self._settled = False
        self._unsettled = 0  # fits in a row that did not agree with the one before
        self._moved = False  # the current fit moved the samples fed (_moves)
        self._whole: tuple | None = None  # a u-blox session: the last round's IMU times, rate, GPS time span
        self._fed_rate = 0  # ... and the rate of the increments fed
        self.fed = False  # the last poll fed samples
        self._fit_cost_s = 0.0  # what the last clock fit took (s)
        self._failed_at = -math.inf  # valid IMU samples when a fit last failed
        self._worker: threading.Thread | None = None  # a clock fit running beside the rounds
        self._worker_result: dict | None = None
        self._sidecar = _Sidecar(self.session)

    def poll(self, final: bool = False) -> flt.Solution | None:
        """Feed what is new; ``final``: the session is complete, feed everything held back."""
        self.fed = False
        if self.stream is None:
            return self._poll_whole(final)
        try:
            got = self.stream.read(imu=final)
        except growing.NotSuperstar:
            self.stream = None
            return self._poll_whole(final)
        except (layouts.LogError, FileNotFoundError):
            return None
        gps, imu = self.stream.gps, self.stream.imu
        if imu is None or gps.week is None or gps.newest() is None:
            return None
        self._collect()
        if not (got["gps"] or final or self._fit is None or self._refit_now):
            return None  # IMU samples alone: they wait for their fix (or the blocks of an outage)
        if self._fit is None or self._refit_now:
            n = int(imu.valid.a.sum())
            if not final and n - self._failed_at < REFIT_S * imu.rate_hz:
                return None  # the last try failed: the next when more has come
            if not self._refit():
                self._failed_at = n
                return None  # not enough on disk yet to know GPS time
        if self.week is None:
            self.week = int(gps.week)
        elif gps.week != self.week:
            return None  # another stretch (a receiver restart): replay it on its own
        self.leap_s = gps.leap_s if gps.leap_s is not None else self.leap_s
        self.maintain()  # a cheap fit (a short session) now: the samples about to be fed get the freshest
        if final and self._fit["count"] < int(imu.valid.a.sum()):
            self._refit()  # everything is on disk: the samples left get the whole session's fit, as in replay
        idx = self._unfed()
        t = self._times(idx)
        if self._refit_now:  # a gap the counter cannot count: the whole fit, now
            if not self._refit():
                self._failed_at = int(imu.valid.a.sum())
                return None
            t = self._times(idx)
        if not (self._settled or final):
            return None  # the clock map still moves (its first fit, or late GPS stamps): the next fit decides
        if self._moved:
            self._refeed()
            idx = self._unfed()
            t = self._times(idx)
        newest = gps.newest()
        fixes = gps.fixes.a
        last_fix = float(fixes[-1, 0]) if len(fixes) else -math.inf
        limit = last_fix if newest - last_fix < FIX_WAIT_S else newest
        return self._feed_upto(idx, t, np.inf if final else min(newest - self.hold_s, limit))

    def _unfed(self) -> np.ndarray:
        """Raw indices of the valid IMU records not yet fed or passed over."""
        valid = self.stream.imu.valid.a
        return np.flatnonzero(valid[self.raw_fed + 1:]) + self.raw_fed + 1

    def _feed_upto(self, idx: np.ndarray, t: np.ndarray, upto: float) -> flt.Solution | None:
        """Feed the samples ``idx`` (timed ``t``) up to GPS time ``upto``, with the fixes, pseudoranges and
        ephemerides up to the last of them."""
        gps, imu = self.stream.gps, self.stream.imu
        take = np.isfinite(t) & (t <= upto)
        if not take.any():
            return None
        last = int(np.flatnonzero(take)[-1])
        idx, t = idx[:last + 1], t[:last + 1]
        self.raw_fed = int(idx[-1])
        keep = np.isfinite(t) & (t > self.t_fed + 0.5 / imu.rate_hz)  # in time order after what was fed
        idx, t = idx[keep], t[keep]
        if not len(idx):
            return None
        self.last_fed = int(idx[-1])
        rows = np.column_stack([t, imu.dtheta.a[idx] * imu.lsb[0], imu.dv.a[idx] * imu.lsb[1]])
        prs = gps.pseudoranges(self.pr_fed, float(t[-1])) if self.mode == "tight" else None
        iono = (gps.iono.alpha, gps.iono.beta) if gps.iono else None
        ephemerides = []
        if self.mode == "tight":
            from .. import _core

            for _, w in gps.ephemerides[self._eph_done:]:
                try:
                    ephemerides.append(_core.gnss.decode_subframes(w.subframes, w.prn, self.week))
                except ValueError:
                    pass
            self._eph_done = len(gps.ephemerides)
        return self._feed(rows, gps.fixes.a, prs, iono, ephemerides)

    def _refeed(self) -> None:
        """The clock map moved the samples fed so far (``_moves``): a new filter is fed them
        again at their new times, up to the last epoch already out (those epochs stay as they went out;
        the ones after come from the new filter, the state replay would have with this clock map).
        Without it a map moved forward leaves a hole in the samples (the filter restarts after a gap over
        ``max_gap_s``) and one moved back drops the samples it moves behind the last fed."""
        last, t_out = self.last_fed, self._start_over()
        idx = self._unfed()
        t = self._times(idx)
        self._feed_upto(idx, t, _refeed_upto(t_out, float(t[np.searchsorted(idx, last)]),
                                             1.0 / self.stream.imu.rate_hz))
        self.fed = False

    def _moves(self, shift_s: float) -> bool:
        """Whether a fit that moved the last sample fed by ``shift_s`` calls for a refeed."""
        return shift_s > REFEED_S or (shift_s > FINE_REFEED_S and self.n_imu <= FINE_REFEED_SAMPLES)

    def _start_over(self) -> float:
        """No filter and nothing fed (``_refeed``); returns the time of the last epoch out."""
        t_out = self.t_fed
        self.filter, self.raw_fed, self.last_fed, self.t_fed = None, -1, -1, -math.inf
        self.fix_fed = self.pr_fed = -math.inf
        self.n_imu = self.n_fix = self.n_pr = 0
        self.ephemerides_seen, self._eph_done = set(), 0
        self._moved = False
        self.refeeds += 1
        return t_out

    @property
    def clock_settled(self) -> bool:
        """Whether the clock map has SETTLE_SPAN_S of GPS time messages behind it, and the IMU clock's newest
        piece (after a gap the counter cannot count) as long: epochs out before then were timed on a map that
        later messages may still move by a millisecond or more (2.2 ms right after an unplugged IMU)."""
        if self.stream is None:
            return self._whole is not None and self._whole[2] >= SETTLE_SPAN_S
        return self._fit is not None and min(self._fit["gps_span_s"], self._fit["piece_span_s"]) >= SETTLE_SPAN_S

    def finished(self) -> bool:
        """The logger has marked the session stopped (its sidecar says so)."""
        return self._sidecar()

    def maintain(self) -> None:
        """The whole clock fit again when it is due (after a round's outputs, off the NMEA's path): when
        the valid IMU samples grew by REFIT_S of data or REFIT_SHARE of the session since the last fit;
        between fits, new samples are timed by extending the last fit's IMU clock along the counter. A fit
        that took over INLINE_FIT_S last time (a long session: 0.14 s at an hour) runs in a thread on a
        snapshot of the columns, and the rounds go on with the last fit until it is in."""
        if self.stream is None or not self._due() or self._worker is not None:
            return
        if self._fit_cost_s < INLINE_FIT_S:
            self._refit()
            return
        inputs = self._fit_inputs()

        def work():
            t0 = time.perf_counter()
            self._worker_result = self._compute_fit(*inputs)
            self._fit_cost_s = time.perf_counter() - t0

        self._worker = threading.Thread(target=work, name="gpsins-live-fit", daemon=True)
        self._worker.start()

    def _collect(self) -> None:
        """A fit the thread finished: in use from now on (unless a newer one came meanwhile)."""
        if self._worker is None or self._worker.is_alive():
            return
        self._worker.join()
        fit, self._worker, self._worker_result = self._worker_result, None, None
        if fit is not None and (self._fit is None or fit["count"] > self._fit["count"]):
            self._install(fit)

    def _due(self) -> bool:
        if self._fit is None or self.stream.imu is None:
            return False
        n = int(self.stream.imu.valid.a.sum())
        return n - self._fit["count"] >= max(REFIT_S * self.stream.imu.rate_hz, REFIT_SHARE * n)

    def _refit(self) -> bool:
        t0 = time.perf_counter()
        fit = self._compute_fit(*self._fit_inputs())
        self._fit_cost_s = time.perf_counter() - t0
        if fit is None:
            return False
        self._install(fit)
        return True

    def _fit_inputs(self) -> tuple:
        """What a fit takes, copied (a fit in a thread reads no column the rounds extend)."""
        gps, imu = self.stream.gps, self.stream.imu
        g = gps.good_blocks()
        kept = np.flatnonzero(imu.valid.a)
        return (gps.tow.a[g], gps.stamps.a[g], int(gps.week), kept, imu.stamps.a[kept], imu.counter.a[kept],
                imu.rate_hz)

    def _compute_fit(self, tow, gps_stamps, week, kept, imu_stamps, counter, rate_hz) -> dict | None:
        try:
            al = alignment.align(tow, gps_stamps, week, imu_stamps, counter, rate_hz, gps_latency_s=self.gps_latency_s,
                                 imu_latency_s=self.imu_latency_s)
        except timing.AlignmentError:
            return None
        span = float(imu_stamps[-1] - imu_stamps[0])
        return {"idx": kept, "t": al.imu_t, "n": al.imu_index.astype(np.int64), "p": float(al.imu_period_s),
                "count": len(kept), "gps_per_system_s": (float(al.imu_t[-1] - al.imu_t[0]) / span) if span > 0
                else 1.0, "warnings": list(al.warnings), "gps_span_s": float(np.ptp(tow)),
                "piece_span_s": float(al.imu_t[-1] - al.imu_t[_newest_piece(al)])}

    def _install(self, fit: dict) -> None:
        before = self._fit
        self._fit = fit
        self.refits += 1
        self._refit_now = False
        self.warnings = fit["warnings"]
        if before is not None:
            k = before["idx"][-1:]
            self._note_settled(abs(float(self._times(k)[0] - before["t"][-1])) <= REFEED_S)
        if self.last_fed >= 0 and self._moves(abs(float(self._times(np.array([self.last_fed]))[0]) - self.t_fed)):
            self._moved = True

    def _note_settled(self, agrees: bool) -> None:
        """A fit that agrees with the one before settles the map; so do MAX_UNSETTLED fits in a row that
        do not (a map that keeps moving is fed anyway, and fed again whenever it moves what was fed)."""
        self._unsettled = 0 if agrees else self._unsettled + 1
        self._settled = agrees or self._unsettled >= MAX_UNSETTLED

    def _times(self, idx: np.ndarray) -> np.ndarray:
        """GPS times of valid IMU records (raw indices): the last fit's, and past it the fit's IMU clock
        extended along the frame counter (t = t_last + P (n - n_last)). A step the counter may have
        wrapped over (the stamps disagree by over half a counter period) or a gap that starts a new
        piece of the IMU clock (``timing.PIECE_GAP_S``) asks for the whole fit (``_refit_now``)."""
        fit, imu = self._fit, self.stream.imu
        fi = fit["idx"]
        t = np.full(len(idx), np.nan)
        inside = idx <= fi[-1]
        if inside.any():
            pos = np.minimum(np.searchsorted(fi, idx[inside]), len(fi) - 1)
            t[inside] = np.where(fi[pos] == idx[inside], fit["t"][pos], np.nan)
        ext = idx[~inside]
        if len(ext):
            chain = np.concatenate([[fi[-1]], ext])
            step = np.diff(imu.counter.a[chain].astype(np.int64)) % 256
            step[step == 0] = 256
            n = np.cumsum(step)
            t[~inside] = fit["t"][-1] + fit["p"] * n
            seen = np.diff(imu.stamps.a[chain]) * fit["gps_per_system_s"] / fit["p"]
            if np.any(step * fit["p"] >= timing.PIECE_GAP_S) or np.any(np.abs(seen - step) > 128):
                self._refit_now = True
        return t

    def _feed(self, rows: np.ndarray, fixes: np.ndarray, prs, iono, ephemerides) -> flt.Solution | None:
        t_end = float(rows[-1, 0])
        fx = fixes[(fixes[:, 0] > self.fix_fed) & (fixes[:, 0] <= t_end)]
        if self.filter is None:
            setup = flt.setup_run(rows[:0], fixes[:0], self.cfg, self.mode, [], iono,
                               self.week * gpstime.SECONDS_PER_WEEK)
            self.filter, self.scale_factors = setup.core_filter, setup.scale_factors
        for e in ephemerides:
            key = (e.prn, e.week, e.iode, e.toe_s)
            if key not in self.ephemerides_seen:
                self.ephemerides_seen.add(key)
                self.filter.add_ephemeris(e)
        out = self.filter.run(rows, np.ascontiguousarray(fx), prs, 1, True, False, 256.0, False, self.n_imu,
                              self.n_fix, self.n_pr, None, 0)
        self.n_imu, self.n_fix = self.n_imu + len(rows), self.n_fix + len(fx)
        self.t_fed, self.fed = t_end, True
        if len(fx):
            self.fix_fed = float(fx[-1, 0])
        if prs is not None and len(prs):
            self.n_pr += len(prs)
            self.pr_fed = float(prs[-1, 0])
        self.counters = out["counters"]
        sol = flt.Solution.from_batch(out, self.mode, self.scale_factors)
        return sol if len(sol.t) else None

    def _poll_whole(self, final: bool) -> flt.Solution | None:
        """A u-blox session: everything on disk decoded and aligned again each round (the incremental
        reader is the Superstar II's)."""
        try:
            dec = measurements_ubx.decode_session(self.session, nav_config.value(self.cfg, "fix_uere_m"))
            al = alignment.align(dec.gps.tow, dec.gps.stamps, dec.gps.week, dec.imu.stamps, dec.imu.counter,
                                 dec.imu.rate_hz, gps_latency_s=self.gps_latency_s, imu_latency_s=self.imu_latency_s)
        except (layouts.LogError, timing.AlignmentError, FileNotFoundError):
            return None  # not enough on disk yet to know GPS time (or no session yet)
        if self.week is None:
            self.week = int(dec.gps.week)
        elif dec.gps.week != self.week:
            return None
        self.leap_s = dec.gps.leap_s if dec.gps.leap_s is not None else self.leap_s
        self.warnings = list(al.warnings)
        # The ESF samples' rate is counted against the stamps' span (whole Hz): early in a session it may be
        # 1 Hz off, and every increment with it (they are rates times the period).
        before, self._whole = self._whole, (al.imu_t, dec.imu.rate_hz, float(np.ptp(dec.gps.tow)))
        if before is not None and len(before[0]):  # the last record both fits time, as _install compares
            k = min(len(before[0]), len(al.imu_t)) - 1
            self._note_settled(abs(float(al.imu_t[k] - before[0][k])) <= REFEED_S and before[1] == dec.imu.rate_hz)
        if not (self._settled or final):
            return None
        if self.last_fed >= 0 and (self.last_fed >= len(al.imu_t) or self._fed_rate != dec.imu.rate_hz
                                   or self._moves(abs(float(al.imu_t[self.last_fed]) - self.t_fed))):
            last, t_out = self.last_fed, self._start_over()
            self._feed_whole(dec, al, _refeed_upto(t_out, float(al.imu_t[min(last, len(al.imu_t) - 1)]),
                                                   1.0 / dec.imu.rate_hz))
            self.fed = False
        newest = float(dec.gps.tow[-1])
        last_fix = float(dec.gps.fixes[-1, 0]) if len(dec.gps.fixes) else -math.inf
        # A fix reaches the file a fraction of a second after its epoch's measurements: samples past
        # the last fix wait for the next one (fed later it would be late for the filter, and the
        # solution no longer the replay's), unless the receiver has gone on without fixes (an outage).
        limit = last_fix if newest - last_fix < FIX_WAIT_S else newest
        return self._feed_whole(dec, al, np.inf if final else min(newest - self.hold_s, limit))

    def _feed_whole(self, dec, al, upto: float) -> flt.Solution | None:
        new = np.flatnonzero((al.imu_t > self.t_fed + 0.5 / dec.imu.rate_hz) & (al.imu_t <= upto))
        if not len(new):
            return None
        self.last_fed, self._fed_rate = int(new[-1]), dec.imu.rate_hz
        imu = nav_inputs.ImuColumns(al.imu_t, dec.imu.dtheta, dec.imu.dv, dec.imu.lsb)
        rows = np.asarray(imu[int(new[0]):int(new[-1]) + 1], dtype=float)
        prs = None
        if self.mode == "tight":
            p = dec.gps.pseudoranges
            pt = np.asarray(p.t)
            take = np.flatnonzero((pt > self.pr_fed) & (pt <= float(rows[-1, 0])))
            prs = p[int(take[0]):int(take[-1]) + 1] if len(take) else np.zeros((0, 5))
        iono = (dec.gps.iono.alpha, dec.gps.iono.beta) if dec.gps.iono else None
        return self._feed(rows, dec.gps.fixes, prs, iono, dec.gps.decoded_ephemerides() if self.mode == "tight"
                          else [])


def _newest_piece(al) -> int:
    """The first record of the IMU clock's newest piece (after its last gap of PIECE_GAP_S or more)."""
    long_gaps = [k for k, missing in al.gaps if missing * al.imu_period_s >= timing.PIECE_GAP_S]
    return long_gaps[-1] if long_gaps else 0


def _refeed_upto(t_out: float, t_last: float, period_s: float) -> float:
    """How far a refeed goes: to the last sample fed (``t_last``, at its new time) when it moved less than
    half a step, so each sample is an epoch once as in replay; else to the last epoch out (``t_out``), so
    the outputs stay in time order and a sample moved past it is not left out."""
    return t_last if abs(t_last - t_out) < 0.5 * period_s else t_out


class _Sidecar:
    """Whether the logger marked the session stopped, the sidecar read again only when it changed."""

    def __init__(self, session: Path):
        self.path, self._key, self.stopped = session / "session.json", None, False

    def __call__(self) -> bool:
        try:
            st = self.path.stat()
        except OSError:
            return False
        key = (st.st_mtime_ns, st.st_size, st.st_ino)
        if key != self._key:
            self._key, self.stopped = key, session_finished(self.path.parent)
        return self.stopped


def session_finished(session: Path) -> bool:
    try:
        side = json.loads((session / "session.json").read_text(encoding="utf-8"))
    except (OSError, ValueError):
        return False
    return side.get("state") == "stopped"

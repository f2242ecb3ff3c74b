"""The Superstar II-like receiver: visibility, tracking, pseudoranges,
carrier, receiver clock, and the receiver's own position fix.

Measurement epochs are whole tenths of a second of *receiver* time; the true
GPS time of an epoch is receiver time minus the receiver clock bias. Each
pseudorange is the geometric range at transmission time (light-time
iteration, Earth rotation during travel) plus receiver clock, minus satellite
clock (polynomial, relativistic term, TGD), plus ionosphere, troposphere,
multipath and noise. The receiver's fix is a weighted least-squares solution
of those pseudoranges with the corrections a receiver can make (broadcast
Klobuchar, a standard troposphere), so its errors depend on the geometry as a
real receiver's do: 3D with 4 or more satellites, 2D (height held) with 3,
none with fewer.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from importlib import resources
from pathlib import Path

import numpy as np

from ..formats.gpstime import SECONDS_PER_WEEK
from . import atmosphere, earth, ephemeris
from .draws import Stream
from .processes import gauss_markov
from .scenario import GnssModel, Scenario
from .trajectory import Truth

MAX_PRN = 32
L1_WAVELENGTH = ephemeris.C / 1575.42e6


def load_nav(model: GnssModel) -> ephemeris.NavFile:
    p = Path(model.nav_file)
    if not p.exists():
        p = Path(str(resources.files(__package__).joinpath("data", model.nav_file)))
    return ephemeris.read_rinex2_nav(p)


def az_el(r_rx: np.ndarray, r_sat: np.ndarray, lat: np.ndarray, lon: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    d = r_sat - r_rx
    sl, cl, so, co = np.sin(lat), np.cos(lat), np.sin(lon), np.cos(lon)
    e = -so * d[..., 0] + co * d[..., 1]
    n = -sl * co * d[..., 0] - sl * so * d[..., 1] + cl * d[..., 2]
    u = cl * co * d[..., 0] + cl * so * d[..., 1] + sl * d[..., 2]
    return np.mod(np.arctan2(e, n), 2 * np.pi), np.arctan2(u, np.hypot(e, n))


@dataclass
class ReceiverClock:
    bias_s: np.ndarray  # at each measurement epoch (receiver clock minus GPS time)
    drift_s_per_s: np.ndarray


@dataclass
class Fix:
    t: float  # run time of the epoch (true GPS time - start)
    tow_s: float  # receiver time of week
    mode: int  # 2 = 3D, 3 = 2D, 0 = none
    r_ecef: np.ndarray
    llh: tuple[float, float, float]
    v_ecef: np.ndarray
    v_ned: np.ndarray
    hdop: float
    vdop: float
    sats: int
    prns: tuple[int, ...]


@dataclass
class GnssSim:
    """Everything the receiver model produced, per epoch and satellite (dense, indexed by PRN - 1)."""

    t: np.ndarray  # (m,) run time of each measurement epoch
    tow_rx: np.ndarray  # (m,) receiver time of week of each epoch
    week: int
    clock: ReceiverClock
    tracked: np.ndarray  # (m, 32) bool
    visible: np.ndarray  # (m, 32) bool: above the mask and not obstructed
    pseudorange_m: np.ndarray  # (m, 32), NaN where not tracked
    carrier_cycles: np.ndarray
    cn0_dbhz: np.ndarray
    lock_count: np.ndarray  # (m, 32) int
    elevation: np.ndarray
    azimuth: np.ndarray
    iono_m: np.ndarray
    trop_m: np.ndarray
    multipath_m: np.ndarray
    sat_pos: np.ndarray  # (m, 32, 3) at transmission, in the ECEF frame of reception
    sat_clock_s: np.ndarray  # (m, 32) incl. relativistic term and TGD
    ephemerides: dict[int, ephemeris.Ephemeris]  # per satellite, the latest ephemeris the epochs use
    ion_alpha: tuple
    ion_beta: tuple
    k0: int = 0  # index of the first epoch in the run (a block's epochs start there)
    eph_toe: np.ndarray | None = None  # (m, 32) toe of the ephemeris each satellite's epoch uses, NaN for none
    eph_table: dict = field(default_factory=dict)  # (prn, toe) -> every ephemeris the epochs use
    fixes: list[Fix] = field(default_factory=list)

    def doppler_hz(self) -> np.ndarray:
        """(m, 32) Doppler (Hz, positive approaching) from the carrier's rate, as a receiver measures both:
        central differences inside a track, one-sided at its ends, NaN where a satellite is tracked for a
        single epoch (or not at all)."""
        cyc, t = self.carrier_cycles, self.t
        out = np.full(cyc.shape, np.nan)
        if len(t) < 2:
            return out
        fwd = (cyc[1:] - cyc[:-1]) / (t[1:] - t[:-1])[:, None]  # rate over each step, NaN across a gap
        before = np.vstack([np.full((1, cyc.shape[1]), np.nan), fwd])
        after = np.vstack([fwd, np.full((1, cyc.shape[1]), np.nan)])
        both = np.isfinite(before) & np.isfinite(after)
        out[both] = -0.5 * (before[both] + after[both])
        out[~both] = -np.where(np.isfinite(before), before, after)[~both]
        return out


def _blocked(sc: Scenario, t: np.ndarray, az: np.ndarray, el: np.ndarray, flicker: list,
             spans: np.ndarray) -> np.ndarray:
    """Satellites behind the obstructions active at t (spans: each obstruction's (t0, t1))."""
    out = np.zeros(t.shape + az.shape[1:], dtype=bool)
    azd, eld = np.degrees(az), np.degrees(el)
    for j in np.flatnonzero((spans[:, 0] <= t.max()) & (spans[:, 1] > t.min())) if len(t) else ():
        ob, through_draws = sc.obstructions[j], flicker[j]
        when = (t >= ob.t0_s) & (t < ob.t1_s)
        a0, a1 = ob.azimuth_deg
        width = a1 - a0 if 0.0 <= a1 - a0 <= 360.0 else (a1 - a0) % 360.0  # [0, 360] is the whole horizon
        inside = ((azd - a0) % 360.0) <= width
        hit = when[:, None] & inside & (eld < ob.below_elevation_deg)
        if ob.flicker > 0:  # forest: each satellite comes through in some periods
            period = np.floor(np.maximum(t, 0.0) / ob.flicker_period_s).astype(np.int64)
            through = through_draws.rows(int(period[0]), int(period[-1]) + 1) < ob.flicker
            hit &= ~through[period - period[0]]
        out |= hit
    return out


def _runs(on: np.ndarray, idx: np.ndarray, last_off: np.ndarray) -> np.ndarray:
    """Per column, the latest index (idx along axis 0) where `on` was False, from last_off before the rows."""
    marks = np.where(on, -1, idx[:, None])
    return np.maximum.accumulate(np.concatenate([last_off[None], marks]), axis=0)[1:]


class Receiver:
    """The receiver's epochs in order, a truth block at a time.

    Every random draw is addressed by epoch (``draws.Stream``) and every process (receiver
    clock, multipath, tracking, lock counts, the fix's starting point and held height) carries
    its state from block to block, so the epochs are the same however the run is cut."""

    def __init__(self, sc: Scenario, seed: int):
        self.sc, model = sc, sc.gnss
        nav = load_nav(model)
        self.ion_alpha, self.ion_beta = nav.ion_alpha, nav.ion_beta
        self.dt = 1.0 / model.measurement_rate_hz
        self.m = int(np.floor(sc.duration_s * model.measurement_rate_hz)) + 1
        self.t_start = sc.start.gps_week * SECONDS_PER_WEEK + sc.start.gps_tow_s
        self.week = sc.start.gps_week + int(sc.start.gps_tow_s // SECONDS_PER_WEEK)
        # Every healthy broadcast ephemeris per satellite: each epoch uses the one with the nearest toe (within
        # the 2-hour validity, as ephemeris.select), so a day-long drive goes through the day's uploads.
        self.ephs: dict[int, list[ephemeris.Ephemeris]] = {}
        for e in sorted(nav.ephemerides, key=lambda e: (e.prn, e.t_oe)):
            if e.health == 0 and 1 <= e.prn <= MAX_PRN:
                self.ephs.setdefault(e.prn, []).append(ephemeris.quantised(e))
        self.toes = {prn: np.array([e.t_oe for e in lst]) for prn, lst in self.ephs.items()}
        const = np.random.default_rng([seed, 2, 0])
        self.mp_first = const.normal(0.0, 1.0, MAX_PRN)  # unit stationary std
        self.ambiguity = const.integers(-10_000, 10_000, MAX_PRN)
        self.r_last = earth.geodetic_to_ecef(np.radians(sc.start.lat_deg), np.radians(sc.start.lon_deg),
                                             sc.start.height_m) + const.normal(0.0, 50.0, 3)  # a cold guess
        self.h_last = None
        # Signal-in-space error: its own generator, so the other draws do not move with it.
        sis = np.random.default_rng([seed, 2, 1])
        self.sis = (sis.normal(0.0, 1.0, MAX_PRN), sis.normal(0.0, 1.0, MAX_PRN), sis.uniform(0.0, 2 * np.pi, MAX_PRN))
        key = (seed, 2)
        self.draw = {name: Stream(key + (j,), width=w) for j, (name, w) in enumerate(
            (("clock frequency", None), ("clock phase", None), ("multipath", MAX_PRN), ("code", MAX_PRN),
             ("carrier", MAX_PRN), ("cn0", MAX_PRN), ("fix velocity", 3)), start=1)}
        self.obstruction_spans = np.array([(o.t0_s, o.t1_s) for o in sc.obstructions]).reshape(-1, 2)
        # Small pieces, not kept: a day's drive has thousands of obstructions, each active for seconds.
        self.flicker = [Stream(key + (100, j), "uniform", MAX_PRN, atom=64, cache=False)
                        for j in range(len(sc.obstructions))]
        self.per_fix = int(round(model.measurement_rate_hz / model.fix_rate_hz))
        self.reacquire = int(round(model.reacquire_s * model.measurement_rate_hz))
        # Carried state: next epoch, clock random walks, multipath, tracking and lock runs.
        self.next = 0
        self._clock = (0.0, 0.0, 0.0, 0.0)  # (t of the last epoch, frequency walk, phase sums)
        self._mp = self.mp_first
        self._last_invisible = np.full(MAX_PRN, -1, dtype=np.int64)
        self._last_untracked = np.full(MAX_PRN, -1, dtype=np.int64)

    def _clock_at(self, k0: int, k1: int):
        """Receiver clock at epochs k0..k1-1 from the carried state, and the state after each epoch."""
        model = self.sc.gnss
        t = self.sc.start.gps_tow_s + self.dt * np.arange(k0, k1) - self.sc.start.gps_tow_s
        t_prev, walk, drift_sum, noise_sum = self._clock
        dt = np.diff(t, prepend=t[0] if k0 == 0 else t_prev)
        drift0 = 5e-8 if model.clock == "unsteered" else model.clock_drift_s_per_s
        walk = np.cumsum(np.concatenate([[walk], self.draw["clock frequency"].rows(k0, k1)
                                         * model.clock_freq_noise_per_sqrt_s * np.sqrt(dt)]))[1:]
        freq = drift0 + walk
        if model.clock == "steered":  # the receiver trims its frequency back towards zero drift
            freq = freq * np.exp(-t / 600.0) + (freq - drift0) * (1.0 - np.exp(-t / 600.0))
        drift_sum = np.cumsum(np.concatenate([[drift_sum], freq * dt]))[1:]
        noise_sum = np.cumsum(np.concatenate([[noise_sum], self.draw["clock phase"].rows(k0, k1)
                                              * model.clock_phase_noise_s_per_sqrt_s * np.sqrt(dt)]))[1:]
        bias = model.clock_bias_s + drift_sum + noise_sum
        if model.clock == "ms_jumps":
            bias = bias - 1e-3 * np.round(bias / 1e-3)
        return t, ReceiverClock(bias, freq), (t, walk, drift_sum, noise_sum)

    def epochs(self, tr: Truth, last: bool) -> GnssSim:
        """The epochs whose true time falls before the end of truth block `tr` (all that remain if last)."""
        sc, model, k0 = self.sc, self.sc.gnss, self.next
        k1 = self.m if last else min(self.m, k0 + int(np.ceil((tr.t[-1] - self.dt * k0) / self.dt)) + 3)
        if k1 <= k0:
            return self._empty()
        trel, clock, state = self._clock_at(k0, k1)
        t = trel - clock.bias_s  # true GPS time of each epoch, from the start
        n = len(t) if last else int(np.searchsorted(t, tr.t[-1], side="left"))
        if n == 0:
            return self._empty()
        k1 = k0 + n
        t, clock = t[:n], ReceiverClock(clock.bias_s[:n], clock.drift_s_per_s[:n])
        self._clock = tuple(x[n - 1] for x in state)
        self.next = k1
        idx = np.arange(k0, k1)
        tow_rx = sc.start.gps_tow_s + self.dt * idx
        r_rx = tr.position_at(t)
        lat_k = np.interp(t, tr.t, tr.lat)
        lon_k = np.interp(t, tr.t, tr.lon)
        h_k = np.interp(t, tr.t, tr.h)
        shape = (n, MAX_PRN)
        sat_pos = np.full(shape + (3,), np.nan)
        sat_clk = np.full(shape, np.nan)
        rng_geo = np.full(shape, np.nan)
        t_rx = self.t_start + t
        eph_toe = np.full(shape, np.nan)
        in_use: dict[int, ephemeris.Ephemeris] = {}
        table: dict[tuple[int, float], ephemeris.Ephemeris] = {}
        for prn, lst in self.ephs.items():
            toes = self.toes[prn]
            j = np.abs(t_rx[:, None] - toes[None, :]).argmin(axis=1)
            ok = np.abs(t_rx - toes[j]) <= 7200.0 + 1.0
            for jj in np.unique(j[ok]):
                e, sel = lst[jj], ok & (j == jj)
                tau = np.full(int(sel.sum()), 0.075)
                for _ in range(4):
                    rs = ephemeris.sat_position(e, t_rx[sel] - tau)
                    c, s = np.cos(earth.OMEGA_E * tau), np.sin(earth.OMEGA_E * tau)
                    rot = np.stack([c * rs[:, 0] + s * rs[:, 1], -s * rs[:, 0] + c * rs[:, 1], rs[:, 2]], -1)
                    rho = np.linalg.norm(rot - r_rx[sel], axis=-1)
                    tau = rho / ephemeris.C
                sat_pos[sel, prn - 1] = rot
                rng_geo[sel, prn - 1] = rho
                sat_clk[sel, prn - 1] = ephemeris.sat_clock(e, t_rx[sel] - tau)
                eph_toe[sel, prn - 1] = e.t_oe
                in_use[prn] = table[(prn, e.t_oe)] = e
        az, el = az_el(r_rx[:, None, :], sat_pos, lat_k[:, None], lon_k[:, None])
        have = np.isfinite(rng_geo)
        visible = have & (el >= np.radians(model.elevation_mask_deg))
        visible &= ~_blocked(sc, t, np.where(have, az, 0.0), np.where(have, el, -1.0), self.flicker,
                             self.obstruction_spans)
        # Tracking: visible satellites are tracked from the start; a lost one is tracked again after it
        # has been visible for the reacquisition time.
        last_off = _runs(visible, idx, self._last_invisible)
        tracked = visible & ((last_off < 0) | (idx[:, None] - last_off > self.reacquire))
        untracked = _runs(tracked, idx, self._last_untracked)
        lock = np.where(tracked, np.minimum(idx[:, None] - untracked - 1, 255), 0)
        self._last_invisible, self._last_untracked = last_off[-1], untracked[-1]
        tow_true = (sc.start.gps_tow_s + t)[:, None]
        klob = atmosphere.klobuchar_m(self.ion_alpha, self.ion_beta, lat_k[:, None], lon_k[:, None], az, el,
                                      tow_true)
        iono = atmosphere.true_iono_m(klob, t[:, None], np.arange(1, MAX_PRN + 1)[None, :], model.iono_scale,
                                      model.iono_variation, model.iono_period_s)
        trop = atmosphere.true_trop_m(el, lat_k[:, None], h_k[:, None], model.trop_wet_zenith_m)
        sin_el = np.sin(np.clip(el, np.radians(1.0), None))
        phi = np.exp(-self.dt / model.multipath_tau_s)
        drive = self.draw["multipath"].rows(k0, k1) * np.sqrt(1.0 - phi * phi)
        unit_mp = (gauss_markov(self.mp_first, drive[1:], phi, include_first=True) if k0 == 0
                   else gauss_markov(self._mp, drive, phi))
        self._mp = unit_mp[-1]
        mp = unit_mp * model.multipath_m / sin_el
        noise = self.draw["code"].rows(k0, k1) * model.code_noise_m / np.sqrt(sin_el)
        a, b, ph = self.sis
        sis = model.sis_error_m * (a + b * np.sin(2 * np.pi * t[:, None] / model.sis_period_s + ph))
        pr = rng_geo + ephemeris.C * (clock.bias_s[:, None] - sat_clk) + iono + trop + mp + noise + sis
        carrier = ((rng_geo + ephemeris.C * (clock.bias_s[:, None] - sat_clk) - iono + trop + sis) / L1_WAVELENGTH
                   + self.ambiguity + self.draw["carrier"].rows(k0, k1) * model.carrier_noise_cycles)
        cn0 = model.cn0_zenith_dbhz - 13.0 * (1.0 - sin_el) + self.draw["cn0"].rows(k0, k1)
        nan = ~tracked
        for a in (pr, carrier, cn0):
            a[nan] = np.nan
        out = GnssSim(t, tow_rx % SECONDS_PER_WEEK, self.week, clock, tracked, visible, pr, carrier, cn0, lock,
                      el, az, iono, trop, mp, sat_pos, sat_clk, in_use, self.ion_alpha, self.ion_beta, k0=k0,
                      eph_toe=eph_toe, eph_table=table)
        out.fixes = self._fixes(out, tr)
        return out

    def _empty(self) -> GnssSim:
        z = np.zeros((0, MAX_PRN))
        return GnssSim(np.zeros(0), np.zeros(0), self.week, ReceiverClock(np.zeros(0), np.zeros(0)),
                       z.astype(bool), z.astype(bool), z, z, z, z.astype(np.int64), z, z, z, z, z,
                       np.zeros((0, MAX_PRN, 3)), z, {}, self.ion_alpha, self.ion_beta, k0=self.next,
                       eph_toe=z.copy())

    def _solve_fix(self, g: GnssSim, k: int, use: np.ndarray, n: int):
        """(position, llh, C_en, hdop, vdop) of epoch k from satellites `use` (3: height held)."""
        gm = self.sc.gnss
        el = g.elevation[k, use]
        w = 1.0 / (gm.code_noise_m ** 2 / np.sin(el) + (gm.multipath_m / np.sin(el)) ** 2)
        r, _, geo, step = _solve(g.pseudorange_m[k, use], g.sat_pos[k, use], g.sat_clock_s[k, use], w,
                                 self.r_last, None if n >= 4 else self.h_last, g.tow_rx[k], g.ion_alpha, g.ion_beta)
        if not (step < 1.0 and np.all(np.isfinite(r))):  # diverged (a near-singular geometry): no solution
            return None
        llh = earth.ecef_to_geodetic(r)
        c_en = earth.ecef_to_ned_matrix(llh[0], llh[1])
        gl = np.hstack([geo[:, :3] @ c_en, geo[:, 3:]])  # north, east, down, clock
        if n >= 4:
            cov = np.linalg.inv(gl.T @ gl)
            hdop, vdop = float(np.sqrt(cov[0, 0] + cov[1, 1])), float(np.sqrt(cov[2, 2]))
        else:  # 2D: the held height is a perfect extra measurement
            aug = np.vstack([gl, [0.0, 0.0, 1.0, 0.0]])
            cov = np.linalg.inv(aug.T @ aug)
            hdop, vdop = float(np.sqrt(cov[0, 0] + cov[1, 1])), 99.9
        if not (np.isfinite(hdop) and np.isfinite(vdop)):
            return None
        return r, llh, c_en, hdop, vdop

    def _fixes(self, g: GnssSim, tr: Truth) -> list[Fix]:
        """The receiver's fixes at this block's fix epochs, each starting from the last one's position."""
        per = self.per_fix
        ks = [k for k in range(len(g.t)) if (g.k0 + k) % per == 0]
        if not ks:
            return []
        f0 = (g.k0 + ks[0]) // per
        v_noise = self.draw["fix velocity"].rows(f0, f0 + len(ks))
        fixes = []
        for k, vn in zip(ks, v_noise):
            use = np.flatnonzero(g.tracked[k])
            n = len(use)
            v_true = tr.velocity_at(g.t[k])
            fix = Fix(float(g.t[k]), float(g.tow_rx[k]), 0, np.full(3, np.nan), (np.nan,) * 3, np.full(3, np.nan),
                      np.full(3, np.nan), 99.9, 99.9, n, tuple(int(p + 1) for p in use))
            solved = None
            if n >= 3 and (n >= 4 or self.h_last is not None):
                try:
                    with np.errstate(all="ignore"):  # a diverging solution is found out below, not warned about
                        solved = self._solve_fix(g, k, use, n)
                except np.linalg.LinAlgError:  # a degenerate geometry: no solution this epoch, as a receiver says
                    solved = None
            if solved is not None:
                r, llh, c_en, hdop, vdop = solved
                v = v_true + vn * (0.05 * min(hdop, 10.0))
                fix = Fix(fix.t, fix.tow_s, 2 if n >= 4 else 3, r, llh, v, c_en.T @ v, min(hdop, 99.9),
                          min(vdop, 99.9), n, fix.prns)
                self.r_last = r
                if n >= 4:
                    self.h_last = llh[2]
            fixes.append(fix)
        return fixes


def concatenate(parts: list[GnssSim]) -> GnssSim:
    """One GnssSim of consecutive blocks' epochs."""
    first = parts[0]
    cat = lambda name: np.concatenate([getattr(p, name) for p in parts])  # noqa: E731
    out = GnssSim(cat("t"), cat("tow_rx"), first.week,
                  ReceiverClock(np.concatenate([p.clock.bias_s for p in parts]),
                                np.concatenate([p.clock.drift_s_per_s for p in parts])),
                  *(cat(name) for name in ("tracked", "visible", "pseudorange_m", "carrier_cycles", "cn0_dbhz",
                                           "lock_count", "elevation", "azimuth", "iono_m", "trop_m", "multipath_m",
                                           "sat_pos", "sat_clock_s")),
                  {prn: e for p in parts for prn, e in p.ephemerides.items()}, first.ion_alpha, first.ion_beta,
                  k0=first.k0, eph_toe=cat("eph_toe"),
                  eph_table={k: e for p in parts for k, e in p.eph_table.items()})
    out.fixes = [f for p in parts for f in p.fixes]
    return out


# --- the receiver's own fix ------------------------------------------------------------------


def _solve(pr, sats, clk, weights, r0, height_hold: float | None, tow: float, alpha, beta):
    """Iterated weighted least squares with the receiver's corrections; returns (r, clock bias in m, geometry,
    the last step's length in m)."""
    x = np.append(r0, 0.0)
    for _ in range(10):
        lat, lon, h = earth.ecef_to_geodetic(x[:3])
        d = sats - x[:3]
        # Earth rotation during travel is already in sats (they are given in the frame of reception)
        rho = np.linalg.norm(d, axis=1)
        u = d / rho[:, None]
        az, el = az_el(x[:3], sats, lat, lon)
        model = (rho + x[3] - ephemeris.C * clk + atmosphere.klobuchar_m(alpha, beta, lat, lon, az, el, tow)
                 + atmosphere.receiver_trop_m(el, h))
        g = np.hstack([-u, np.ones((len(pr), 1))])
        y = pr - model
        w = weights.copy()
        if height_hold is not None:  # 2D: the height is a measurement of itself
            up = np.array([np.cos(lat) * np.cos(lon), np.cos(lat) * np.sin(lon), np.sin(lat)])
            g = np.vstack([g, np.append(up, 0.0)])
            y = np.append(y, height_hold - h)
            w = np.append(w, 1.0 / 0.5 ** 2)
        gw = g * w[:, None]
        dx = np.linalg.solve(g.T @ gw, gw.T @ y)
        x += dx
        if np.linalg.norm(dx[:3]) < 1e-4:
            break
    return x[:3], x[3], g[:len(pr)], float(np.linalg.norm(dx[:3]))

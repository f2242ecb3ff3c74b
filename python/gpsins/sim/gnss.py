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

from . import atmosphere, earth, ephemeris
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


def receiver_clock(model: GnssModel, t: np.ndarray, rng: np.random.Generator) -> ReceiverClock:
    """Two-state clock (phase and frequency random walks); steered keeps it near its start."""
    dt = np.diff(t, prepend=t[0])
    drift0 = model.clock_drift_s_per_s if model.clock == "steered" else 5e-8
    freq = drift0 + np.cumsum(rng.normal(0.0, 1.0, len(t)) * model.clock_freq_noise_per_sqrt_s * np.sqrt(dt))
    if model.clock == "steered":  # the receiver trims its frequency back towards zero drift
        freq = freq * np.exp(-t / 600.0) + (freq - drift0) * (1.0 - np.exp(-t / 600.0))
    phase = model.clock_bias_s + np.cumsum(freq * dt) + np.cumsum(
        rng.normal(0.0, 1.0, len(t)) * model.clock_phase_noise_s_per_sqrt_s * np.sqrt(dt))
    return ReceiverClock(phase, freq)


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
    ephemerides: dict[int, ephemeris.Ephemeris]
    ion_alpha: tuple
    ion_beta: tuple
    fixes: list[Fix] = field(default_factory=list)


def _blocked(sc: Scenario, t: np.ndarray, az: np.ndarray, el: np.ndarray, rng: np.random.Generator) -> np.ndarray:
    out = np.zeros(t.shape + az.shape[1:], dtype=bool)
    azd, eld = np.degrees(az), np.degrees(el)
    for ob in sc.obstructions:
        when = (t >= ob.t0_s) & (t < ob.t1_s)
        a0, a1 = ob.azimuth_deg
        width = a1 - a0 if 0.0 <= a1 - a0 <= 360.0 else (a1 - a0) % 360.0  # [0, 360] is the whole horizon
        inside = ((azd - a0) % 360.0) <= width
        hit = when[:, None] & inside & (eld < ob.below_elevation_deg)
        if ob.flicker > 0:  # forest: each satellite comes through in some periods
            block = np.floor(t / ob.flicker_period_s).astype(int)
            through = rng.random((block.max() + 2, az.shape[1])) < ob.flicker
            hit &= ~through[block]
        out |= hit
    return out


def _track(visible: np.ndarray, reacquire_epochs: int) -> np.ndarray:
    """Tracking: visible satellites are tracked from the start; a lost one is tracked
    again after it has been visible for the reacquisition time."""
    tracked = np.zeros_like(visible)
    for j in range(visible.shape[1]):
        run = 0
        for k in range(visible.shape[0]):
            if visible[k, j]:
                run += 1
                tracked[k, j] = (k < run and visible[0, j]) or run > reacquire_epochs
            else:
                run = 0
    return tracked


def _lock_counts(tracked: np.ndarray) -> np.ndarray:
    lock = np.zeros(tracked.shape, dtype=np.int64)
    for k in range(1, tracked.shape[0]):
        lock[k] = np.where(tracked[k], np.where(tracked[k - 1], np.minimum(lock[k - 1] + 1, 255), 0), 0)
    return lock


def simulate(sc: Scenario, tr: Truth, rng: np.random.Generator) -> GnssSim:
    model = sc.gnss
    nav = load_nav(model)
    dt = 1.0 / model.measurement_rate_hz
    m = int(np.floor(sc.duration_s * model.measurement_rate_hz)) + 1
    tow_rx = sc.start.gps_tow_s + dt * np.arange(m)
    t_start = sc.start.gps_week * ephemeris.WEEK_S + sc.start.gps_tow_s
    clock = receiver_clock(model, tow_rx - sc.start.gps_tow_s, rng)
    t = tow_rx - sc.start.gps_tow_s - clock.bias_s  # true GPS time of each epoch, from the start
    r_rx = tr.position_at(t)
    lat_k = np.interp(t, tr.t, tr.lat)
    lon_k = np.interp(t, tr.t, tr.lon)
    h_k = np.interp(t, tr.t, tr.h)
    ephs: dict[int, ephemeris.Ephemeris] = {}
    shape = (m, MAX_PRN)
    sat_pos = np.full(shape + (3,), np.nan)
    sat_clk = np.full(shape, np.nan)
    rng_geo = np.full(shape, np.nan)
    for prn in range(1, MAX_PRN + 1):
        e = ephemeris.select(nav.ephemerides, prn, t_start + 0.5 * sc.duration_s)
        if e is None:
            continue
        e = ephemeris.quantised(e)
        ephs[prn] = e
        t_rx = t_start + t
        tau = np.full(m, 0.075)
        for _ in range(4):
            rs = ephemeris.sat_position(e, t_rx - tau)
            c, s = np.cos(earth.OMEGA_E * tau), np.sin(earth.OMEGA_E * tau)
            rot = np.stack([c * rs[:, 0] + s * rs[:, 1], -s * rs[:, 0] + c * rs[:, 1], rs[:, 2]], -1)
            rho = np.linalg.norm(rot - r_rx, axis=-1)
            tau = rho / ephemeris.C
        sat_pos[:, prn - 1] = rot
        rng_geo[:, prn - 1] = rho
        sat_clk[:, prn - 1] = ephemeris.sat_clock(e, t_rx - tau)
    az, el = az_el(r_rx[:, None, :], sat_pos, lat_k[:, None], lon_k[:, None])
    have = np.isfinite(rng_geo)
    visible = have & (el >= np.radians(model.elevation_mask_deg))
    visible &= ~_blocked(sc, t, np.where(have, az, 0.0), np.where(have, el, -1.0), rng)
    tracked = _track(visible, int(round(model.reacquire_s * model.measurement_rate_hz)))
    tow_true = (sc.start.gps_tow_s + t)[:, None]
    klob = atmosphere.klobuchar_m(nav.ion_alpha, nav.ion_beta, lat_k[:, None], lon_k[:, None], az, el, tow_true)
    iono = atmosphere.true_iono_m(klob, t[:, None], np.arange(1, MAX_PRN + 1)[None, :], model.iono_scale,
                                  model.iono_variation, model.iono_period_s)
    trop = atmosphere.true_trop_m(el, lat_k[:, None], h_k[:, None], model.trop_wet_zenith_m)
    sin_el = np.sin(np.clip(el, np.radians(1.0), None))
    phi = np.exp(-dt / model.multipath_tau_s)
    first = rng.normal(0.0, 1.0, shape[1:])  # unit stationary std
    drive = rng.normal(0.0, np.sqrt(1.0 - phi * phi), shape)
    mp = gauss_markov(first, drive[1:], phi, include_first=True) * model.multipath_m / sin_el
    noise = rng.normal(0.0, 1.0, shape) * model.code_noise_m / np.sqrt(sin_el)
    pr = rng_geo + ephemeris.C * (clock.bias_s[:, None] - sat_clk) + iono + trop + mp + noise
    ambiguity = rng.integers(-10_000, 10_000, MAX_PRN)
    carrier = ((rng_geo + ephemeris.C * (clock.bias_s[:, None] - sat_clk) - iono + trop) / L1_WAVELENGTH
               + ambiguity + rng.normal(0.0, model.carrier_noise_cycles, shape))
    cn0 = model.cn0_zenith_dbhz - 13.0 * (1.0 - sin_el) + rng.normal(0.0, 1.0, shape)
    nan = ~tracked
    for a in (pr, carrier, cn0):
        a[nan] = np.nan
    out = GnssSim(t, tow_rx % ephemeris.WEEK_S, sc.start.gps_week + int(tow_rx[0] // ephemeris.WEEK_S), clock,
                  tracked, visible, pr, carrier, cn0, _lock_counts(tracked), el, az, iono, trop, mp, sat_pos,
                  sat_clk, ephs, nav.ion_alpha, nav.ion_beta)
    out.fixes = receiver_fixes(sc, out, tr, rng)
    return out


# --- the receiver's own fix ------------------------------------------------------------------


def _solve(pr, sats, clk, weights, r0, height_hold: float | None, tow: float, alpha, beta):
    """Iterated weighted least squares with the receiver's corrections; returns (r, clock bias in m, geometry)."""
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
    return x[:3], x[3], g[:len(pr)]


def receiver_fixes(sc: Scenario, g: GnssSim, tr: Truth, rng: np.random.Generator) -> list[Fix]:
    per = int(round(sc.gnss.measurement_rate_hz / sc.gnss.fix_rate_hz))
    fixes = []
    r_last = earth.geodetic_to_ecef(np.radians(sc.start.lat_deg), np.radians(sc.start.lon_deg), sc.start.height_m)
    r_last = r_last + rng.normal(0.0, 50.0, 3)  # a cold guess near the site
    h_last = None
    for k in range(0, len(g.t), per):
        use = np.flatnonzero(g.tracked[k])
        n = len(use)
        v_true = tr.velocity_at(g.t[k])
        fix = Fix(float(g.t[k]), float(g.tow_rx[k]), 0, np.full(3, np.nan), (np.nan,) * 3, np.full(3, np.nan),
                  np.full(3, np.nan), 99.9, 99.9, n, tuple(int(p + 1) for p in use))
        if n >= 3 and (n >= 4 or h_last is not None):
            el = g.elevation[k, use]
            w = 1.0 / (sc.gnss.code_noise_m ** 2 / np.sin(el) + (sc.gnss.multipath_m / np.sin(el)) ** 2)
            r, _, geo = _solve(g.pseudorange_m[k, use], g.sat_pos[k, use], g.sat_clock_s[k, use], w, r_last,
                               None if n >= 4 else h_last, g.tow_rx[k], g.ion_alpha, g.ion_beta)
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
            v = v_true + rng.normal(0.0, 0.05 * min(hdop, 10.0), 3)
            fix = Fix(fix.t, fix.tow_s, 2 if n >= 4 else 3, r, llh, v, c_en.T @ v, min(hdop, 99.9),
                      min(vdop, 99.9), n, fix.prns)
            r_last = r
            if n >= 4:
                h_last = llh[2]
        fixes.append(fix)
    return fixes

"""The IMU error model: turns ideal increments into what a BP3010-like unit outputs.

Per axis, in the units of the report's tables (Tables 5.1, 5.5, 5.8, 5.9):
output = (I + scale factor + misalignment) ideal + bias * dt + white noise,
plus, for the gyros, the g-sensitivity G delta-v (a rate error G f),
where bias = turn-on bias + bias instability (a weighted sum of first-order
Gauss-Markov processes whose Allan deviation is flat at 0.664 B) + rate random
walk + warm-up (a drawn step reached as 1 - exp(-t / tau) after power-on).
Quantisation is the frame's LSB, applied by the encoder. Every true value is
returned so tests can set a filter's Q and P0 from it.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from scipy.optimize import nnls

from .draws import Sequential
from .processes import gauss_markov
from .scenario import ImuModel

FLAT_ALLAN_FACTOR = 0.664  # sqrt(2 ln 2 / pi): ADEV of flicker bias instability B


def gm_avar(tau: np.ndarray, sigma: float, t_corr: float) -> np.ndarray:
    """Allan variance of a first-order Gauss-Markov rate with stationary std sigma and time constant t_corr."""
    x = tau / t_corr
    return sigma ** 2 / x ** 2 * (2.0 * x - 3.0 + 4.0 * np.exp(-x) - np.exp(-2.0 * x))


def bias_instability_weights(taus_corr: tuple[float, ...]) -> np.ndarray:
    """Stationary variances (per unit B^2) of GM processes whose summed ADEV is flat at 0.664 B."""
    tc = np.asarray(taus_corr, dtype=float)
    tau = np.logspace(np.log10(tc[0]), np.log10(tc[-1]), 60)
    a = np.stack([gm_avar(tau, 1.0, T) for T in tc], -1)
    w, _ = nnls(a / FLAT_ALLAN_FACTOR ** 2, np.ones_like(tau))
    return w


@dataclass
class ImuErrors:
    """True error values of one simulated unit (SI)."""

    gyro_bias_rad_per_s: np.ndarray  # turn-on bias (3,)
    accel_bias_mps2: np.ndarray
    gyro_matrix: np.ndarray  # (3, 3) = I + scale factor + misalignment
    accel_matrix: np.ndarray
    gyro_bias_drift: np.ndarray  # (n, 3) time-varying part of the bias at each sample
    accel_bias_drift: np.ndarray
    gyro_g_matrix: np.ndarray | None = None  # (3, 3) rad/s per m/s^2 of specific force; None = none
    gyro_warmup_rad_per_s: np.ndarray | None = None  # (3,) where the warm-up takes the bias; None = none
    accel_warmup_mps2: np.ndarray | None = None

    def as_dict(self) -> dict:
        return {k: np.asarray(v).tolist() for k, v in self.__dict__.items() if "drift" not in k and v is not None}


def _vec(x) -> np.ndarray:
    return np.broadcast_to(np.asarray(x, dtype=float), (3,)).copy()


def _matrix(rng, sf, mis_std, m: ImuModel) -> np.ndarray:
    a = np.eye(3)
    if m.terms["scale_factor"]:
        a += np.diag(_vec(sf))
    if m.terms["misalignment"] and mis_std > 0:
        off = rng.normal(0.0, mis_std, (3, 3))
        np.fill_diagonal(off, 0.0)
        a += off
    return a


def _g_sensitivity(rng, m: ImuModel) -> np.ndarray | None:
    return rng.normal(0.0, m.gyro_g_sensitivity_rad_per_s_per_mps2, (3, 3)) \
        if m.gyro_g_sensitivity_rad_per_s_per_mps2 > 0 else None


def _systematic(dtheta, dv, e: ImuErrors, dt: float, gyro_drift, accel_drift):
    """Matrices, biases and g-sensitivity applied to ideal increments (no white noise)."""
    g = dtheta @ e.gyro_matrix.T + (e.gyro_bias_rad_per_s + gyro_drift) * dt
    a = dv @ e.accel_matrix.T + (e.accel_bias_mps2 + accel_drift) * dt
    if e.gyro_g_matrix is not None:
        g += dv @ e.gyro_g_matrix.T
    return g, a


class ImuErrorProcess:
    """One simulated unit's errors, sample range by sample range in order.

    The constant terms (turn-on bias, scale factor and misalignment matrices, the bias
    processes' starting values, g-sensitivity) are drawn once from ``constants``; the
    processes' drives and the white noise come from ``noise(name)``, a source of standard
    normal rows (3 wide) addressed by sample index (``draws.Stream``), so any cut into
    ranges gives the same output. The bias processes carry their state from range to range."""

    def __init__(self, m: ImuModel, constants: np.random.Generator, noise, draw_g_sensitivity: bool = True):
        self.m, self.dt = m, 1.0 / m.rate_hz
        rng = constants
        gb = _vec(m.gyro_bias_rad_per_s) + rng.normal(0.0, m.gyro_bias_residual_rad_per_s, 3)
        ab = _vec(m.accel_bias_mps2) + rng.normal(0.0, m.accel_bias_residual_mps2, 3)
        if not m.terms["turn_on_bias"]:
            gb[:], ab[:] = 0.0, 0.0
        gm = _matrix(rng, m.gyro_scale_factor, m.gyro_misalignment_rad, m)
        am = _matrix(rng, m.accel_scale_factor, m.accel_misalignment_rad, m)
        self._sensors = [self._bias_terms(rng, "gyro", _vec(m.gyro_bias_instability_rad_per_s),
                                          _vec(m.gyro_rrw_rad_per_s_sqrt_s), noise),
                         self._bias_terms(rng, "accel", _vec(m.accel_bias_instability_mps2),
                                          _vec(m.accel_rrw_mps2_per_sqrt_s), noise)]
        # Drawn last and only when asked for, so the other terms' draws stay the same per seed.
        gg = _g_sensitivity(rng, m) if draw_g_sensitivity else None
        self._warmup = [rng.normal(0.0, s, 3) if s > 0 else None
                        for s in (m.gyro_warmup_rad_per_s, m.accel_warmup_mps2)]
        self.constants = ImuErrors(gb, ab, gm, am, np.zeros((0, 3)), np.zeros((0, 3)), gg, *self._warmup)
        self._white = [noise("gyro white"), noise("accel white")] if m.terms["white_noise"] else None
        self._next = 0

    def _bias_terms(self, rng, name: str, b: np.ndarray, k: np.ndarray, noise) -> dict:
        """Gauss-Markov terms [(phi, drive std, state, source)] and the random walk (std, state, source)."""
        m, dt = self.m, self.dt
        gms, rw = [], None
        if m.terms["bias_instability"] and np.any(b > 0):
            var = bias_instability_weights(m.bias_instability_tau_s)
            for j, (T, v) in enumerate(zip(np.asarray(m.bias_instability_tau_s, dtype=float), var)):
                phi = np.exp(-dt / T)
                sig = np.sqrt(v) * b  # stationary std per axis
                x0 = rng.normal(0.0, 1.0, 3) * sig  # start in the stationary distribution
                gms.append([phi, sig * np.sqrt(1.0 - phi * phi), x0, noise(f"{name} bias instability {j}")])
        if m.terms["rate_random_walk"] and np.any(k > 0):
            rw = [k * np.sqrt(dt), np.zeros(3), noise(f"{name} rate random walk")]
        return {"gm": gms, "rw": rw}

    def drift(self, i1: int) -> tuple[np.ndarray, np.ndarray]:
        """Time-varying bias parts (gyro, accel) at samples self._next..i1-1; advances."""
        i0, out = self._next, []
        for s in self._sensors:
            d = np.zeros((i1 - i0, 3))
            for term in s["gm"]:
                phi, std, x, src = term
                y = gauss_markov(x, src.rows(i0, i1) * std, phi)
                term[2] = y[-1] if len(y) else x
                d += y
            if s["rw"] is not None:
                std, x, src = s["rw"]
                y = np.cumsum(np.concatenate([x[None], src.rows(i0, i1) * std]), axis=0)
                s["rw"][1] = y[-1]
                d += y[1:]
            out.append(d)
        if any(step is not None for step in self._warmup):
            settled = 1.0 - np.exp(-np.arange(i0, i1) * self.dt / self.m.warmup_tau_s)
            for d, step in zip(out, self._warmup):
                if step is not None:
                    d += settled[:, None] * step
        self._next = i1
        return out[0], out[1]

    def measure(self, i0: int, dtheta: np.ndarray, dv: np.ndarray, gyro_drift: np.ndarray,
                accel_drift: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Increments of samples i0.. as the unit reports them (before the frame's quantisation)."""
        m, dt = self.m, self.dt
        g, a = _systematic(dtheta, dv, self.constants, dt, gyro_drift, accel_drift)
        if self._white is not None:
            i1 = i0 + len(dtheta)
            g += self._white[0].rows(i0, i1) * _vec(m.gyro_arw_rad_per_sqrt_s) * np.sqrt(dt)
            a += self._white[1].rows(i0, i1) * _vec(m.accel_vrw_mps_per_sqrt_s) * np.sqrt(dt)
        return g, a


def draw_errors(m: ImuModel, n: int, rng: np.random.Generator) -> ImuErrors:
    """A unit's errors over n samples in one piece, every draw from rng in turn (the IMU lab's way)."""
    p = ImuErrorProcess(m, rng, lambda name: Sequential(rng, 3), draw_g_sensitivity=False)
    gd, ad = p.drift(n)
    e = p.constants
    # The g-sensitivity after everything else here too, so switching it on changes no other term.
    return ImuErrors(e.gyro_bias_rad_per_s, e.accel_bias_mps2, e.gyro_matrix, e.accel_matrix, gd, ad,
                     _g_sensitivity(rng, m), e.gyro_warmup_rad_per_s, e.accel_warmup_mps2)


def measure(dtheta: np.ndarray, dv: np.ndarray, m: ImuModel, err: ImuErrors,
            rng: np.random.Generator) -> tuple[np.ndarray, np.ndarray]:
    """Increments as the unit reports them (before the frame's quantisation), white noise from rng."""
    n = len(dtheta)
    dt = 1.0 / m.rate_hz
    g, a = _systematic(dtheta, dv, err, dt, err.gyro_bias_drift, err.accel_bias_drift)
    if m.terms["white_noise"]:
        g += rng.normal(0.0, 1.0, (n, 3)) * _vec(m.gyro_arw_rad_per_sqrt_s) * np.sqrt(dt)
        a += rng.normal(0.0, 1.0, (n, 3)) * _vec(m.accel_vrw_mps_per_sqrt_s) * np.sqrt(dt)
    return g, a

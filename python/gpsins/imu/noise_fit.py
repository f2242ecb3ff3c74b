"""Noise terms from an Allan variance curve (seed 000; IEEE Std 952 terms).

    AVAR(tau) = 3 Q^2 / tau^2 + N^2 / tau + (2 ln 2 / pi) B^2 + K^2 tau / 3 + R^2 tau^2 / 2
                [+ first-order Gauss-Markov terms, seed 000 eq. 10.17]

Q quantisation (rad or m/s), N white rate noise (rad/sqrt(s), m/s/sqrt(s)), B bias
instability (rad/s, m/s^2), K rate random walk (rad/s/sqrt(s), m/s^2/sqrt(s)), R
rate ramp (rad/s^2, m/s^3). Fitted by non-negative least squares on the variance,
each point weighted by its relative uncertainty (sqrt(edf / 2) / AVAR), terms
switchable. The slope read-outs of the report (N on the -1/2 line at tau = 1, K on
the +1/2 line at tau = 3, B = minimum / 0.664) are given for comparison.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field

import numpy as np
from scipy.optimize import nnls

TERMS = ("Q", "N", "B", "K", "R")
FLAT = math.sqrt(2.0 * math.log(2.0) / math.pi)  # 0.664: ADEV floor per unit B

# Unit conversions to the report's table units.
RAD_PER_S_TO_DEG_PER_H = math.degrees(1.0) * 3600.0
RAD_PER_SQRT_S_TO_DEG_PER_SQRT_H = math.degrees(1.0) * 60.0
MPS_PER_SQRT_S_TO_MPS_PER_SQRT_H = 60.0


def basis(tau: np.ndarray, terms=TERMS, gm_tau_s: tuple[float, ...] = ()) -> np.ndarray:
    tau = np.asarray(tau, dtype=float)
    cols = {"Q": 3.0 / tau ** 2, "N": 1.0 / tau, "B": np.full_like(tau, FLAT ** 2), "K": tau / 3.0,
            "R": tau ** 2 / 2.0}
    out = [cols[t] for t in terms]
    for T in gm_tau_s:
        x = tau / T
        out.append((2.0 * x - 3.0 + 4.0 * np.exp(-x) - np.exp(-2.0 * x)) / x ** 2)  # per unit sigma^2
    return np.stack(out, -1)


@dataclass
class NoiseFit:
    terms: tuple[str, ...]
    value: dict  # coefficient per term (SI); Gauss-Markov as 'GM<T>' -> stationary sigma
    sigma: dict  # 1-sigma uncertainty of each coefficient
    model_adev: np.ndarray
    slope_readouts: dict = field(default_factory=dict)


def fit(tau: np.ndarray, adev: np.ndarray, edf: np.ndarray | None = None, terms=("Q", "N", "B", "K"),
        gm_tau_s: tuple[float, ...] = ()) -> NoiseFit:
    tau = np.asarray(tau, dtype=float)
    av = np.asarray(adev, dtype=float) ** 2
    a = basis(tau, terms, gm_tau_s)
    rel = np.sqrt(2.0 / np.asarray(edf, dtype=float)) if edf is not None else np.full(len(tau), 0.1)
    w = 1.0 / (rel * av)
    coef, _ = nnls(a * w[:, None], av * w)
    names = list(terms) + [f"GM{T:g}" for T in gm_tau_s]
    # Uncertainty from the weighted normal matrix of the active terms.
    active = coef > 0
    cov = np.zeros((len(coef), len(coef)))
    if active.any():
        j = (a * w[:, None])[:, active]
        cov_a = np.linalg.pinv(j.T @ j)
        cov[np.ix_(active, active)] = cov_a
    value, sigma = {}, {}
    for i, n in enumerate(names):
        c = math.sqrt(coef[i])
        value[n] = c
        sigma[n] = math.sqrt(cov[i, i]) / (2.0 * c) if c > 0 else math.sqrt(math.sqrt(max(cov[i, i], 0.0)))
    return NoiseFit(tuple(names), value, sigma, np.sqrt(a @ coef), slope_readouts(tau, np.sqrt(av)))


def slope_readouts(tau: np.ndarray, adev: np.ndarray) -> dict:
    """The report's graphical read-outs: N = the -1/2 line at tau = 1 (through the
    shortest-tau decade), K = the +1/2 line at tau = 3 (through the longest-tau decade
    when it rises), B = minimum / 0.664."""
    lt, la = np.log10(tau), np.log10(adev)
    short = lt <= lt[0] + 1.0
    n = 10 ** np.mean(la[short] + 0.5 * lt[short])
    long_ = lt >= lt[-1] - 1.0
    rising = np.polyfit(lt[long_], la[long_], 1)[0] > 0.25 if long_.sum() >= 2 else False
    k = 10 ** np.mean(la[long_] - 0.5 * (lt[long_] - math.log10(3.0))) if rising else float("nan")
    return {"N_at_tau_1": float(n), "K_at_tau_3": float(k), "B_min_over_0.664": float(adev.min() / FLAT),
            "tau_at_min_s": float(tau[np.argmin(adev)])}


def table_units(kind: str, fitres: NoiseFit) -> dict:
    """Coefficients in the report's table units: gyro deg/sqrt(h), deg/h, deg/h/sqrt(h);
    accelerometer m/s/sqrt(h), m/s^2, m/s^2/sqrt(h)."""
    v = fitres.value
    if kind == "gyro":
        return {"N_deg_per_sqrt_h": v.get("N", 0) * RAD_PER_SQRT_S_TO_DEG_PER_SQRT_H,
                "B_deg_per_h": v.get("B", 0) * RAD_PER_S_TO_DEG_PER_H,
                "K_deg_per_h_sqrt_h": v.get("K", 0) * RAD_PER_S_TO_DEG_PER_H * 60.0}
    return {"N_mps_per_sqrt_h": v.get("N", 0) * MPS_PER_SQRT_S_TO_MPS_PER_SQRT_H, "B_mps2": v.get("B", 0),
            "K_mps2_per_sqrt_h": v.get("K", 0) * 60.0}


def fit_term_curve(tau: np.ndarray, f: NoiseFit, term: str) -> np.ndarray | None:
    """ADEV of one fitted term alone (for plots)."""
    c = f.value.get(term, 0.0)
    if c <= 0:
        return None
    if term.startswith("GM"):
        return c * np.sqrt(basis(tau, (), (float(term[2:]),))[:, 0])
    return c * np.sqrt(basis(tau, (term,))[:, 0])

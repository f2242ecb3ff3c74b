"""Noise terms from an Allan variance curve (seed 000; IEEE Std 952 terms).

    AVAR(tau) = 3 Q^2 / tau^2 + N^2 / tau + (2 ln 2 / pi) B^2 + K^2 tau / 3 + R^2 tau^2 / 2
                [+ first-order Gauss-Markov terms, seed 000 eq. 10.17]

Q quantisation (rad or m/s), N white rate noise (rad/sqrt(s), m/s/sqrt(s)), B bias
instability (rad/s, m/s^2), K rate random walk (rad/s/sqrt(s), m/s^2/sqrt(s)), R
rate ramp (rad/s^2, m/s^3). Fitted by non-negative least squares on the variance,
each point weighted by its relative uncertainty (sqrt(edf / 2) / AVAR of the model,
iterated from the data's AVAR), terms switchable. The slope read-outs of the report (N on the -1/2 line at tau = 1, K on
the +1/2 line at tau = 3, B = minimum / 0.664) are given for comparison, but only
from taus with at least MIN_EDF equivalent degrees of freedom: at the last taus of
a record (2-3 degrees of freedom) the curve scatters by tens of percent and its
minimum is picked where it scattered low.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field

import numpy as np
from scipy.optimize import nnls

TERMS = ("Q", "N", "B", "K", "R")
MIN_EDF = 10.0  # slope read-outs use only taus with this many equivalent degrees of freedom
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
        gm_tau_s: tuple[float, ...] = (), min_edf: float = MIN_EDF) -> NoiseFit:
    tau = np.asarray(tau, dtype=float)
    av = np.asarray(adev, dtype=float) ** 2
    a = basis(tau, terms, gm_tau_s)
    rel = np.sqrt(2.0 / np.asarray(edf, dtype=float)) if edf is not None else np.full(len(tau), 0.1)
    w = 1.0 / (rel * av)
    coef, _ = nnls(a * w[:, None], av * w)
    # Reweight by the model, not the data: a point that scattered low (the last taus, a few degrees
    # of freedom) would otherwise get a weight 1 / AVAR large enough to drag the whole fit down.
    for _ in range(4):
        model = np.maximum(a @ coef, 1e-300)
        w = 1.0 / (rel * model)
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
    ro = slope_readouts(tau, np.sqrt(av), edf, min_edf)
    if "tau_at_min_s" in ro:
        # The minimum also holds the white noise, random walk and quantisation there (the curve of a
        # MEMS gyro rarely flattens): less the fitted other terms, the read-out is comparable with B.
        t = np.array([ro["tau_at_min_s"]])
        others = sum(value.get(k, 0.0) ** 2 * basis(t, (k,))[0, 0] for k in ("Q", "N", "K", "R") if k in terms)
        left = (ro["B_min_over_0.664"] * FLAT) ** 2 - others
        ro["B_min_less_other_terms"] = float(math.sqrt(left) / FLAT) if left > 0 else 0.0
    return NoiseFit(tuple(names), value, sigma, np.sqrt(a @ coef), ro)


def slope_readouts(tau: np.ndarray, adev: np.ndarray, edf: np.ndarray | None = None,
                   min_edf: float = MIN_EDF) -> dict:
    """The report's graphical read-outs: N = the -1/2 line at tau = 1 (through the
    shortest-tau decade), K = the +1/2 line at tau = 3 (through the longest-tau decade
    when it rises), B = minimum / 0.664; only taus with edf >= min_edf take part. When
    the minimum falls on the last such tau the curve may still be falling: B is then
    flagged as an upper bound (``B_is_upper_bound``)."""
    tau, adev = np.asarray(tau, dtype=float), np.asarray(adev, dtype=float)
    ok = np.ones(len(tau), bool) if edf is None else np.asarray(edf, dtype=float) >= min_edf
    if ok.sum() < 2:
        return {"min_edf": min_edf, "taus_used": int(ok.sum()),
                "warning": f"fewer than 2 taus with at least {min_edf:g} degrees of freedom: no read-outs"}
    tau, adev = tau[ok], adev[ok]
    lt, la = np.log10(tau), np.log10(adev)
    short = lt <= lt[0] + 1.0
    n = 10 ** np.mean(la[short] + 0.5 * lt[short])
    long_ = lt >= lt[-1] - 1.0
    rising = np.polyfit(lt[long_], la[long_], 1)[0] > 0.25 if long_.sum() >= 2 else False
    k = 10 ** np.mean(la[long_] - 0.5 * (lt[long_] - math.log10(3.0))) if rising else float("nan")
    j = int(np.argmin(adev))
    return {"N_at_tau_1": float(n), "K_at_tau_3": float(k), "B_min_over_0.664": float(adev[j] / FLAT),
            "tau_at_min_s": float(tau[j]), "B_is_upper_bound": bool(j == len(tau) - 1), "min_edf": min_edf,
            "taus_used": int(ok.sum()), "max_tau_used_s": float(tau[-1])}


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


GM_PEAK_TAU_PER_T = 1.89  # seed 000: the Gauss-Markov ADEV peaks at tau = 1.89 T
GM_PEAK_PER_SIGMA = 0.617  # ... at 0.617 of the stationary sigma (ERRATA), = 0.437 q_c sqrt(T)
GM_PEAK_PER_QC_SQRT_T = 0.437


def gauss_markov_bump(tau: np.ndarray, adev: np.ndarray, lo: np.ndarray, hi: np.ndarray, edf: np.ndarray,
                      min_edf: float = MIN_EDF) -> dict | None:
    """The seed-000 read-out of a bump: an interior maximum whose lower bound lies above the upper
    bounds of points on both sides (a significant rise and fall), from taus with edf >= min_edf.
    T = tau_peak / 1.89, stationary sigma = peak / 0.617, driving density q_c = peak / (0.437 sqrt(T))."""
    ok = np.asarray(edf) >= min_edf
    tau, adev, lo, hi = (np.asarray(v)[ok] for v in (tau, adev, lo, hi))
    for j in np.argsort(adev)[::-1]:
        if 0 < j < len(tau) - 1 and (hi[:j] < lo[j]).any() and (hi[j + 1:] < lo[j]).any():
            T = tau[j] / GM_PEAK_TAU_PER_T
            return {"tau_peak_s": float(tau[j]), "peak": float(adev[j]), "T_s": float(T),
                    "sigma": float(adev[j] / GM_PEAK_PER_SIGMA),
                    "q_c": float(adev[j] / (GM_PEAK_PER_QC_SQRT_T * math.sqrt(T)))}
    return None


def model_psd(f: np.ndarray, value: dict, tau0: float) -> np.ndarray:
    """Two-sided rate PSD of the fitted terms (IEEE Std 952 forms): Q (2 pi f)^2 Q^2 tau0, N^2,
    B^2 / (2 pi f), K^2 / (2 pi f)^2, plus Gauss-Markov terms 'GM<T>' (stationary sigma s:
    2 s^2 / T / ((1/T)^2 + (2 pi f)^2) / 2)."""
    w = 2 * math.pi * np.asarray(f, dtype=float)
    s = (value.get("Q", 0.0) ** 2 * w ** 2 * tau0 + value.get("N", 0.0) ** 2 + value.get("B", 0.0) ** 2 / w
         + value.get("K", 0.0) ** 2 / w ** 2)
    for name, c in value.items():
        if name.startswith("GM") and c > 0:
            T = float(name[2:])
            s = s + c ** 2 / T / ((1 / T) ** 2 + w ** 2)
    return s


def window_combination_variance(value: dict, tau0: float, windows: list[tuple[float, float, float]]) -> float:
    """Variance of sum_k weight_k * mean(rate over [start_k, start_k + length_k]) for a noise with the
    fitted terms: 2 int_0^{1/(2 tau0)} S(f) |H(f)|^2 df, H the combination's transfer function. The
    weights must sum to zero (a difference of means: its variance is finite for flicker and random walk).
    Above 20 / (shortest window) the oscillating terms are replaced by their mean, which drops the
    correlation of adjacent windows' shared edge: the white-phase (Q) part comes out up to a third low,
    the white-rate part 0.5 % low; both are negligible against drift for windows of seconds or longer.
    windows: (start_s, length_s, weight). Two adjacent windows of length T, weights -1 and +1, give 2 AVAR(T)."""
    return float(window_combination_covariance(value, tau0, [windows])[0, 0])


def window_combination_covariance(value: dict, tau0: float,
                                  combinations: list[list[tuple[float, float, float]]]) -> np.ndarray:
    """Covariance matrix of several such combinations (2 int S Re(H_j conj(H_k)) df); in the averaged
    tail only identical windows of two combinations correlate."""
    allw = [w for c in combinations for w in c]
    starts = np.array([w[0] for w in allw])
    lengths = np.array([w[1] for w in allw])
    span = starts.max() + lengths.max() - starts.min()
    f_hi = 0.5 / tau0
    f_cut = min(f_hi, 20.0 / lengths.min())  # above it the sinc terms are replaced by their mean
    f = np.logspace(math.log10(1e-4 / span), math.log10(f_cut), 20000)
    hs = []
    for c in combinations:
        st, ln, wt = (np.array([w[i] for w in c]) for i in range(3))
        hs.append((wt[None, :] * np.sinc(f[:, None] * ln[None, :]) *
                   np.exp(-2j * math.pi * f[:, None] * (st + ln / 2)[None, :])).sum(1))
    h = np.stack(hs, 1)  # (frequencies, combinations)
    s = model_psd(f, value, tau0) * f
    cov = np.trapezoid(s[:, None, None] * np.real(h[:, :, None] * np.conj(h[:, None, :])), np.log(f), axis=0)
    if f_cut < f_hi:
        f2 = np.logspace(math.log10(f_cut), math.log10(f_hi), 2000)
        tail = model_psd(f2, value, tau0) * f2 / (2 * math.pi ** 2 * f2 ** 2)
        for j, cj in enumerate(combinations):
            for k, ck in enumerate(combinations):
                shared = sum(wa[2] * wb[2] / wa[1] ** 2 for wa in cj for wb in ck if wa[:2] == wb[:2])
                if shared:
                    cov[j, k] += shared * np.trapezoid(tail, np.log(f2))
    return 2.0 * cov

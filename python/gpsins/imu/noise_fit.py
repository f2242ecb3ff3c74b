"""Noise terms from an Allan variance curve (IEEE Std 952 terms; the
tuning notes in docs/references.md).

    AVAR(tau) = 3 Q^2 / tau^2 + N^2 / tau + (2 ln 2 / pi) B^2 + K^2 tau / 3 + R^2 tau^2 / 2
                [+ first-order Gauss-Markov terms, the tuning notes' eq. 10.17]

Q quantisation (rad or m/s), N white rate noise (rad/sqrt(s), m/s/sqrt(s)), B bias
instability (rad/s, m/s^2), K rate random walk (rad/s/sqrt(s), m/s^2/sqrt(s)), R
rate ramp (rad/s^2, m/s^3); terms switchable.

The sensor's own output filter. A sensor that low-passes its samples (the ADIS16405's
Bartlett FIR, any anti-alias filter) makes them correlated: with g_k the autocovariance
of the white part at lag k (zero beyond L samples), the second difference of m >= L
samples gives exactly

    AVAR(tau) = N^2 / tau - 3 F^2 / tau^2,   N^2 = tau0 sum_k g_k,   F^2 = tau0^2 sum_{k>=1} k g_k,

a white-phase term of negative sign (a first-order filter of time constant T: F^2 = N^2 T / 2).
So the 1/tau^2 coefficient is fitted with either sign: positive is quantisation (Q),
negative the filter (reported as F); ADEV alone cannot tell the two apart where both act.
Without it the bend of the shortest taus, which hold by far the most degrees of freedom,
was taken up by B: a synthetic 2.78 h, 100 Hz record through a 40 Hz low-pass got B twice
its read-out and a curve above the data from 0.1 s on, as the issue's ADIS16405 log did.

Fitted by least squares in log AVAR (coefficients >= 0 but the 1/tau^2 one), each tau
weighted by the chi-square spread of its estimate: log(chi2_nu / nu) has mean
psi(nu/2) - ln(nu/2) (subtracted) and variance psi'(nu/2), nu the equivalent degrees of
freedom. In logs a last tau with two degrees of freedom whose ADEV scattered ten times low
is a three-sigma point, not one that drags the fit down. Taus shorter than the filter's length
follow no term: the shortest taus are left out while the fit misses the shortest one kept
by more than TRIM_SIGMA (within the first decade; `fitted_from_tau_s` says where it starts).

The slope read-outs of the report (N on the -1/2 line at tau = 1, K on the +1/2 line at
tau = 3, B = minimum / 0.664) are given for comparison, but only from taus with at least
MIN_EDF equivalent degrees of freedom: at the last taus of a record (2-3 degrees of
freedom) the curve scatters by tens of percent and its minimum is picked where it
scattered low.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field

import numpy as np
from scipy.optimize import least_squares, nnls
from scipy.special import digamma, polygamma

from ..nav.config import GM_PEAK_PER_SIGMA

TERMS = ("Q", "N", "B", "K", "R")
MIN_EDF = 10.0  # slope read-outs use only taus with this many equivalent degrees of freedom
TRIM_SIGMA = 5.0  # a shortest tau missed by more than this many sigmas of its log AVAR is left out
EDF_UNKNOWN = 200.0  # degrees of freedom assumed per tau when none are given (10 % in AVAR)
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
    fitted_from_tau_s: float = 0.0  # the shortest tau the fit used (shorter ones: the sensor's filter)


def fit(tau: np.ndarray, adev: np.ndarray, edf: np.ndarray | None = None, terms=("Q", "N", "B", "K"),
        gm_tau_s: tuple[float, ...] = (), min_edf: float = MIN_EDF) -> NoiseFit:
    tau = np.asarray(tau, dtype=float)
    av = np.asarray(adev, dtype=float) ** 2
    a = basis(tau, terms, gm_tau_s)
    nu = np.full(len(tau), EDF_UNKNOWN) if edf is None else np.maximum(np.asarray(edf, dtype=float), 1.0)
    y = np.log(av) - (digamma(nu / 2) - np.log(nu / 2))  # unbiased log AVAR
    sd = np.sqrt(polygamma(1, nu / 2))
    names = list(terms) + [f"GM{T:g}" for T in gm_tau_s]
    signed = np.array([n == "Q" for n in names])
    # Unknowns are each term's share of the data (coefficient / scale): all of order one.
    scale = np.array([np.median(av / a[:, j]) for j in range(a.shape[1])])
    b = a * scale
    # Start: every tau weighted alike in relative terms, the signed term as two columns.
    z, _ = nnls(np.column_stack([b, -b[:, signed]]) / av[:, None], np.ones(len(tau)))
    x0 = z[:len(names)].copy()
    x0[signed] -= z[len(names):]
    x0 = np.where(signed, x0, np.maximum(x0, 1e-6))

    def model(x):
        return b @ x

    def resid(x):
        m = model(x)
        return (np.log(np.maximum(m, 1e-12 * av)) - y) / sd

    def jac(x):
        m = model(x)
        j = b / (m * sd)[:, None]
        j[m <= 1e-12 * av] = 0.0  # a negative model there: a constant penalty, no gradient
        return j

    lo = np.where(signed, -np.inf, 0.0)

    def solve(x, used):
        return least_squares(lambda v: resid(v)[used], x, jac=lambda v: jac(v)[used], bounds=(lo, np.inf),
                             method="trf", x_scale="jac", xtol=1e-12, ftol=1e-12, gtol=1e-12, max_nfev=500).x

    # The shortest taus go while the fit misses the shortest one kept by more than TRIM_SIGMA: below
    # the length of a sensor's output filter no term describes the curve, and these taus hold the
    # most degrees of freedom. Only within the first decade of taus, and never below p + 3 taus.
    first = 0
    x = solve(x0, slice(0, None))
    last_first = min(int(np.searchsorted(tau, 10.0 * tau[0])), len(tau) - len(names) - 3)
    while first < last_first and abs(resid(x)[first]) > TRIM_SIGMA:
        first += 1
        x = solve(x, slice(first, None))
    used = np.arange(len(tau)) >= first
    x = np.where(signed | (x > 1e-9), x, 0.0)  # a term at its bound: absent (the solver stops just above)
    coef = x * scale
    # Uncertainty from the normal matrix of the active terms over the taus used, widened by the
    # scatter when the model misses by more than the chi-square allows.
    r = resid(x)[used]
    active = (coef != 0) & ((coef > 0) | signed)
    cov = np.zeros((len(coef), len(coef)))
    if active.any():
        j = jac(x)[used][:, active]
        dof = max(int(used.sum()) - int(active.sum()), 1)
        birge = max(1.0, float(np.sum(r ** 2)) / dof)
        sa = scale[active]
        cov[np.ix_(active, active)] = np.linalg.pinv(j.T @ j) * np.outer(sa, sa) * birge
    value, sigma = {}, {}
    out_names = list(names)
    for i, n in enumerate(names):
        c = coef[i]
        if n == "Q" and c < 0:
            value["Q"], sigma["Q"] = 0.0, 0.0
            value["F"], sigma["F"] = math.sqrt(-c), math.sqrt(cov[i, i]) / (2.0 * math.sqrt(-c))
            out_names.append("F")
            continue
        c = math.sqrt(max(c, 0.0))
        value[n] = c
        sigma[n] = math.sqrt(cov[i, i]) / (2.0 * c) if c > 0 else math.sqrt(math.sqrt(max(cov[i, i], 0.0)))
    ro = slope_readouts(tau, np.sqrt(av), edf, min_edf)
    if "tau_at_min_s" in ro:
        # The minimum also holds the white noise, random walk and quantisation there (the curve of a
        # MEMS gyro rarely flattens): less the fitted other terms, the read-out is comparable with B.
        t = np.array([ro["tau_at_min_s"]])
        keep = [i for i, n in enumerate(names) if n in ("Q", "N", "K", "R")]
        others = float(basis(t, terms, gm_tau_s)[0, keep] @ coef[keep]) if keep else 0.0
        left = (ro["B_min_over_0.664"] * FLAT) ** 2 - others
        ro["B_min_less_other_terms"] = float(math.sqrt(left) / FLAT) if left > 0 else 0.0
    return NoiseFit(tuple(out_names), value, sigma, np.sqrt(np.maximum(a @ coef, 0.0)), ro, float(tau[first]))


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


RATE_UNITS = {"gyro": "rad/s", "accel": "m/s^2"}


def rate_unit(name: str) -> str:
    """SI unit of a column's rate from its name (gyro_x, accel, ...); 'u' when the name does not say."""
    return RATE_UNITS.get(name.split("_")[0], "u")


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
    """ADEV of one fitted term alone (for plots); None for F, which only takes variance away."""
    c = f.value.get(term, 0.0)
    if c <= 0 or term == "F":
        return None
    if term.startswith("GM"):
        return c * np.sqrt(basis(tau, (), (float(term[2:]),))[:, 0])
    return c * np.sqrt(basis(tau, (term,))[:, 0])


GM_PEAK_TAU_PER_T = 1.89  # the Gauss-Markov ADEV peaks at tau = 1.89 T
# ... at GM_PEAK_PER_SIGMA = 0.617 of the stationary sigma q_c sqrt(T/2) (= 0.437 q_c sqrt(T))
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

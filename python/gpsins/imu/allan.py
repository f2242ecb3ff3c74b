"""Overlapping Allan deviation of rate data (or of phase / integrated rate).

For rate samples y at interval tau0, the phase is x = tau0 * cumsum(y) (with a
leading 0) and, with m the cluster size and tau = m tau0,

    AVAR(tau) = sum_{i=0}^{N-2m-1} (x[i+2m] - 2 x[i+m] + x[i])^2 / (2 tau^2 (N - 2m)),

N the number of phase points: one pass per tau (the C++ kernel), so O(N) per
tau. The mean rate is removed first: it does not change AVAR but would cost
digits in the cumulative sum.

Confidence intervals: the report's eq. 5.9 (relative sigma 1 / sqrt(2 (N/m - 1)))
and chi-square intervals with the equivalent degrees of freedom of overlapping
ADEV by noise type (Howe, Allan and Barnes 1981, the simple formulas).
"""

from __future__ import annotations

import os
from concurrent.futures import ThreadPoolExecutor
from dataclasses import dataclass

import numpy as np
from scipy.stats import chi2

from .. import _core

# Noise types are the power-law exponent alpha of the rate (frequency) PSD: +2 white phase
# (quantisation), +1 flicker phase, 0 white rate (ARW), -1 flicker rate (bias instability),
# -2 random-walk rate (RRW).


def cluster_sizes(n_phase: int, spec: str | int = 10) -> np.ndarray:
    """Cluster sizes m for N phase points: 'octave' (1, 2, 4, ...), 'all', 'decade'
    (1, 2, 4 per decade), or points per decade (log-spaced, rounded, unique)."""
    m_max = (n_phase - 1) // 2
    if m_max < 1:
        raise ValueError(f"too few samples for an Allan deviation ({n_phase - 1})")
    if spec == "octave":
        return 2 ** np.arange(int(np.log2(m_max)) + 1)
    if spec == "all":
        return np.arange(1, m_max + 1)
    if spec == "decade":
        m = np.concatenate([[1, 2, 4] * 10 ** k for k in range(int(np.log10(m_max)) + 1)])
        return m[m <= m_max]
    per_decade = int(spec)
    m = np.unique(np.round(np.logspace(0, np.log10(m_max), int(np.log10(m_max) * per_decade) + 1)).astype(np.int64))
    return m[(m >= 1) & (m <= m_max)]


def phase_from_rate(y: np.ndarray, tau0: float) -> np.ndarray:
    y = np.asarray(y, dtype=float)
    return np.concatenate([[0.0], np.cumsum((y - y.mean()) * tau0)])


def oavar_phase(x: np.ndarray, tau0: float, m: np.ndarray) -> np.ndarray:
    """Overlapping Allan variance of a phase series at cluster sizes m."""
    x = np.ascontiguousarray(x, dtype=float)
    m = np.asarray(m, dtype=np.int64)
    sums = _core.allan_second_difference_sums(x, m)
    tau = m * tau0
    return sums / (2.0 * tau ** 2 * (len(x) - 2 * m))


def edf_simple(n_phase: int, m: np.ndarray, alpha: int | np.ndarray) -> np.ndarray:
    """Equivalent degrees of freedom of overlapping ADEV (Howe, Allan, Barnes 1981)."""
    N = float(n_phase)
    m = np.asarray(m, dtype=float)
    alpha = np.broadcast_to(np.asarray(alpha), m.shape)
    out = np.empty_like(m)
    for i, (mm, a) in enumerate(zip(m, alpha)):
        if a == 2:
            e = (N + 1) * (N - 2 * mm) / (2 * (N - mm))
        elif a == 1:
            e = np.exp(np.sqrt(np.log((N - 1) / (2 * mm)) * np.log((2 * mm + 1) * (N - 1) / 4)))
        elif a == 0:
            e = (3 * (N - 1) / (2 * mm) - 2 * (N - 2) / N) * 4 * mm ** 2 / (4 * mm ** 2 + 5)
        elif a == -1:
            e = 2 * (N - 2) / (2.3 * N - 4.9) if mm == 1 else 5 * N ** 2 / (4 * mm * (N + 3 * mm))
        else:
            e = (N - 2) / mm * ((N - 1) ** 2 - 3 * mm * (N - 1) + 4 * mm ** 2) / (N - 3) ** 2
        out[i] = max(e, 1.0)
    return out


def noise_type_lag1(x: np.ndarray, m: np.ndarray) -> np.ndarray:
    """Dominant power-law noise per cluster size from the lag-1 autocorrelation of the
    m-averaged rate (Riley and Greenhall), alpha in {2, 1, 0, -1, -2}."""
    out = []
    for mm in np.asarray(m):
        y = (x[mm::mm] - x[:-mm:mm])  # m-averaged rate (times tau), non-overlapping
        d = 0
        while True:
            z = y - y.mean()
            if len(z) < 30:
                out.append(out[-1] if out else 0)
                break
            r1 = np.dot(z[:-1], z[1:]) / np.dot(z, z)
            delta = r1 / (1 + r1)
            if delta < 0.25 or d >= 2:
                # On rate (frequency) data the exponent is alpha itself.
                out.append(int(np.clip(-np.round(2 * delta) - 2 * d, -2, 2)))
                break
            y = np.diff(y)
            d += 1
    return np.array(out)


@dataclass
class AllanResult:
    tau: np.ndarray  # s
    adev: np.ndarray  # per tau (, axes)
    m: np.ndarray
    n_phase: int
    tau0: float
    alpha: np.ndarray  # noise type used for the EDF, per tau (, axes)
    edf: np.ndarray
    lo: np.ndarray  # chi-square bounds at `confidence`
    hi: np.ndarray
    rel_sigma_eq59: np.ndarray  # the report's eq. 5.9 relative uncertainty of ADEV
    confidence: float
    estimator: str = "overlapping"

    @property
    def avar(self) -> np.ndarray:
        return self.adev ** 2

    @property
    def eq59_lo(self) -> np.ndarray:
        """ADEV minus its eq. 5.9 one-sigma error (floored at zero)."""
        rel = self.rel_sigma_eq59 if self.adev.ndim == 1 else self.rel_sigma_eq59[:, None]
        return np.maximum(self.adev * (1.0 - rel), 0.0)

    @property
    def eq59_hi(self) -> np.ndarray:
        rel = self.rel_sigma_eq59 if self.adev.ndim == 1 else self.rel_sigma_eq59[:, None]
        return self.adev * (1.0 + rel)


def oadev(data: np.ndarray, rate_hz: float, *, taus: str | int = 10, data_type: str = "rate",
          confidence: float = 0.683, alpha: int | None = None) -> AllanResult:
    """Overlapping ADEV of rate data (n,) or (n, axes), or of phase data with data_type='phase'."""
    a = np.asarray(data, dtype=float)
    single = a.ndim == 1
    a = a[:, None] if single else a
    tau0 = 1.0 / rate_hz
    xs = [a[:, k] if data_type == "phase" else phase_from_rate(a[:, k], tau0) for k in range(a.shape[1])]
    n = len(xs[0])
    m = cluster_sizes(n, taus)
    # The kernel releases the GIL: axes run in parallel on the machine's cores.
    with ThreadPoolExecutor(max_workers=min(len(xs), os.cpu_count() or 1)) as pool:
        av = np.stack(list(pool.map(lambda x: oavar_phase(x, tau0, m), xs)), -1)
    al = np.stack([noise_type_lag1(x, m) if alpha is None else np.full(len(m), alpha) for x in xs], -1)
    edf = np.stack([edf_simple(n, m, al[:, k]) for k in range(len(xs))], -1)
    adev, lo, hi = _chi2_bounds(av, edf, confidence)
    rel = 1.0 / np.sqrt(2.0 * (n / m - 1.0))
    squeeze = (lambda v: v[:, 0]) if single else (lambda v: v)
    return AllanResult(m * tau0, squeeze(adev), m, n, tau0, squeeze(al), squeeze(edf), squeeze(lo), squeeze(hi), rel,
                       confidence, "overlapping")


def _chi2_bounds(avar: np.ndarray, edf: np.ndarray, confidence: float) -> tuple[np.ndarray, ...]:
    """ADEV and its two-sided chi-square confidence bounds for the given degrees of freedom."""
    p_lo, p_hi = (1 - confidence) / 2, (1 + confidence) / 2
    adev = np.sqrt(avar)
    return adev, adev * np.sqrt(edf / chi2.ppf(p_hi, edf)), adev * np.sqrt(edf / chi2.ppf(p_lo, edf))


def adev_nonoverlapping(data: np.ndarray, rate_hz: float, *, taus: str | int = 10,
                        confidence: float = 0.683) -> AllanResult:
    """The report's estimator (eq. 5.6-5.7): means of floor(N/n) disjoint clusters of n rate samples,
    half the mean squared difference of successive means. Chi-square bounds with floor(N/n) - 1
    degrees of freedom (the number of differences; exact for white rate noise), and eq. 5.9."""
    a = np.asarray(data, dtype=float)
    single = a.ndim == 1
    a = a[:, None] if single else a
    n = len(a)
    m = cluster_sizes(n + 1, taus)
    m = m[n // m >= 3]
    av = np.empty((len(m), a.shape[1]))
    for i, mm in enumerate(m):
        k = n // mm
        means = a[:k * mm].reshape(k, mm, -1).mean(1)
        av[i] = 0.5 * np.mean(np.diff(means, axis=0) ** 2, axis=0)
    edf = np.repeat((n // m - 1.0)[:, None], a.shape[1], 1)
    adev, lo, hi = _chi2_bounds(av, edf, confidence)
    rel = 1.0 / np.sqrt(2.0 * (n / m - 1.0))
    squeeze = (lambda v: v[:, 0]) if single else (lambda v: v)
    alpha = np.zeros_like(edf, dtype=int)
    return AllanResult(m / rate_hz, squeeze(adev), m, n + 1, 1.0 / rate_hz, squeeze(alpha), squeeze(edf), squeeze(lo),
                       squeeze(hi), rel, confidence, "non-overlapping")

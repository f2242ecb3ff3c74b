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


def phase_from_rate(y: np.ndarray, tau0: float, out: np.ndarray | None = None) -> np.ndarray:
    """x = tau0 * cumsum(y - mean) after a leading 0, N + 1 points. ``out`` (N + 1 float64, contiguous)
    receives it; ``out[1:]`` may be y itself, which is then overwritten (no copy of the record is made)."""
    y = np.asarray(y, dtype=float)
    x = np.empty(len(y) + 1) if out is None else out
    mean = y.mean()
    # The same operations as tau0 * cumsum(y - mean), element by element, without full-size temporaries.
    for a in range(0, len(y), _CHUNK):
        b = min(len(y), a + _CHUNK)
        np.subtract(y[a:b], mean, out=x[a + 1:b + 1])
        np.multiply(x[a + 1:b + 1], tau0, out=x[a + 1:b + 1])
    x[0] = 0.0
    # In place: accumulate reads y[i] before it writes x[i] (checked: identical to np.cumsum's copy).
    np.add.accumulate(x[1:], out=x[1:])
    return x


_CHUNK = 1 << 20  # elements per piece of the element-wise passes: temporaries that stay in cache


def oavar_phase(x: np.ndarray, tau0: float, m: np.ndarray, workers: int = 1) -> np.ndarray:
    """Overlapping Allan variance of a phase series at cluster sizes m; ``workers`` threads share the
    cluster sizes (each sum is computed whole by one of them, so the result does not depend on it)."""
    m = np.asarray(m, dtype=np.int64)
    with ThreadPoolExecutor(max_workers=max(1, workers)) as pool:
        return _avar(_sums_started(pool, x, m, workers), x, tau0, m)


def _sums_started(pool: ThreadPoolExecutor, x: np.ndarray, m: np.ndarray, workers: int) -> list:
    """The kernel's sums, started on ``pool``: ``workers`` interleaved shares of the cluster sizes."""
    x = np.ascontiguousarray(x, dtype=float)
    workers = max(1, min(workers, len(m)))
    return [pool.submit(_core.allan_second_difference_sums, x, m[k::workers]) for k in range(workers)]


def _avar(running: list, x: np.ndarray, tau0: float, m: np.ndarray) -> np.ndarray:
    sums = np.empty(len(m))
    for k, r in enumerate(running):
        sums[k::len(running)] = r.result()
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
    m-averaged rate (Riley and Greenhall), alpha in {2, 1, 0, -1, -2}.

    For each m the m-averaged rate (times tau, non-overlapping) y = x[m::m] - x[:-m:m] is tested
    as it is (d = 0) and, while it looks like a random walk (delta >= 0.25), differenced again,
    at most twice. The sums of every m at one d come from one pass of the C++ core over the phase
    (``_core.allan_lag1_sums``), the mean of each series from its ends (differences telescope):
    r1 can differ from NumPy's in its last digits, which would move alpha only at an exact threshold."""
    x = np.ascontiguousarray(x, dtype=float)
    ms = [int(v) for v in np.asarray(m)]
    points = [(len(x) - 1) // mm + 1 for mm in ms]  # x[0], x[m], x[2m], ...
    r1: dict[tuple[int, int], float] = {}
    wanted = [i for i in range(len(ms)) if points[i] - 1 >= 30]
    for d in range(3):
        if not wanted:
            break
        means = np.empty(len(wanted))
        for j, i in enumerate(wanted):
            mm, n = ms[i], points[i] - 1 - d
            # The sum of the d-th differences of the points' first differences telescopes.
            first = np.diff(x[0:d * mm + 1:mm], d)[0]
            last = np.diff(x[n * mm:(n + d) * mm + 1:mm], d)[0]
            means[j] = float(last - first) / n
        sums = _core.allan_lag1_sums(x, np.array([ms[i] for i in wanted], dtype=np.int64),
                                     np.full(len(wanted), d, dtype=np.int64), means)
        for j, i in enumerate(wanted):
            r1[i, d] = float(sums[j, 1] / sums[j, 0])
        # Differenced again: those that look like a random walk and still have 30 values.
        wanted = [i for i in wanted if _delta(r1[i, d]) >= 0.25 and points[i] - 2 - d >= 30]
    out = []
    for i in range(len(ms)):  # as the series were tested one after the other
        d = 0
        while True:
            if points[i] - 1 - d < 30:  # too few values: as the cluster size before
                out.append(out[-1] if out else 0)
                break
            delta = _delta(r1[i, d])
            if delta < 0.25 or d >= 2:
                # On rate (frequency) data the exponent is alpha itself.
                out.append(int(np.clip(-np.round(2 * delta) - 2 * d, -2, 2)))
                break
            d += 1
    return np.array(out)


def _delta(r1: float) -> float:
    return r1 / (1 + r1)


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
          confidence: float = 0.683, alpha: int | None = None, meanwhile=None) -> AllanResult:
    """Overlapping ADEV of rate data (n,) or (n, axes), or of phase data with data_type='phase'.
    One axis at a time (one phase series in memory beside the data); the kernel releases the GIL and
    the machine's cores share each axis's cluster sizes while another thread identifies the noise.
    ``meanwhile()``: run once on the calling thread while they work (the command imports the noise
    fit's SciPy there: imports stay on one thread)."""
    a = np.asarray(data, dtype=float)
    single = a.ndim == 1
    a = a[:, None] if single else a
    tau0 = 1.0 / rate_hz
    n = len(a) if data_type == "phase" else len(a) + 1
    m = cluster_sizes(n, taus)
    workers = os.cpu_count() or 1
    av, al = np.empty((len(m), a.shape[1])), np.empty((len(m), a.shape[1]), dtype=int)
    x = None
    with ThreadPoolExecutor(max_workers=workers + 1) as pool:
        for k in range(a.shape[1]):
            x = a[:, k] if data_type == "phase" else phase_from_rate(a[:, k], tau0, x)
            running = _sums_started(pool, x, m, workers)
            # The noise identification reads the same phase beside the kernel.
            ident = pool.submit(noise_type_lag1, x, m) if alpha is None else None
            if meanwhile is not None:
                meanwhile()
                meanwhile = None
            av[:, k] = _avar(running, x, tau0, m)
            al[:, k] = ident.result() if ident is not None else np.full(len(m), alpha)
    edf = np.stack([edf_simple(n, m, al[:, k]) for k in range(a.shape[1])], -1)
    adev, lo, hi = _chi2_bounds(av, edf, confidence)
    rel = 1.0 / np.sqrt(2.0 * (n / m - 1.0))
    squeeze = (lambda v: v[:, 0]) if single else (lambda v: v)
    return AllanResult(m * tau0, squeeze(adev), m, n, tau0, squeeze(al), squeeze(edf), squeeze(lo), squeeze(hi), rel,
                       confidence, "overlapping")


def _chi2_bounds(avar: np.ndarray, edf: np.ndarray, confidence: float) -> tuple[np.ndarray, ...]:
    """ADEV and its two-sided chi-square confidence bounds for the given degrees of freedom."""
    p_lo, p_hi = (1 - confidence) / 2, (1 + confidence) / 2
    adev = np.sqrt(avar)
    return adev, adev * np.sqrt(edf / chi2_ppf(p_hi, edf)), adev * np.sqrt(edf / chi2_ppf(p_lo, edf))


def chi2_ppf(p: float, dof: np.ndarray) -> np.ndarray:
    """scipy.stats.chi2.ppf(p, dof) for 0 < p < 1 and dof > 0: the same function it calls
    (2 gammaincinv(dof / 2, p)), without importing scipy.stats (a second or more of the command's start)."""
    from scipy.special import gammaincinv

    return 2 * gammaincinv(np.asarray(dof) / 2, p)


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

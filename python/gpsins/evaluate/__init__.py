"""Filter solutions against a truth: errors in the filter's own error-state
convention, in local frames, and the consistency statistics (NEES, NIS).

Error convention (that of the filter's error state): delta = truth - estimate
for velocity and position; attitude delta-theta is the body-side rotation
vector with q_true = q_est (x) exp(delta-theta).
"""

from __future__ import annotations

import mmap
from dataclasses import dataclass

import numpy as np

from .. import _core


def _qmul(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    w1, x1, y1, z1 = np.moveaxis(a, -1, 0)
    w2, x2, y2, z2 = np.moveaxis(b, -1, 0)
    return np.stack([w1 * w2 - x1 * x2 - y1 * y2 - z1 * z2, w1 * x2 + x1 * w2 + y1 * z2 - z1 * y2,
                     w1 * y2 - x1 * z2 + y1 * w2 + z1 * x2, w1 * z2 + x1 * y2 - y1 * x2 + z1 * w2], -1)


def c_en(lat: np.ndarray, lon: np.ndarray) -> np.ndarray:
    """(n, 3, 3) rotations NED -> ECEF; columns north, east, down."""
    sl, cl, so, co = np.sin(lat), np.cos(lat), np.sin(lon), np.cos(lon)
    z = np.zeros_like(lat)
    return np.stack([np.stack([-sl * co, -so, -cl * co], -1), np.stack([-sl * so, co, -cl * so], -1),
                     np.stack([cl, z, -sl], -1)], -2)


@dataclass
class Truth:
    """A reference trajectory sampled densely: t (s), r and v ECEF, q_eb (w, x, y, z)."""

    t: np.ndarray
    r_ecef: np.ndarray
    v_ecef: np.ndarray
    q_eb: np.ndarray

    def at(self, t: np.ndarray) -> "Truth":
        """Linear interpolation (quaternions: normalised, sign-aligned); exact at sample times."""
        t = np.asarray(t, dtype=float)
        if t.size and (t.min() < self.t[0] - 1e-9 or t.max() > self.t[-1] + 1e-9):
            raise ValueError(f"truth covers {self.t[0]:.3f}..{self.t[-1]:.3f} s, asked for "
                             f"{t.min():.3f}..{t.max():.3f} s")
        i = np.clip(np.searchsorted(self.t, t, side="right") - 1, 0, len(self.t) - 2)
        w = ((t - self.t[i]) / (self.t[i + 1] - self.t[i]))[:, None]
        q0, q1 = self.q_eb[i], self.q_eb[i + 1]
        q1 = q1 * np.sign(np.sum(q0 * q1, -1, keepdims=True))
        q = (1 - w) * q0 + w * q1
        lerp = lambda a: (1 - w) * a[i] + w * a[i + 1]  # noqa: E731
        return Truth(t, lerp(self.r_ecef), lerp(self.v_ecef), q / np.linalg.norm(q, axis=-1, keepdims=True))

    def release(self) -> None:
        """Give back the pages read so far of memory-mapped arrays (a day-long truth file): they
        count in the process's resident memory until the mapping goes, and are read again if needed."""
        release_pages(self.t, self.r_ecef, self.v_ecef, self.q_eb)


def release_pages(*arrays) -> None:
    """Drop the resident pages of the memory maps under these arrays (no-op for arrays in memory)."""
    for a in arrays:
        while a is not None and not isinstance(a, mmap.mmap):
            a = getattr(a, "base", None)
        if a is not None and hasattr(a, "madvise") and not a.closed:
            a.madvise(mmap.MADV_DONTNEED)


@dataclass
class NavErrors:
    t: np.ndarray
    dtheta: np.ndarray  # (n, 3) body-side attitude error, rad
    dv: np.ndarray  # (n, 3) ECEF, m/s (truth - estimate)
    dr: np.ndarray  # (n, 3) ECEF, m
    r_ned: np.ndarray  # (n, 3) position error estimate - truth in local NED, m
    ypr_deg: np.ndarray  # (n, 3) yaw, pitch, roll estimate - truth, deg (wrapped)
    v_ned: np.ndarray  # (n, 3) velocity error estimate - truth in local NED, m/s

    @property
    def e9(self) -> np.ndarray:
        return np.hstack([self.dtheta, self.dv, self.dr])


def _about(axis: np.ndarray, angle: np.ndarray) -> np.ndarray:
    """Quaternions (n, 4) of rotations by angle about unit axes (n, 3)."""
    return np.column_stack([np.cos(angle / 2), axis * np.sin(angle / 2)[:, None]])


def _conj(q: np.ndarray) -> np.ndarray:
    return q * np.array([1.0, -1.0, -1.0, -1.0])


def _attitude_error(q_est: np.ndarray, q_true: np.ndarray) -> np.ndarray:
    dq = _qmul(_conj(q_est), q_true)
    return _core.rotvec_from_quat(dq * np.where(dq[:, :1] < 0, -1.0, 1.0))


def nav_errors(sol, truth: Truth) -> NavErrors:
    """Errors of a solution. While its heading is unknown (``sol.heading_known`` False) the
    yaw error can be anything, and the rotation vector of a large rotation mixes it into
    roll and pitch: there the attitude error is the tilt error after turning the estimate
    by the yaw error about the local vertical, plus the yaw error (wrapped) along the
    body's vertical, the form in which the filter carries it."""
    ref = truth.at(sol.t)
    dtheta = _attitude_error(sol.q_eb, ref.q_eb)
    llh = _core.ecef_to_geodetic(ref.r_ecef)
    c = c_en(llh[:, 0], llh[:, 1])
    c_ne = np.swapaxes(c, -1, -2)
    r_ned = np.einsum("nij,nj->ni", c_ne, sol.r_ecef - ref.r_ecef)
    v_ned = np.einsum("nij,nj->ni", c_ne, sol.v_ecef - ref.v_ecef)
    ypr_est = _core.euler_from_body_to_ecef(sol.q_eb, llh)
    ypr_true = _core.euler_from_body_to_ecef(ref.q_eb, llh)
    dypr = np.degrees(np.angle(np.exp(1j * (ypr_est - ypr_true))))
    unknown = ~np.asarray(getattr(sol, "heading_known", np.ones(len(sol.t), bool)), bool)
    if unknown.any():
        down = c[unknown][:, :, 2]  # local down in ECEF
        dpsi = np.angle(np.exp(1j * (ypr_true[unknown, 0] - ypr_est[unknown, 0])))
        q_est = sol.q_eb[unknown]
        turned = _qmul(_about(down, dpsi), q_est)
        down_b = np.einsum("nji,nj->ni", _dcm(q_est), down)
        dtheta[unknown] = _attitude_error(turned, ref.q_eb[unknown]) + dpsi[:, None] * down_b
    return NavErrors(sol.t, dtheta, ref.v_ecef - sol.v_ecef, ref.r_ecef - sol.r_ecef, r_ned, dypr, v_ned)


def _dcm(q: np.ndarray) -> np.ndarray:
    """(n, 3, 3) rotation matrices of quaternions (w, x, y, z)."""
    w, x, y, z = q.T
    return np.stack([np.stack([1 - 2 * (y * y + z * z), 2 * (x * y - w * z), 2 * (x * z + w * y)], -1),
                     np.stack([2 * (x * y + w * z), 1 - 2 * (x * x + z * z), 2 * (y * z - w * x)], -1),
                     np.stack([2 * (x * z - w * y), 2 * (y * z + w * x), 1 - 2 * (x * x + y * y)], -1)], -2)


def nees(errors: np.ndarray, covariance: np.ndarray) -> np.ndarray:
    """e^T P^-1 e per epoch; errors (n, k), covariance (n, k, k)."""
    return np.einsum("ni,ni->n", errors, np.linalg.solve(covariance, errors[..., None])[..., 0])


def nees_band(dof: int, runs: int, probability: float = 0.95) -> tuple[float, float]:
    """Two-sided band of the NEES averaged over `runs` independent runs (Bar-Shalom)."""
    from scipy.stats import chi2  # here: importing scipy.stats costs every command 0.7 s

    lo, hi = chi2.ppf([(1 - probability) / 2, (1 + probability) / 2], dof * runs)
    return float(lo / runs), float(hi / runs)


def ned_sigma(sol) -> np.ndarray:
    """Position standard deviations in local NED, (n, 3), from the full covariance."""
    if sol.covariance is None:
        raise ValueError("the solution has no covariance: run with covariance=True")
    llh = sol.llh()
    c = c_en(llh[:, 0], llh[:, 1])
    p_ned = np.swapaxes(c, -1, -2) @ sol.covariance[:, 6:9, 6:9] @ c
    return np.sqrt(np.diagonal(p_ned, axis1=-2, axis2=-1))

"""Anyone's estimator where the built-in filter would run (``gpsins replay SOURCE --estimator MOD:NAME``).

An estimator is a callable (a function, or a class whose instances are called) that takes the
``EstimatorInputs`` a replay prepares - the aligned IMU increments, the fixes with their quality,
the pseudoranges and ephemerides where the source has them, the outage schedule already applied,
the data set's lever arm and the configuration the built-in filter would run with - and returns
its solution as a mapping (or any object with these attributes):

- ``t`` (n,): GPS seconds since the start of ``inputs.week``, increasing;
- ``r_ecef`` (n, 3) m and ``v_ecef`` (n, 3) m/s of the IMU point; ``q_eb`` (n, 4) Hamilton w, x, y, z,
  body (forward-right-down) to ECEF (NaN where it has no attitude);
- optional: ``sigma`` (n, >= 9) standard deviations of the attitude error (rad, about the local north,
  east and down axes), velocity (m/s, NED) and position (m, NED) errors, in that order; ``covariance``
  (n, >= 9, >= 9) in the same order and axes (NEES uses it, else the sigmas as a diagonal one, else none;
  the replay turns both into the built-in filter's axes: attitude on the body side, velocity and
  position in ECEF); ``gyro_bias``, ``accel_bias`` (n, 3); ``heading_known`` (n,) bool; ``updates``, the
  built-in filter's update table (kind, t, dof, nis, accepted, ...), for NIS; ``counters`` (fixes_accepted,
  updates_rejected, ...), for run.json and the terminal.

The replay then scores, writes and reports it exactly as its own: errors against the truth or the
reference, drift per outage, NEES where it gives sigmas or covariances, NIS where it gives updates.
A ``filter.Solution`` is returned as it is: ``builtin`` (the built-in filter as a plug-in) gives
the native scores exactly.
"""

from __future__ import annotations

import importlib
from dataclasses import dataclass, field

import numpy as np

from .. import _core, evaluate
from . import runs as flt
from ..formats.gpstime import SECONDS_PER_WEEK

UPDATE_COLUMNS = {"t": (np.float64, ()), "kind": (np.int32, ()), "id": (np.int32, ()), "dof": (np.int32, ()),
                  "nis": (np.float64, ()), "gate": (np.float64, ()), "log_det_s": (np.float64, ()),
                  "r_scale": (np.float64, ()), "accepted": (np.bool_, ()), "guarded": (np.bool_, ()),
                  "innovation": (np.float64, (3,)), "innovation_sigma": (np.float64, (3,))}


class EstimatorError(ValueError):
    pass


@dataclass
class EstimatorInputs:
    """What a replay feeds an estimator, on one time base: GPS seconds since the start of ``week``."""

    mode: str  # "loose" or "tight": what the user asked the run to be
    week: int
    imu: np.ndarray  # (n, 7) [t, dtheta xyz rad, dv xyz m/s]: increments over the step ending at t, body axes
    fixes: np.ndarray  # (m, 10 or 16) filter.run's fix rows: [t, r xyz, v xyz, hdop, vdop, mode 2/3, (sigmas)]
    lever_arm_body_m: np.ndarray  # (3,) antenna from the IMU, body axes
    config: dict  # the configuration the built-in filter would run with (noise figures, gates, ...)
    pseudoranges: np.ndarray | None = None  # (k, 5 or 6) [t, prn, pseudorange m, C/N0, lock, (Doppler Hz)]
    ephemerides: list = field(default_factory=list)
    klobuchar: tuple | None = None
    outages: np.ndarray = field(default_factory=lambda: np.zeros((0, 2)))  # [start, end) already removed


def load(spec: str):
    """The estimator ``package.module:name`` (a class is instantiated without arguments)."""
    module, sep, name = spec.partition(":")
    if not sep or not module or not name:
        raise EstimatorError(f"--estimator {spec!r}: give package.module:name")
    try:
        obj = getattr(importlib.import_module(module), name)
    except ImportError as e:
        raise EstimatorError(f"--estimator {spec}: cannot import {module} ({e})") from None
    except AttributeError:
        raise EstimatorError(f"--estimator {spec}: {module} has no {name}") from None
    obj = obj() if isinstance(obj, type) else obj
    if not callable(obj):
        raise EstimatorError(f"--estimator {spec}: {name} is not callable")
    return obj


def builtin(inputs: EstimatorInputs) -> flt.Solution:
    """The built-in filter as a plug-in (loose or tight as asked): the native run, returned whole."""
    tight = {}
    if inputs.mode == "tight":
        tight = dict(pseudoranges=inputs.pseudoranges, ephemerides=inputs.ephemerides, klobuchar=inputs.klobuchar,
                     gps_time_offset_s=inputs.week * SECONDS_PER_WEEK)
    return flt.run(inputs.imu, inputs.fixes, {**inputs.config, "mode": inputs.mode}, covariance=True, **tight)


def _get(out, name: str):
    if isinstance(out, dict):
        return out.get(name)
    return getattr(out, name, None)


def as_solution(out, mode: str, n_imu: int, n_fixes: int, spec: str) -> flt.Solution:
    """An estimator's result as the replay's solution type, checked."""
    if isinstance(out, flt.Solution):
        return out
    t = _get(out, "t")
    if t is None:
        raise EstimatorError(f"{spec}: the result has no t")
    t = np.asarray(t, dtype=float).reshape(-1)
    n = len(t)
    if n == 0 or not np.all(np.diff(t) > 0):
        raise EstimatorError(f"{spec}: t must be a non-empty increasing array (GPS seconds since the week's start)")

    def arr(name: str, width: int, required: bool, fill=np.nan) -> np.ndarray:
        v = _get(out, name)
        if v is None:
            if required:
                raise EstimatorError(f"{spec}: the result has no {name}")
            return np.full((n, width), fill)
        v = np.asarray(v, dtype=float)
        if v.shape[0] != n or v.ndim != 2 or v.shape[1] < width:
            raise EstimatorError(f"{spec}: {name} has shape {v.shape}, expected ({n}, {width})")
        return v

    sigma = arr("sigma", 9, False)[:, :9]
    cov = _get(out, "covariance")
    if cov is not None:
        cov = np.asarray(cov, dtype=float)
        if cov.ndim != 3 or cov.shape[0] != n or min(cov.shape[1:]) < 9:
            raise EstimatorError(f"{spec}: covariance has shape {cov.shape}, expected ({n}, >= 9, >= 9)")
        cov = cov[:, :9, :9]
    known = _get(out, "heading_known")
    known = np.ones(n, bool) if known is None else np.asarray(known, bool).reshape(-1)
    updates = _get(out, "updates") or {k: np.zeros((0,) + shape, dtype) for k, (dtype, shape) in
                                       UPDATE_COLUMNS.items()}
    counters = {"imu_samples": int(n_imu), "fixes": int(n_fixes), "fixes_accepted": 0, "updates_rejected": 0,
                "diverged": False, **dict(_get(out, "counters") or {})}  # the plug-in's own, where it counts
    return flt.Solution(mode, sigma.shape[1], t, arr("r_ecef", 3, True)[:, :3], arr("v_ecef", 3, True)[:, :3],
                        arr("q_eb", 4, True)[:, :4], arr("gyro_bias", 3, False, 0.0)[:, :3],
                        arr("accel_bias", 3, False, 0.0)[:, :3], sigma, np.zeros(n, bool), known, dict(updates),
                        counters, covariance=cov)


def filter_axes(cov_ned: np.ndarray, q_eb: np.ndarray, r_ecef: np.ndarray) -> np.ndarray:
    """(n, 9, 9) covariances from a plug-in's axes (attitude about N, E, D; velocity, position NED) to
    the built-in filter's (attitude on the body side, q_true = q (x) exp(dtheta); velocity, position ECEF)."""
    llh = _core.ecef_to_geodetic(r_ecef)
    c_en = evaluate.c_en(llh[:, 0], llh[:, 1])  # NED -> ECEF
    c_be = np.swapaxes(_core.dcm_from_quat(q_eb), 1, 2)  # ECEF -> body
    t = np.zeros((len(cov_ned), 9, 9))
    t[:, 0:3, 0:3] = c_be @ c_en
    t[:, 3:6, 3:6] = t[:, 6:9, 6:9] = c_en
    return t @ cov_ned @ np.swapaxes(t, 1, 2)


class PluginRun:
    """An estimator's run in the place of ``nav.runs.ChunkedRun``: one call, its solution handed on in
    the chunks the built-in filter's would come in (the epochs up to every ``chunk_rows``-th IMU
    sample), so the replay writes and scores it as its own, to the last bit."""

    def __init__(self, estimator, spec: str, inputs: EstimatorInputs, chunk_rows: int = flt.CHUNK_ROWS):
        result = estimator(inputs)
        self._ned = not isinstance(result, flt.Solution)  # the built-in's own is in the filter's axes already
        self._out = as_solution(result, inputs.mode, len(inputs.imu), len(inputs.fixes), spec)
        self.counters = dict(self._out.counters)
        self.fixes_after_end = int(self._out.extra.get("fixes_after_end", 0))
        self.heading_search = None
        self._ends = inputs.imu[chunk_rows - 1::chunk_rows, 0]  # the last IMU time of each chunk

    def chunks(self, covariance: bool = True, navigation_covariance: bool = False):
        """The plug-in's solution in the built-in's chunks; its covariance as it gave it (the navigation
        block in the filter's axes when it gave NED), whatever ``navigation_covariance`` asks."""
        s, n = self._out, len(self._out.t)
        upd_t = np.asarray(s.updates["t"]) if len(s.updates.get("t", ())) else np.zeros(0)
        ev_t = np.asarray(s.events.get("t", ())) if s.events else np.zeros(0)
        cuts = np.unique(np.concatenate([np.searchsorted(s.t, self._ends, side="right"), [n]]))
        for a, b in zip(np.concatenate([[0], cuts[:-1]]), cuts):
            if b <= a:
                continue
            t_lo = -np.inf if a == 0 else s.t[a - 1]
            t_hi = np.inf if b == n else s.t[b - 1]
            u = (upd_t > t_lo) & (upd_t <= t_hi)
            e = (ev_t > t_lo) & (ev_t <= t_hi)
            pick = (lambda x, a=a, b=b: None if x is None else x[a:b])
            cov = pick(s.covariance)
            sigma = s.sigma[a:b]
            if self._ned:  # a plug-in's NED axes turned into the filter's, chunk by chunk (memory)
                if cov is None:  # sigmas only: a diagonal covariance (NaN without them)
                    cov = np.zeros((b - a, 9, 9))
                    cov[:, np.arange(9), np.arange(9)] = sigma[:, :9] ** 2
                cov = filter_axes(cov[:, :9, :9], s.q_eb[a:b], s.r_ecef[a:b])
                sigma = np.sqrt(np.clip(np.diagonal(cov, axis1=1, axis2=2), 0.0, None))
            yield flt.Solution(s.mode, sigma.shape[1], s.t[a:b], s.r_ecef[a:b], s.v_ecef[a:b], s.q_eb[a:b],
                               s.gyro_bias[a:b], s.accel_bias[a:b], sigma, s.standstill[a:b],
                               s.heading_known[a:b], {k: np.asarray(v)[u] for k, v in s.updates.items()},
                               self.counters, pick(s.scale_factors), pick(s.clock),
                               cov if covariance else None, {},
                               {k: np.asarray(v)[e] for k, v in s.events.items()} if s.events else {},
                               pick(s.fix_error), pick(s.time_offset))

    def release_inputs(self) -> None:
        pass

    def smooth(self, *_, **__):
        raise EstimatorError("--smooth: the fixed-interval smoother runs on the built-in filter's record; a "
                             "plug-in estimator smooths inside itself if it wants to")

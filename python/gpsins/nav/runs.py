"""Runs of the C++ core from Python: a batch run, a chunked run (``ChunkedRun``: the filter fed a chunk
of IMU samples at a time, and its smoother), a streaming filter, the solution type, and the heading
search of a hand-held device. The configuration language is ``nav.config``; the inputs by columns are
``nav.inputs``.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field

import numpy as np

from .. import _core
# The configuration language lives in filter_config; these are the names callers reach through here.
from .config import merge, as_vec3, core_config, load_config
from .inputs import imu_table, pseudorange_table, pr_table


# The core's names of its event and update kinds (one list, cpp/include/gpsins/filter_names.hpp).
EVENT_KINDS = dict(_core.EVENT_KINDS)
UPDATE_KINDS = dict(_core.UPDATE_KINDS)


def _at_gnss_time(r, v, dt, sigma, cov):
    """With the IMU time offset state the nominal at filter time t is the vehicle at GNSS time t + dt:
    its position moved back to t, r - v dt, so that every row is at its stamped (GNSS) time as without
    the state (velocity and attitude as they are: the acceleration over dt is left out). The position's
    error then gains -v ddt: with the covariance exactly (J P J^T, J = I but -v in the position rows'
    offset column), without it the two as if independent."""
    r = r - v * dt[:, None]
    sigma = sigma.copy()
    if cov is not None:
        cov = np.array(cov)  # a copy
        cov[:, 6:9, :] -= v[:, :, None] * cov[:, -1, None, :]  # J P, then (J P) J^T
        cov[:, :, 6:9] -= cov[:, :, -1, None] * v[:, None, :]
        sigma[:, 6:9] = np.sqrt(np.maximum(np.einsum("nii->ni", cov[:, 6:9, 6:9]), 0.0))
    else:
        sigma[:, 6:9] = np.hypot(sigma[:, 6:9], v * sigma[:, -1:])
    return r, sigma, cov


@dataclass
class Solution:
    """A batch run's output: states at IMU epochs, every update, and the counters."""

    mode: str
    n_states: int
    t: np.ndarray
    r_ecef: np.ndarray
    v_ecef: np.ndarray
    q_eb: np.ndarray  # (n, 4) w, x, y, z
    gyro_bias: np.ndarray
    accel_bias: np.ndarray
    sigma: np.ndarray  # (n, n_states) error-state standard deviations
    standstill: np.ndarray
    heading_known: np.ndarray  # False while aligning: the heading is not yet known
    updates: dict
    counters: dict
    scale_factors: np.ndarray | None = None  # (n, 6) gyro xyz, accel xyz
    clock: np.ndarray | None = None  # (n, 2) bias m, drift m/s
    covariance: np.ndarray | None = None
    extra: dict = field(default_factory=dict)
    events: dict = field(default_factory=dict)  # t, kind (EVENT_KINDS), value: restarts, resets, rejected samples
    fix_error: np.ndarray | None = None  # (n, 3) loose with fix-error states: the fix's correlated error, ECEF m
    # (n,) with estimate_time_offset: dt_imu (s), by which the IMU stamps lag GNSS time after the data
    # set's declared offset (the value to add to [imu] time_offset_s)
    time_offset: np.ndarray | None = None

    @classmethod
    def from_batch(cls, out: dict, mode: str, scale_factors: bool) -> "Solution":
        s = out["state"]
        n = int(out["n_states"])
        k = 17
        sf = None
        if scale_factors:
            sf, k = s[:, k:k + 6], k + 6
        # After them the augmented states: the signal-in-space slots and the clock (tight) or the fix error
        # (loose, fix_error_gm_sigma_m), then the IMU time offset (estimate_time_offset): what is left after
        # the tight ones (0 or 1) or the loose count (0, 1, 3, 4) tells which are there.
        clock = fix_error = time_offset = None
        augmented = n - 15 - (6 if scale_factors else 0)
        if mode == "tight":
            k += _core.SIS_SLOTS  # slot values mean nothing without the filter's satellite table
            clock, k = s[:, k:k + 2], k + 2
            augmented -= 2 + _core.SIS_SLOTS
        elif augmented >= 3:
            fix_error, k = s[:, k:k + 3], k + 3
            augmented -= 3
        if augmented == 1:
            time_offset, k = s[:, k], k + 1
        flags = s[:, k + n].astype(int)
        r, sigma, cov = s[:, 1:4], s[:, k:k + n], out.get("covariance")
        if time_offset is not None:
            r, sigma, cov = _at_gnss_time(r, s[:, 4:7], time_offset, sigma, cov)
        return cls(mode, n, s[:, 0], r, s[:, 4:7], s[:, 7:11], s[:, 11:14], s[:, 14:17],
                   sigma, (flags & 1) > 0, (flags & 2) > 0, out["updates"], out["counters"], sf, clock,
                   cov, {"fixes_after_end": out["fixes_after_end"]}, out["events"],
                   fix_error=fix_error, time_offset=time_offset)

    @property
    def time_offset_sigma(self) -> np.ndarray | None:
        """(n,) the IMU time offset's sigma (s), with estimate_time_offset (its state is the last)."""
        return None if self.time_offset is None else self.sigma[:, -1]

    def event_list(self) -> list[dict]:
        """The filter's events in time order as {t, kind, value} with kind named (EVENT_KINDS)."""
        e = self.events
        return [{"t": float(t), "kind": EVENT_KINDS.get(int(k), str(int(k))), "value": float(v)}
                for t, k, v in zip(e.get("t", ()), e.get("kind", ()), e.get("value", ()))]

    def llh(self) -> np.ndarray:
        return _core.ecef_to_geodetic(self.r_ecef)

    def ypr(self) -> np.ndarray:
        """Yaw, pitch, roll (rad) relative to local NED."""
        llh = self.llh()
        return _core.euler_from_body_to_ecef(self.q_eb, llh)


def run(imu: np.ndarray, fixes: np.ndarray, config=None, *, mode: str | None = None, output_every: int = 1,
        covariance: bool = False, pseudoranges: np.ndarray | None = None, ephemerides=(), klobuchar=None,
        gps_time_offset_s: float | None = None, smooth: bool = False, smooth_chunk_mb: float = 256.0,
        attitude: np.ndarray | None = None) -> Solution:
    """Run the filter over whole arrays in C++.

    imu: (n, 7) [t, dtheta xyz (rad), dv xyz (m/s)] at the IMU's sampling instants.
    fixes: (m, 10) [t, r_ecef xyz, v_ecef xyz (NaN if none), hdop, vdop, mode (2 = 3D, 3 = 2D)], or (m, 16)
    with the stated sigmas [..., sigma n e d (m), sigma vn ve vd (m/s)] (NaN or <= 0: from the DOP and
    fix_uere_m, or fix_velocity_sigma_mps).
    ``platform = "handheld"`` without an initial yaw: the heading is searched first (``search_heading``);
    the result is in ``Solution.extra["heading_search"]``.
    config: a configuration table, preset name or TOML path (see load_config).
    Tight mode also takes pseudoranges (k, 5) [t, prn, pseudorange m, C/N0 dB-Hz, lock count], or (k, 6)
    with the Doppler (Hz, positive approaching, NaN: none; used with ``doppler_sigma_mps``) (one epoch's
    rows share t), the ephemerides (``_core.gnss.Ephemeris``), the Klobuchar
    (alpha, beta) and the offset from the time base to GPS seconds since the GPS epoch.
    smooth: also run the fixed-interval smoother; its solution (same epochs) is
    ``extra["smoothed"]``, its tape size and timings ``extra["smooth_info"]``.
    attitude: (j, 5) [t, yaw, pitch (NaN: none), sigma yaw, sigma pitch] (rad) of a dual-antenna
    receiver whose baseline is ``antenna_baseline_body``.
    """
    imu = imu_table(imu)
    setup = setup_run(imu, fixes, config, mode, ephemerides, klobuchar, gps_time_offset_s)
    f, fixes = setup.core_filter, setup.fixes
    prs = None if pseudoranges is None else pr_table(pseudoranges[:])
    out = f.run(imu, fixes, prs, output_every, covariance, smooth, smooth_chunk_mb,
                attitude=_attitude_table(attitude))
    sol = Solution.from_batch(out, setup.mode, setup.scale_factors)
    if setup.search is not None:
        sol.extra["heading_search"] = setup.search
    if smooth:
        sm = dict(out, state=out["smooth_state"], covariance=out.get("smooth_covariance"))
        sol.extra["smoothed"] = Solution.from_batch(sm, setup.mode, setup.scale_factors)
        sol.extra["smooth_info"] = dict(out["smooth_info"])
    return sol


def _attitude_table(attitude) -> np.ndarray | None:
    return None if attitude is None else np.ascontiguousarray(attitude, dtype=float).reshape(-1, 5)


@dataclass
class _Setup:
    core_filter: "_core.InsFilter"
    mode: str
    scale_factors: bool
    fixes: np.ndarray
    search: dict | None


def setup_run(imu, fixes, config, mode, ephemerides, klobuchar, gps_time_offset_s) -> _Setup:
    """The core filter of a run: configuration, heading search (handheld), ephemerides, ionosphere."""
    cfg = config if isinstance(config, dict) and "preset" in config else load_config(config)
    mode = mode or cfg.get("mode", "loose")
    fixes = np.ascontiguousarray(fixes, dtype=float)
    if fixes.ndim != 2 or fixes.size == 0:  # an empty list or array: no fixes
        fixes = fixes.reshape(-1, 10)
    search = None
    if needs_heading_search(cfg):
        search = search_heading(imu_table(imu), fixes, cfg)
        if search["yaw_deg"] is not None:
            cfg = starting_at_yaw(cfg, search["yaw_deg"], search["sigma_deg"])
    core = core_config(cfg)
    if gps_time_offset_s is not None:
        core.gps_time_offset_s = float(gps_time_offset_s)
    f = _core.InsFilter(core, mode)
    for e in ephemerides:
        f.add_ephemeris(e)
    if klobuchar is not None and len(klobuchar[0]) == 4:
        f.set_klobuchar(list(klobuchar[0]), list(klobuchar[1]))
    return _Setup(f, mode, core.scale_factor_states, fixes, search)


CHUNK_ROWS = 4096  # IMU samples per call of a chunked run: ~10 MB of covariances at 17 states (tight: 28 MB)
# With an epoch out every k samples a call takes up to this many times as many samples: about as many
# epochs per call, and the per-call Python work (tables, scoring) k times rarer.
MAX_CALL_SCALE = 16


class ChunkedRun:
    """The filter over a whole run in consecutive calls of ``chunk_rows`` IMU samples (times
    ``output_every``, up to ``MAX_CALL_SCALE``), so that what is in memory at a time does not grow with
    the run: ``chunks()`` yields each call's
    ``Solution`` (its epochs only, with their covariances), the same rows one ``run`` gives.
    ``record=True`` keeps the smoother's record of the forward pass (spilled to a temporary
    file in ``smooth_chunk_mb`` pieces); ``overlap``: the core runs the next chunk on a second
    thread while the caller works on this one (off where runs are already one per core);
    ``smooth(sink)`` then hands the smoothed solution over in blocks, newest block first, each
    in time order."""

    def __init__(self, imu: np.ndarray, fixes: np.ndarray, config=None, *, mode: str | None = None,
                 output_every: int = 1, pseudoranges: np.ndarray | None = None, ephemerides=(), klobuchar=None,
                 gps_time_offset_s: float | None = None, record: bool = False, smooth_chunk_mb: float = 256.0,
                 chunk_rows: int = CHUNK_ROWS, attitude: np.ndarray | None = None, overlap: bool = True):
        if chunk_rows < 1:
            raise ValueError("chunk_rows must be >= 1")
        self.imu = imu
        self._setup = setup_run(imu, fixes, config, mode, ephemerides, klobuchar, gps_time_offset_s)
        self.fixes = self._setup.fixes
        self.prs = pseudorange_table(pseudoranges)
        self.attitude = _attitude_table(attitude)
        self.mode, self.output_every, self.record = self._setup.mode, output_every, record
        self.smooth_chunk_mb, self.chunk_rows, self.overlap = smooth_chunk_mb, chunk_rows, overlap
        self.counters: dict = {}
        self.fixes_after_end = len(self.fixes)
        self.heading_search = self._setup.search

    def chunks(self, covariance: bool = True, navigation_covariance: bool = False):
        """The solution chunk by chunk. The core runs the next chunk on a second thread while
        the caller works on this one (the core lets go of the GIL): replay's scoring and writing
        overlap the filter instead of following it. One chunk is in flight at a time and the
        filter still sees its calls in order, so the rows are those of a single thread.
        ``navigation_covariance``: each epoch's covariance is only the navigation block (attitude,
        velocity, position, then the IMU time offset when it is a state), all a replay's sigmas
        and NEES take."""
        from concurrent.futures import ThreadPoolExecutor

        calls = self._calls(covariance, navigation_covariance)
        if not self.overlap:
            for out in calls:
                yield Solution.from_batch(out, self.mode, self._setup.scale_factors)
            return
        with ThreadPoolExecutor(max_workers=1, thread_name_prefix="gpsins-filter") as pool:
            pending = pool.submit(next, calls, None)
            while True:
                out = pending.result()
                if out is None:
                    return
                pending = pool.submit(next, calls, None)
                yield Solution.from_batch(out, self.mode, self._setup.scale_factors)

    def _calls(self, covariance: bool, navigation_covariance: bool):
        """The core's calls, one per chunk, each output dict as it comes."""
        f = self._setup.core_filter
        n = len(self.imu)
        j = q = g = 0
        step = self.chunk_rows * min(self.output_every, MAX_CALL_SCALE)
        for a in range(0, n, step):
            b = min(n, a + step)
            imu = np.ascontiguousarray(self.imu[a:b], dtype=float)
            t_end = imu[-1, 0] if b < n else np.inf  # the last call takes what is left (fixes after the end)
            j2 = int(np.searchsorted(self.fixes[:, 0], t_end, side="right"))
            prs, q2 = None, q
            if self.prs is not None:
                q2 = int(np.searchsorted(self.prs[:, 0], t_end, side="right"))
                prs = self.prs[q:q2]
            att, g2 = None, g
            if self.attitude is not None:
                g2 = int(np.searchsorted(self.attitude[:, 0], t_end, side="right"))
                att = self.attitude[g:g2]
            out = f.run(imu, self.fixes[j:j2], prs, self.output_every, covariance, False, self.smooth_chunk_mb,
                        self.record, a, j, q, att, g, navigation_covariance)
            self.counters, self.fixes_after_end = out["counters"], len(self.fixes) - j2 + int(out["fixes_after_end"])
            j, q, g = j2, q2, g2
            yield out

    def release_inputs(self) -> None:
        """Let go of the IMU samples, pseudoranges and attitude fixes once ``chunks()`` has run through
        (a day's are 240 MB); the smoother needs only its record."""
        self.imu = self.prs = self.attitude = None

    def smooth(self, sink, block_rows: int | None = None, covariance: bool = True,
               navigation_covariance: bool = False) -> dict:
        """After ``chunks()`` ran through with ``record=True``: the backward pass, handing
        ``sink(index of the block's first epoch, Solution)`` each block as it completes (newest
        block first, each in time order; ``block_rows`` epochs, by default as many as a forward
        chunk, so the blocks' memory is reused as the forward's is); ``navigation_covariance`` as
        ``chunks()``'s. Returns the tape's size and the times."""
        block_rows = self.chunk_rows if block_rows is None else block_rows
        n_states, sf = self._setup.core_filter.n_states, self._setup.scale_factors

        def take(b: dict) -> None:
            sink(int(b["first"]), Solution.from_batch(
                {"state": b["state"], "covariance": b.get("covariance"), "updates": {}, "counters": self.counters,
                 "fixes_after_end": self.fixes_after_end, "events": {}, "n_states": n_states}, self.mode, sf))

        return dict(self._setup.core_filter.smooth(covariance, take, block_rows, navigation_covariance)["smooth_info"])


# A device whose course is not its heading (handheld): the heading is searched.
HEADING_SEARCH_S = 20.0  # seconds of fixes after the first one that decide it
_COARSE_STEP_DEG, _FINE_STEP_DEG = 30.0, 5.0
MOVING_SPEED_MPS = 0.5  # the search window starts when the fixes move faster
DOMINANCE = 20.0  # -2 log likelihood the best must win by over every hypothesis 90 deg away


def starting_at_yaw(cfg: dict, yaw_deg: float, sigma_deg: float) -> dict:
    """The configuration with the initial yaw and its sigma: the yaw's part of the initial attitude
    sigma (a configured initial yaw otherwise starts at attitude_sigma's yaw, 180 deg in the preset)."""
    if "attitude_sigma_deg" in cfg:
        att = as_vec3(cfg["attitude_sigma_deg"], "attitude_sigma_deg")
    else:
        rad = cfg.get("attitude_sigma_rad", _core.InsConfig().attitude_sigma_rad)
        att = np.degrees(as_vec3(rad, "attitude_sigma_rad"))
    cfg = {k: v for k, v in cfg.items() if k not in ("attitude_sigma_rad", "initial_yaw_rad")}
    return merge(cfg, {"initial_yaw_deg": float(yaw_deg), "attitude_sigma_deg": [att[0], att[1], float(sigma_deg)]})


def needs_heading_search(cfg: dict) -> bool:
    """A handheld platform without a configured initial yaw."""
    yaw = cfg.get("initial_yaw_deg", cfg.get("initial_yaw_rad", math.nan))
    return cfg.get("platform", "vehicle") == "handheld" and not np.isfinite(yaw)


def _fix_log_likelihood(sol: "Solution") -> float:
    """-2 log likelihood of the GNSS updates (fix position and velocity): NIS plus log det S
    (S taken as diagonal, from the innovation sigmas)."""
    u = sol.updates
    sel = np.isin(u["kind"], (1, 2, 3))
    sig = np.asarray(u["innovation_sigma"])[sel]
    logdet = np.where(np.isfinite(sig) & (sig > 0), 2.0 * np.log(np.where(sig > 0, sig, 1.0)), 0.0).sum()
    return float(np.sum(np.asarray(u["nis"])[sel]) + logdet)


def _moving_from(fixes: np.ndarray, speed_mps: float = MOVING_SPEED_MPS) -> float | None:
    """Time of the first fix with a horizontal speed above ``speed_mps`` (its velocity, else the
    difference to the previous fix, which is close enough at walking speed and above)."""
    v = fixes[:, 4:7]
    d = np.diff(fixes[:, 1:4], axis=0) / np.maximum(np.diff(fixes[:, 0]), 1e-3)[:, None]
    v = np.where(np.isfinite(v).all(1)[:, None], v, np.vstack([np.full((1, 3), np.nan), d]))
    up = fixes[:, 1:4] / np.linalg.norm(fixes[:, 1:4], axis=1)[:, None]
    vh = np.linalg.norm(v - np.sum(v * up, axis=1)[:, None] * up, axis=1)
    moving = np.flatnonzero(np.nan_to_num(vh) > speed_mps)
    return float(fixes[moving[0], 0]) if len(moving) else None


def search_heading(imu: np.ndarray, fixes: np.ndarray, cfg: dict, window_s: float | None = None) -> dict:
    """The initial heading of a device whose course is not its heading, from the first seconds of motion.

    Hypotheses of the initial yaw every 30 deg, each a filter run from the start to ``window_s`` seconds
    after motion begins, with a heading sigma of half the spacing (the linear model holds within it),
    scored by the likelihood of their GNSS updates (-2 log L: NIS plus log det S); then every 5 deg
    around the best with a 5 deg sigma. The run then starts at the best with the coarse 15 deg sigma.
    The gate is off in these runs so that every hypothesis is scored
    on the same updates. The search decides only when the best coarse hypothesis beats every one 90 deg
    or more away by ``DOMINANCE`` (a likelihood ratio of e^10); otherwise (no motion, too few fixes) the
    yaw is None and the filter takes its heading from the course as for a vehicle.
    """
    window_s = float(cfg.get("heading_search_s", HEADING_SEARCH_S) if window_s is None else window_s)
    out = {"yaw_deg": None, "sigma_deg": None, "window_s": window_s, "scores": {}}
    sol_fixes = fixes[np.isin(fixes[:, 9], (2.0, 3.0)) & (fixes[:, 0] >= imu[0, 0])]
    t_move = _moving_from(sol_fixes) if len(sol_fixes) >= 5 else None
    if t_move is None:
        return out
    t_end = t_move + window_s
    out["t_end"] = float(t_end)  # the last fix time the search used
    imu_w, fix_w = imu[imu[:, 0] <= t_end], fixes[fixes[:, 0] <= t_end]
    base = {k: v for k, v in cfg.items() if k not in ("platform", "initial_yaw_rad", "heading_sigma_rad")}
    base.update(gate_probability=0.0, gnss_reset_timeout_s=0.0)
    scores: dict[float, float] = out["scores"]

    def score(yaw: float, sigma: float) -> float:
        yaw = float((yaw + 180.0) % 360.0 - 180.0)
        c = starting_at_yaw(base, yaw, sigma)
        s = _fix_log_likelihood(run(imu_w, fix_w, c, mode="loose", output_every=10 ** 6))
        scores[round(yaw, 3)] = s
        return s

    coarse = {float(y): score(y, _COARSE_STEP_DEG / 2) for y in np.arange(-180.0, 180.0, _COARSE_STEP_DEG)}
    best = min(coarse, key=coarse.get)
    far = [s for y, s in coarse.items() if abs((y - best + 180.0) % 360.0 - 180.0) >= 90.0]
    out["dominance"] = float(min(far) - coarse[best])
    if not out["dominance"] >= DOMINANCE:
        return out
    fine = {y: score(y, _FINE_STEP_DEG) for y in best + np.arange(-_COARSE_STEP_DEG / 2, _COARSE_STEP_DEG / 2 + 1e-9,
                                                                     _FINE_STEP_DEG)}
    yaw = min(fine, key=fine.get)
    # Its sigma stays the coarse half-spacing: where the motion shows the heading only weakly (no gait,
    # few turns) the likelihood is flat over tens of degrees, and the filter refines it as it goes.
    out.update(yaw_deg=float((yaw + 180.0) % 360.0 - 180.0), sigma_deg=_COARSE_STEP_DEG / 2)
    return out


def streaming(config=None, mode: str | None = None) -> "_core.InsFilter":
    """A streaming filter: push_imu(t, dtheta, dv), push_fix(...), then read its state."""
    cfg = config if isinstance(config, dict) and "preset" in config else load_config(config)
    return _core.InsFilter(core_config(cfg), mode or cfg.get("mode", "loose"))

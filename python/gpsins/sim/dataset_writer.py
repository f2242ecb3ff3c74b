"""A simulation written as a data set (``gpsins sim --dataset``): the formats of outside recordings,
with a known mounting rotation, antenna lever arm and IMU time offset, so that the data-set path of
``gpsins replay DATASET.toml`` is tested against truth.

Files (all in one directory):

- ``imu.csv``: the unit's samples in IMU axes (v_imu = M^T v_body, M = ``imu_to_body``), times in
  GPS seconds since 1970 (``gpst_unix``) stamped ``imu_time_offset_s`` early (the data set's
  ``time_offset_s`` puts them back). ``increments``: velocity (m/s) and angle (rad) increments,
  each ending at its stamp, as the simulator draws them. ``rates``: the same increments divided by
  the interval (m/s^2, rad/s), stamped at the middle of their interval, where an interval's mean
  rate belongs (the reader's trapezoid then recovers the increments to second order).
- ``receiver.pos``: RTKLIB-style fixes of the antenna at ``gnss_rate_hz`` epochs off whole seconds,
  with per-epoch standard deviations (some RTK-fixed, some float, some stated as zero) and
  velocities; each fix's error is drawn with the sigma it states (a zero-sigma fix: 1 cm).
- ``truth.pos``: the antenna's true trajectory (Q = 1) at 10 Hz, the reference for scoring.
- ``dataset.toml``: the data set, with ``[filter]`` from the simulated unit's noise figures.

It uses the simulator's own truth and NumPy only, never the filter.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np

from . import Simulation, imu_noise_truth
from .draws import Stream
from .earth import ecef_to_geodetic, ecef_to_ned_matrix
from ..formats.gpstime import SECONDS_PER_WEEK

GPS_UNIX_OFFSET_S = 315964800.0  # 1980-01-06 in Unix time (no leap seconds: gpst_unix)


def ypr_matrix(yaw_deg: float, pitch_deg: float, roll_deg: float) -> np.ndarray:
    """Rz(yaw) Ry(pitch) Rx(roll) (the data set's ``imu_to_body_ypr_deg``), written out here independently."""
    y, p, r = np.radians([yaw_deg, pitch_deg, roll_deg])
    cy, sy, cp, sp, cr, sr = np.cos(y), np.sin(y), np.cos(p), np.sin(p), np.cos(r), np.sin(r)
    return np.array([[cy * cp, cy * sp * sr - sy * cr, cy * sp * cr + sy * sr],
                     [sy * cp, sy * sp * sr + cy * cr, sy * sp * cr - cy * sr],
                     [-sp, cp * sr, cp * cr]])


def _gpst_text(t_abs: np.ndarray) -> list[str]:
    """'YYYY/MM/DD hh:mm:ss.sss' GPST for seconds since the GPS epoch."""
    base = np.datetime64("1980-01-06T00:00:00", "ms")
    out = []
    for x in np.atleast_1d(t_abs):
        s = str(base + np.timedelta64(int(round(x * 1000)), "ms"))
        out.append(s[:10].replace("-", "/") + " " + s[11:23])
    return out


def _llh_deg(r: np.ndarray) -> np.ndarray:
    return np.array([[np.degrees(a), np.degrees(b), c] for a, b, c in (ecef_to_geodetic(x) for x in r)])


def _c_eb_at(sim: Simulation, t: np.ndarray) -> np.ndarray:
    """Body-to-ECEF rotation at run times t: the nearest internal truth sample (SUBSTEPS per IMU interval)."""
    tr = sim.truth
    k = np.clip(np.searchsorted(tr.t, t), 1, len(tr.t) - 1)
    k = np.where(np.abs(tr.t[k - 1] - t) < np.abs(tr.t[k] - t), k - 1, k)
    return tr.c_eb[k]


def antenna_truth(sim: Simulation, t: np.ndarray, antenna_m) -> tuple[np.ndarray, np.ndarray]:
    """True ECEF position and velocity of the antenna at run times t (lever arm in body axes)."""
    tr = sim.truth
    c = _c_eb_at(sim, t)
    lever = np.asarray(antenna_m, float)
    r = tr.position_at(t) + c @ lever
    # v_ant = v + C_eb (w_eb x l); w_eb ~ w_ib - C_be w_ie (Earth rate, small but kept).
    k = np.clip(np.searchsorted(tr.t, t), 0, len(tr.t) - 1)
    w_ie = np.array([0.0, 0.0, 7.292115e-5])
    w_eb = tr.w_ib_body[k] - np.einsum("nji,j->ni", c, w_ie)
    v = tr.velocity_at(t) + np.einsum("nij,nj->ni", c, np.cross(w_eb, lever))
    return r, v


POS_HEADER = ("%  GPST                   latitude(deg) longitude(deg)  height(m)   Q  ns   sdn(m)   sde(m)   sdu(m)"
              "  sdne(m)  sdeu(m)  sdun(m) age(s)  ratio    vn(m/s)    ve(m/s)    vu(m/s)     sdvn     sdve     sdvu"
              "    sdvne    sdveu    sdvun")


def _pos_header(program: str) -> str:
    return "\n".join([f"% program   : {program}", "% (lat/lon/height=WGS84/ellipsoidal,Q=1:fix,2:float,5:single)",
                      POS_HEADER]) + "\n"


def _pos_rows(t_abs, r, q, ns, sd_neu, v_neu, sd_v) -> str:
    lines = []
    for ts, (la, lo, h), qq, n, s, v, sv in zip(_gpst_text(t_abs), _llh_deg(r), q, ns, sd_neu, v_neu, sd_v):
        lines.append(f"{ts} {la:14.9f} {lo:14.9f} {h:10.4f} {int(qq):3d} {int(n):3d} {s[0]:8.4f} {s[1]:8.4f} "
                     f"{s[2]:8.4f} {0.0:8.4f} {0.0:8.4f} {0.0:8.4f} {0.0:6.2f} {0.0:6.1f} {v[0]:10.5f} {v[1]:10.5f} "
                     f"{v[2]:10.5f} {sv[0]:8.5f} {sv[1]:8.5f} {sv[2]:8.5f} {0.0:8.5f} {0.0:8.5f} {0.0:8.5f}\n")
    return "".join(lines)


def _toml_value(v) -> str:
    if isinstance(v, str):
        return f'"{v}"'
    if isinstance(v, (list, tuple, np.ndarray)):
        return "[" + ", ".join(_toml_value(x) for x in np.asarray(v).tolist()) + "]"
    return repr(float(v)) if isinstance(v, float) else str(v)


class DatasetWriter:
    """The data set written block by block (``Simulation`` blocks in order), then ``close``. The fixes'
    draws are addressed by fix, so the files are the same however the run is cut. ``t_last_sample``:
    the run's last IMU sampling instant (the fixes and the truth stop short of it)."""

    def __init__(self, sc, seed: int, directory: str | Path, t_last_sample: float, *,
                 imu_to_body_ypr_deg=(-90.0, 3.0, 180.0), antenna_m=(0.6, -0.3, -1.1), imu_time_offset_s: float = 0.05,
                 imu_format: str = "increments", gnss_rate_hz: float = 5.0, gnss_phase_s: float = 0.137,
                 fix_sigma_range_m=(0.01, 0.04), float_every: int = 13, zero_sigma_every: int = 7,
                 velocity_sigma_mps: float = 0.03, seed_offset: int = 0, vehicle_kind: str = "car",
                 velocity_mean_over_epoch: bool = False, undeclared_misalignment_ypr_deg=(0.0, 0.0, 0.0),
                 fix_correlated_sigma_m=(0.0, 0.0), fix_correlated_tau_s: float = 30.0,
                 declared_white_noise_scale: float = 1.0, stated_antenna_m=None, antenna_sigma_m: float = 0.0):
        if imu_format not in ("increments", "rates"):
            raise ValueError(f"imu_format {imu_format!r}: increments or rates")
        # The simulated vehicle moves along its body x axis without slip (also the walk profile and the
        # roller coaster's train): a car for the data set's constraints, unless the caller says otherwise.
        self.vehicle_kind = vehicle_kind
        self.out = Path(directory)
        self.out.mkdir(parents=True, exist_ok=True)
        self.sc, self.seed = sc, seed
        self.mount, self.antenna_m = imu_to_body_ypr_deg, antenna_m
        # What the data set says of the antenna (a tape measure's figure, its sigma); the fixes are of the true one.
        self.stated_antenna_m = antenna_m if stated_antenna_m is None else stated_antenna_m
        self.antenna_sigma_m = float(antenna_sigma_m)
        # The IMU's axes are off the declared mounting by a fine misalignment the data set does not state:
        # the body the data set declares is then turned from the vehicle's axes by it, as the filter's
        # body_to_vehicle_ypr states (what a car's non-holonomic constraint has to find).
        # v_vehicle = M_fine v_body_declared, v_body_declared = M_declared v_imu.
        self.m = ypr_matrix(*undeclared_misalignment_ypr_deg) @ ypr_matrix(*imu_to_body_ypr_deg)
        # The noise the data set declares against what the unit has (a datasheet's figures on a vehicle).
        self.declared_white_noise_scale = declared_white_noise_scale
        self.imu_time_offset_s, self.imu_format, self.gnss_rate_hz = imu_time_offset_s, imu_format, gnss_rate_hz
        self.fix_sigma_range_m = fix_sigma_range_m
        self.float_every, self.zero_sigma_every = float_every, zero_sigma_every
        self.velocity_sigma_mps = velocity_sigma_mps
        # A receiver whose velocity is the antenna's mean over the fix interval just ended (as u-blox NAV-PVT's
        # is), not the velocity at the fix's instant.
        self.velocity_mean_over_epoch = velocity_mean_over_epoch
        self.t_start_abs = sc.start.gps_week * SECONDS_PER_WEEK + sc.start.gps_tow_s  # run time 0 in GPS seconds
        key = (seed, seed_offset, 16)
        self.draw = {"sigma": Stream(key + (1,), "uniform"), "position": Stream(key + (2,), width=3),
                     "velocity": Stream(key + (3,), width=3)}
        # Fixes off whole seconds and the antenna's truth at 10 Hz: a few MB of times for a day's drive.
        self.t_fix = np.arange(gnss_phase_s, t_last_sample - 0.5, 1.0 / gnss_rate_hz)
        # A slow error on top of the stated white one (carrier multipath, an RTK engine's ambiguity
        # residuals): first-order Gauss-Markov per north, east, down axis with sigmas (h, h, v), drawn
        # for every fix up front so that a block's fixes do not depend on where the run is cut.
        self.fix_correlated_ned = self._gauss_markov(key + (4,), fix_correlated_sigma_m, fix_correlated_tau_s)
        self.t_ref = np.arange(0.05, t_last_sample - 0.05, 0.1)
        self._next_fix = self._next_ref = 0
        self._t_prev: float | None = None  # the last IMU sample written
        self.units = ("m/s", "rad") if imu_format == "increments" else ("m/s^2", "rad/s")
        self.imu_file = open(self.out / "imu.csv", "w", encoding="ascii")
        self.imu_file.write("t_gpst_unix,ax,ay,az,gx,gy,gz\n")
        self.fix_file = open(self.out / "receiver.pos", "w", encoding="ascii")
        self.fix_file.write(_pos_header("gpsins sim (receiver)"))
        self.ref_file = open(self.out / "truth.pos", "w", encoding="ascii")
        self.ref_file.write(_pos_header("gpsins sim (truth of the antenna)"))

    def _gauss_markov(self, key, sigma_hv, tau_s: float) -> np.ndarray:
        n = len(self.t_fix)
        sigma = np.array([sigma_hv[0], sigma_hv[0], sigma_hv[1]], float)
        out = np.zeros((n, 3))
        if n == 0 or not (sigma > 0).any():
            return out
        w = Stream(key, width=3).rows(0, n)
        a = np.exp(-np.diff(self.t_fix, prepend=self.t_fix[0]) / tau_s)
        out[0] = w[0] * sigma
        for i in range(1, n):  # x_k = a x_k-1 + sqrt(1 - a^2) sigma w_k: stationary at sigma
            out[i] = a[i] * out[i - 1] + np.sqrt(1.0 - a[i] ** 2) * sigma * w[i]
        return out

    def _times(self, times: np.ndarray, start: int, b: Simulation) -> tuple[int, int]:
        """The range of `times` from `start` that falls in block b's truth (all that remain in the last)."""
        end = len(times) if b.last else start + int(np.searchsorted(times[start:], b.truth.t[-1], side="left"))
        return start, end

    def add(self, b: Simulation) -> None:
        # IMU in its own axes, stamped early by the offset.
        dth_imu, dv_imu = b.imu_dtheta @ self.m, b.imu_dv @ self.m  # rows: (M^T v)^T = v^T M
        t_end = b.imu_t
        before = t_end[0] - (t_end[1] - t_end[0]) if self._t_prev is None else self._t_prev
        dt = np.diff(np.concatenate([[before], t_end]))
        self._t_prev = float(t_end[-1])
        if self.imu_format == "increments":
            t_stamp, acc, gyr = t_end, dv_imu, dth_imu
        else:
            t_stamp, acc, gyr = t_end - dt / 2, dv_imu / dt[:, None], dth_imu / dt[:, None]
        unix = self.t_start_abs + GPS_UNIX_OFFSET_S + t_stamp - self.imu_time_offset_s
        np.savetxt(self.imu_file, np.column_stack([unix, acc, gyr]), delimiter=",", fmt=["%.6f"] + ["%.10e"] * 6)

        # Receiver fixes of the antenna, off whole seconds.
        i0, i1 = self._times(self.t_fix, self._next_fix, b)
        self._next_fix = i1
        if i1 > i0:
            t_fix = self.t_fix[i0:i1]
            r_true, v_true = antenna_truth(b, t_fix, self.antenna_m)
            n = len(t_fix)
            idx = np.arange(i0, i1)
            q = np.where(idx % self.float_every == self.float_every - 1, 2, 1)
            lo, hi = self.fix_sigma_range_m
            s_h = (lo + (hi - lo) * self.draw["sigma"].rows(i0, i1)) * np.where(q == 2, 5.0, 1.0)
            s_v = 1.6 * s_h
            stated_zero = idx % self.zero_sigma_every == 3
            drawn_h, drawn_v = np.where(stated_zero, 0.01, s_h), np.where(stated_zero, 0.015, s_v)
            lat, lon = np.array([ecef_to_geodetic(x)[:2] for x in r_true]).T
            c_en = ecef_to_ned_matrix(lat, lon)  # (n, 3, 3) NED -> ECEF
            e_ned = (self.draw["position"].rows(i0, i1) * np.column_stack([drawn_h, drawn_h, drawn_v])
                     + self.fix_correlated_ned[i0:i1])
            r_fix = r_true + np.einsum("nij,nj->ni", c_en, e_ned)
            if self.velocity_mean_over_epoch:  # from the antenna's position an interval earlier (or the block start)
                t_before = np.maximum(t_fix - 1.0 / self.gnss_rate_hz, b.truth.t[0])
                r_before = antenna_truth(b, t_before, self.antenna_m)[0]
                v_true = (r_true - r_before) / np.maximum(t_fix - t_before, 1e-9)[:, None]
            v_ned = (np.einsum("nji,nj->ni", c_en, v_true)
                     + self.draw["velocity"].rows(i0, i1) * self.velocity_sigma_mps)
            sd = np.column_stack([s_h, s_h, s_v]) * ~stated_zero[:, None]
            sdv = np.full((n, 3), self.velocity_sigma_mps)
            self.fix_file.write(_pos_rows(self.t_start_abs + t_fix, r_fix, q, np.full(n, 9), sd, v_ned * [1, 1, -1],
                                          sdv))

        # The antenna's truth at 10 Hz as the reference.
        i0, i1 = self._times(self.t_ref, self._next_ref, b)
        self._next_ref = i1
        if i1 > i0:
            t_ref = self.t_ref[i0:i1]
            r_ref, v_ref = antenna_truth(b, t_ref, self.antenna_m)
            lat, lon = np.array([ecef_to_geodetic(x)[:2] for x in r_ref]).T
            v_ref_ned = np.einsum("nji,nj->ni", ecef_to_ned_matrix(lat, lon), v_ref)
            z = np.zeros((len(t_ref), 3))
            self.ref_file.write(_pos_rows(self.t_start_abs + t_ref, r_ref, np.ones(len(t_ref)),
                                          np.full(len(t_ref), 9), z, v_ref_ned * [1, 1, -1], z))

    def close(self) -> Path:
        for f in (self.imu_file, self.fix_file, self.ref_file):
            f.close()
        sc, seed = self.sc, self.seed
        noise = imu_noise_truth(sc.imu)
        for k in ("gyro_arw_rad_per_sqrt_s", "accel_vrw_mps_per_sqrt_s"):
            noise["imu_noise"][k] = [x * self.declared_white_noise_scale for x in noise["imu_noise"][k]]
        lines = [f'name = "{sc.name}_seed{seed}"',
                 f'description = "gpsins sim --dataset: {sc.name}, seed {seed}, '
                 f'IMU {sc.imu.rate_hz} Hz ({self.imu_format}), fixes {self.gnss_rate_hz:g} Hz"', "",
                 "[imu]", 'file = "imu.csv"', 'format = "csv"',
                 'columns = ["t", "ax", "ay", "az", "gx", "gy", "gz"]', 'time = "gpst_unix"',
                 f'accel_unit = "{self.units[0]}"', f'gyro_unit = "{self.units[1]}"', "skip_rows = 1",
                 f"time_offset_s = {self.imu_time_offset_s!r}",
                 f"imu_to_body_ypr_deg = {_toml_value([float(x) for x in self.mount])}", "",
                 "[gnss]", 'file = "receiver.pos"', 'format = "rtklib-pos"',
                 f"antenna_m = {_toml_value([float(x) for x in self.stated_antenna_m])}",
                 *([f"antenna_sigma_m = {self.antenna_sigma_m!r}"] if self.antenna_sigma_m > 0 else []), "",
                 "[vehicle]", f'kind = "{self.vehicle_kind}"', "",
                 "[scoring]", 'reference = "truth.pos"', "reference_q = [1]", "",
                 "[filter]", 'preset = "default"',
                 # The unit's calibration (the simulated nominal values), which need not be the preset's unit's.
                 f"gyro_bias_cal_rad_per_s = {_toml_value([float(x) for x in sc.imu.gyro_bias_rad_per_s])}",
                 f"accel_bias_cal_mps2 = {_toml_value([float(x) for x in sc.imu.accel_bias_mps2])}",
                 f"gyro_scale_factor_cal = {_toml_value([float(x) for x in sc.imu.gyro_scale_factor])}",
                 f"accel_scale_factor_cal = {_toml_value([float(x) for x in sc.imu.accel_scale_factor])}",
                 # Each fix's error is drawn white at the sigma it states: no correlated parts on top.
                 "fix_error_gm_sigma_m = [0.0, 0.0, 0.0]",
                 f"gyro_bias_residual_rad_per_s = {noise['gyro_bias_residual_rad_per_s']!r}",
                 f"accel_bias_residual_mps2 = {noise['accel_bias_residual_mps2']!r}", "",
                 "[filter.imu_noise]"] + [f"{k} = {_toml_value(v)}" for k, v in noise["imu_noise"].items()]
        path = self.out / "dataset.toml"
        path.write_text("\n".join(lines) + "\n", encoding="utf-8")
        return path


def write_dataset(sim: Simulation, directory: str | Path, *, seed: int = 0, **options) -> Path:
    """Write the data set of a whole simulation ``sim`` into ``directory`` (created); returns the data-set
    file. Options as ``DatasetWriter``'s; ``seed`` offsets its draws from the simulation's seed."""
    w = DatasetWriter(sim.scenario, sim.seed, directory, float(sim.imu_t[-1]), seed_offset=seed, **options)
    w.add(sim)
    return w.close()

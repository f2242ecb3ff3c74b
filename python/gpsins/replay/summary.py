"""What a results directory holds and what run.json says of a run: the arrays (``RESULT_ARRAYS``) and
the health lines of its counters and update statistics.
"""

from __future__ import annotations


RESULT_ARRAYS = {
    "t": "GPS time, s since the start of `week`", "week": "GPS week of t = 0",
    "r_ecef": "position, m", "v_ecef": "velocity, m/s", "q_eb": "attitude body->ECEF (w, x, y, z)",
    "llh": "latitude, longitude (rad), height (m)", "ypr_deg": "yaw, pitch, roll relative to NED, deg",
    "gyro_bias": "rad/s", "accel_bias": "m/s^2", "sigma": "error-state standard deviations",
    "sigma_ned_m": "position sigma north, east, down", "sigma_ypr_deg": "attitude sigma about N, E, D axes",
    "standstill": "standstill detected", "heading_known": "heading initialised",
    "fixes": "receiver fixes [t, r xyz, v xyz, hdop, vdop, mode] (data sets: then sigma n e d, vn ve vd)",
    "fix_sats": "satellites used per fix",
    "upd_*": "updates: t, kind, id, dof, nis, gate, log_det_s, r_scale (> 1: used down-weighted), accepted, "
             "innovation (3), innovation_sigma (3)",
    "err_ned_m": "position error (estimate - truth) NED", "err_ypr_deg": "attitude error",
    "err_v_ned_mps": "velocity error NED", "nees9": "NEES of the 9 navigation states",
    "seg_labels": "truth segment labels", "seg_t": "truth segments' start and end times",
    "sigma_v_ned_mps": "velocity sigma north, east, down",
    "clock": "tight mode: receiver clock bias (m) and drift (m/s); their sigmas are the last two of `sigma` "
             "(before the time offset's with estimate_time_offset)",
    "time_offset_s": "with estimate_time_offset: the IMU time offset state dt_imu (s), to add to the data set's "
                     "[imu] time_offset_s; its sigma is the last of `sigma`",
    "fix_error": "loose mode with fix_error_gm_sigma_m: the fixes' correlated error state (ECEF; m, or m per unit "
                 "of DOP with fix_error_gm_dop_scaled); sigmas last of `sigma` (before the time offset's)",
    "r_point_ecef": "position of the scored point (antenna unless --point imu; a session's truth: IMU), m",
    "lever_arm_body_m": "antenna relative to the IMU, body axes (the configuration's lever arm)",
    "outages": "outage schedule [start, end), same time base as t",
    "ref_t": "reference epochs used for scoring", "ref_r_ecef": "reference positions",
    "ref_err_ned_m": "solution minus reference at ref_t, NED", "ref_outage": "outage index of each ref_t (-1 outside)",
    "drift_t_s": "time since the outage began, per reference epoch inside one", "drift_h_m": "horizontal drift",
    "drift_v_m": "vertical drift", "drift_outage": "outage index of each drift row",
}


# A source whose updates are refused more often than this is worth a line on the terminal.
REJECTED_SHARE_WARNING = 0.05


def health_lines(counters: dict, sources: dict) -> list[str]:
    """One line for each way the run went wrong: diverged, GNSS resets, a source refused often."""
    lines = []
    if counters.get("diverged"):
        lines.append("the filter diverged (sustained GNSS rejection or an invalid covariance)")
    if counters.get("gnss_resets"):
        lines.append(f"{counters['gnss_resets']} GNSS reset(s): position and velocity were taken from GNSS")
    for name, s in sources.items():
        if s["rejected_fraction"] > REJECTED_SHARE_WARNING:
            lines.append(f"{name}: {100 * s['rejected_fraction']:.1f} % of {s['n']} updates rejected")
    return lines

"""Independent checks of a simulation against its own truth: a simple strapdown
re-integration of the truth's body rate and specific force, and the ideal
increments composed back into attitude and velocity changes."""

import numpy as np
from scipy.spatial.transform import Rotation

from gpsins.sim import earth


def prefix_products(q: Rotation) -> Rotation:
    """Cumulative products q0, q0 q1, q0 q1 q2, ... by a parallel (Hillis-Steele) scan."""
    quat = q.as_quat()
    n, step = len(quat), 1
    while step < n:
        left = Rotation.from_quat(quat[:-step])
        quat = np.concatenate([quat[:step], (left * Rotation.from_quat(quat[step:])).as_quat()])
        step *= 2
    return Rotation.from_quat(quat)


def reintegration_errors(tr) -> tuple[float, float]:
    """(largest attitude error rad, largest position error m) of the truth's body rate and specific
    force integrated (inertial frame, gravity at the re-integrated position) against its own
    attitude and trajectory, over the whole run."""
    h = tr.t[1] - tr.t[0]
    c_ib0 = earth.rot_z(earth.OMEGA_E * tr.t[0]) @ tr.c_eb[0]
    # attitude: per double step, two trapezoid half-increments with the two-sample coning term
    w0, wm, w1 = tr.w_ib_body[0:-2:2], tr.w_ib_body[1:-1:2], tr.w_ib_body[2::2]
    a1, a2 = (w0 + wm) * h / 2, (wm + w1) * h / 2
    rotvec = a1 + a2 + 2.0 / 3.0 * np.cross(a1, a2)
    c_ib = Rotation.from_matrix(c_ib0) * prefix_products(Rotation.from_rotvec(rotvec))
    c_ib_true = earth.rot_z(earth.OMEGA_E * tr.t[2::2]) @ tr.c_eb[2::2]
    att_err = (Rotation.from_matrix(c_ib_true).inv() * c_ib).magnitude().max()
    # velocity and position in the inertial frame; attitude at every sample from the truth's
    # DCM checked above, gravity at the integrated position (two fixed-point passes)
    c_all = earth.rot_z(earth.OMEGA_E * tr.t) @ tr.c_eb
    f_i = np.einsum("nij,nj->ni", c_all, tr.f_body)
    rot_t = earth.rot_z(earth.OMEGA_E * tr.t)
    r_i = np.einsum("nij,nj->ni", rot_t, tr.r_ecef)
    v0 = rot_t[0] @ (tr.v_ecef[0] + np.cross(earth.OMEGA_VEC, tr.r_ecef[0]))
    for _ in range(2):
        r_e = np.einsum("nji,nj->ni", rot_t, r_i)
        # gravitation = gravity minus its centrifugal part
        acc = f_i + np.einsum("nij,nj->ni", rot_t, earth.gravity_ecef(r_e) + np.cross(
            earth.OMEGA_VEC, np.cross(earth.OMEGA_VEC, r_e)))
        # Simpson on double steps for the even samples, a 3-point rule for the odd ones
        even = np.concatenate([[0.0 * acc[0]], np.cumsum(h / 3 * (acc[0:-2:2] + 4 * acc[1:-1:2] + acc[2::2]), 0)])
        odd = even[:-1] + h / 12 * (5 * acc[0:-2:2] + 8 * acc[1:-1:2] - acc[2::2])
        v = np.empty_like(acc)
        v[0::2], v[1::2] = v0 + even, v0 + odd
        even_r = np.concatenate([[0.0 * v[0]], np.cumsum(h / 3 * (v[0:-2:2] + 4 * v[1:-1:2] + v[2::2]), 0)])
        r_i_new = r_i.copy()
        r_i_new[0::2] = r_i[0] + even_r
        r_i = r_i_new
    r_true = np.einsum("nij,nj->ni", rot_t, tr.r_ecef)
    return float(att_err), float(np.linalg.norm(r_i[0::2] - r_true[0::2], axis=1).max())


def increment_errors(s, t0: float, t1: float) -> tuple[float, float]:
    """(attitude error rad, velocity error m/s) of the ideal increments over the IMU samples
    whose intervals lie in [t0, t1] against the truth: the composed delta-thetas against the
    inertial attitude change, the summed delta-v (each rotated by its start-of-interval attitude)
    plus gravity (Simpson on the truth grid) against the inertial velocity change."""
    tr = s.truth
    idx = s.truth_at_imu  # end of each IMU interval on the truth grid
    starts = idx - tr.substeps
    k = np.flatnonzero((tr.t[starts] >= t0 - 1e-9) & (tr.t[idx] <= t1 + 1e-9))
    a, b = starts[k[0]], idx[k[-1]]
    assert np.all(np.diff(k) == 1) and b > a
    rot = earth.rot_z(earth.OMEGA_E * tr.t[a:b + 1])
    c_ib = rot @ tr.c_eb[a:b + 1]  # inertial frame = ECEF at t = 0
    total = Rotation.from_matrix(c_ib[0]) * prefix_products(Rotation.from_rotvec(s.ideal_dtheta[k]))[-1]
    att = (Rotation.from_matrix(c_ib[-1]).inv() * total).magnitude()
    dv_i = np.einsum("nij,nj->ni", c_ib[starts[k] - a], s.ideal_dv[k])
    r, v = tr.r_ecef[a:b + 1], tr.v_ecef[a:b + 1]
    v_i = np.einsum("nij,nj->ni", rot, v + np.cross(earth.OMEGA_VEC, r))
    g_i = np.einsum("nij,nj->ni", rot, earth.gravity_ecef(r) + np.cross(earth.OMEGA_VEC, np.cross(earth.OMEGA_VEC, r)))
    h = tr.t[1] - tr.t[0]
    grav = h / 3 * (g_i[0] + 4 * g_i[1:-1:2].sum(0) + 2 * g_i[2:-1:2].sum(0) + g_i[-1])
    return float(att), float(np.abs(dv_i.sum(0) + grav - (v_i[-1] - v_i[0])).max())

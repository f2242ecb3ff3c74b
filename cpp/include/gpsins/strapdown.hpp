// Strapdown mechanisation in ECEF, driven by the IMU's increments.
//
// One step covers one IMU interval [t0, t0 + dt] with the increments of the
// BP3010 spec: delta-theta is the rotation vector of the body's attitude change
// relative to inertial space (coning included), delta-v the integral of specific
// force expressed in the body frame at the start of the interval (sculling and
// rotation included).
//
// Scheme (errors are per step, for dt = 1/64 s):
// - Attitude: C_eb(t1) = Rz(-w_ie dt) C_eb(t0) exp(delta-theta). Exact: the
//   Earth frame turns about a fixed axis and delta-theta is exact by definition.
// - Specific force to ECEF: C_eb(t0) dv, minus half the Earth frame's turn over
//   the interval, (w_ie dt / 2) x C_eb(t0) dv. Error O((w_ie dt)^2 |dv|), ~1e-13 m/s.
// - Velocity: v1 = v0 + dv_e + (gamma(r_mid) - 2 w_ie x v_mid) dt, with gamma the
//   normal gravity (centrifugal part included, so no separate -w x (w x r): the FOI
//   report's eq. 2.12 counts it twice) and r_mid, v_mid predicted half-step values. Gravity and Coriolis vary
//   slowly; the error is O(dt^3) in the gravity gradient and Coriolis rate,
//   below 1e-9 m/s per step in a car.
// - Position: trapezoid, r1 = r0 + (v0 + v1) dt / 2. Error dt^3/12 times the
//   jerk: 3e-7 m per step at 1 m/s^3.
#pragma once

#include "gpsins/types.hpp"

namespace gpsins {

struct NavState {
  double t_s = 0.0;
  Vec3 r_ecef_m = Vec3::Zero();
  Vec3 v_ecef_mps = Vec3::Zero();
  Quat q_eb = Quat::Identity();  // body (forward-right-down) to ECEF
};

struct Increment {
  double dt_s = 0.0;
  Vec3 dtheta_rad = Vec3::Zero();
  Vec3 dv_mps = Vec3::Zero();
};

// Switches for closed-form tests; the filter always uses the full model.
struct MechanisationOptions {
  bool earth_rotation = true;
  bool gravity = true;
};

void mechanise(NavState& s, const Increment& inc, const MechanisationOptions& opt = {});

// Split an increment at `fraction` (0..1) of its interval, assuming constant body
// rate and specific force within it. `first` covers [t0, t0 + f dt]; `second`
// covers the rest, its delta-v expressed in the body frame at the split.
void split_increment(const Increment& inc, double fraction, Increment& first, Increment& second);

}  // namespace gpsins

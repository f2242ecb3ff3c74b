// Land-vehicle constraints at a vehicle point p (body axes, from the IMU): a
// wheeled vehicle does not slide sideways or leave the road, so its velocity
// in vehicle axes has no lateral and no vertical part (non-holonomic
// constraint).
//   v_p (vehicle axes) = C_vb (C_be v + w x p),  w the body rate relative to the Earth,
// C_vb the body-to-vehicle rotation (scale-factor states are left out of H). With q_true = q (x) exp(dtheta) and
// w = w_c - dbg: C_be_true v_true = C_be v + C_be dv + [C_be v]x dtheta, and
// (w_c - dbg) x p = w_c x p + [p]x dbg, so
//   h_true - h = C_vb (C_be dv + [C_be v]x dtheta + [p]x dbg).
#pragma once

#include "gpsins/aiding/measurement.hpp"
#include "gpsins/eskf.hpp"

namespace gpsins {

// The vehicle point's velocity in vehicle axes and its Jacobian (rows forward,
// right, down). w_ib_body: the calibrated gyro rate, before the estimated bias.
template <int NB, int NC, int NT>
Measurement<3, Eskf<NB, NC, NT>::N> vehicle_velocity(const Eskf<NB, NC, NT>& f, const Mat3& c_vb,
                                                     const Vec3& point_body_m, const Vec3& w_ib_body_rad_per_s) {
  Measurement<3, Eskf<NB, NC, NT>::N> m;
  const Mat3 c_be = f.nav.q_eb.toRotationMatrix().transpose();
  const Vec3 w_ie_b = c_be * earth_rate_ecef();
  const Vec3 w_ib =
      (w_ib_body_rad_per_s - f.imu.gyro_bias_rad_per_s).cwiseQuotient(Vec3::Ones() + f.imu.gyro_scale_factor);
  const Vec3 w = w_ib - w_ie_b;
  const Vec3 v_b = c_be * f.nav.v_ecef_mps;
  m.y = -(c_vb * (v_b + w.cross(point_body_m)));  // y = z - h with z = 0; the caller sets the rows' z
  m.H.template block<3, 3>(0, es::vel) = c_vb * c_be;
  // The Earth rate seen through the attitude error adds [p]x [w_ie_b]x (small).
  m.H.template block<3, 3>(0, es::att) = c_vb * (skew(v_b) + skew(point_body_m) * skew(w_ie_b));
  m.H.template block<3, 3>(0, es::bg) = c_vb * skew(point_body_m);
  return m;
}

// No lateral and no vertical velocity: the rows right and down, z = 0, each with its own sigma.
template <int NB, int NC, int NT>
Measurement<2, Eskf<NB, NC, NT>::N> nonholonomic(const Eskf<NB, NC, NT>& f, const Mat3& c_vb, const Vec3& point_body_m,
                                                 const Vec3& w_ib_body_rad_per_s, double lateral_sigma_mps,
                                                 double vertical_sigma_mps) {
  const auto full = vehicle_velocity(f, c_vb, point_body_m, w_ib_body_rad_per_s);
  Eigen::Matrix<double, 2, 3> rows = Eigen::Matrix<double, 2, 3>::Zero();
  rows(0, 1) = 1.0;
  rows(1, 2) = 1.0;
  auto m = project(full, rows);
  m.R = Eigen::Vector2d(lateral_sigma_mps * lateral_sigma_mps, vertical_sigma_mps * vertical_sigma_mps).asDiagonal();
  return m;
}

}  // namespace gpsins

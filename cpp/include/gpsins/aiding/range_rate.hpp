// One satellite's Doppler as the range rate at the antenna: with v_a = v + C (w x l)
// the antenna's velocity (velocity.hpp), r_a = r + C l its position, u the unit vector
// from antenna to satellite at range rho, v_s the satellite's velocity and d the
// receiver clock drift state (m/s),
//   rate = u . (v_s - v_a) + Sagnac rate + d - c dt_s_dot + noise,
// the satellite's clock drift moved to the measurement side. Its error: the antenna
// velocity's seen along u, d(rate) = -u^T d(v_a) + dd (the rows of the GNSS
// velocity's H: velocity, attitude, gyro bias and scale factor through the lever
// arm), plus the line of sight turning with the antenna's position,
// d(rate) = g^T d(r_a), g = -(I - u u^T)(v_s - v_a) / rho (about 1e-4 s^-1).
#pragma once

#include "gpsins/aiding/measurement.hpp"
#include "gpsins/aiding/velocity.hpp"
#include "gpsins/eskf.hpp"
#include "gpsins/gnss/models.hpp"

namespace gpsins {

template <int NB, int NC, int NT>
Measurement<1, Eskf<NB, NC, NT>::N> range_rate(const Eskf<NB, NC, NT>& f, const Vec3& lever_body_m,
                                               const Vec3& gyro_rate_rad_per_s, const Vec3& sat_ecef,
                                               const Vec3& sat_v_ecef_mps, double corrected_rate_mps,
                                               double variance_m2_per_s2) {
  static_assert(Eskf<NB, NC, NT>::kHasClock, "range rates need the receiver clock drift state");
  const Mat3 c = f.nav.q_eb.toRotationMatrix();
  const Vec3 r_a = f.nav.r_ecef_m + c * lever_body_m;
  const Vec3 d = sat_ecef - r_a;
  const double rho = d.norm();
  const Vec3 u = d / rho;
  const Vec3 v_a = antenna_velocity(f, lever_body_m, gyro_rate_rad_per_s);
  const Vec3 v_rel = sat_v_ecef_mps - v_a;
  const Vec3 g = -(v_rel - u * u.dot(v_rel)) / rho;
  const auto dv_a = gnss_velocity(f, v_a, Mat3::Zero(), lever_body_m, gyro_rate_rad_per_s);
  Measurement<1, Eskf<NB, NC, NT>::N> m;
  m.y(0) = corrected_rate_mps - (u.dot(v_rel) + gnss::sagnac_rate_mps(sat_ecef, sat_v_ecef_mps, r_a, v_a) + f.clock(1));
  m.H = -u.transpose() * dv_a.H;
  m.H.template block<1, 3>(0, es::pos) += g.transpose();
  m.H.template block<1, 3>(0, es::att) -= g.transpose() * c * skew(lever_body_m);  // d(r_a)/d(theta) = -C [l]x
  m.H(0, Eskf<NB, NC, NT>::kClock + 1) = 1.0;
  m.R(0, 0) = variance_m2_per_s2;
  return m;
}

}  // namespace gpsins

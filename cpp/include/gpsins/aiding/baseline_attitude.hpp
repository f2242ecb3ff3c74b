// Heading and pitch of a dual-antenna GNSS baseline (the report's reference
// receiver, section 4.2): the direction of the baseline b (a unit vector in
// body axes, antenna 1 to antenna 2) in local NED is u = C_nb b, and the
// receiver measures
//   yaw   psi   = atan2(u_e, u_n)
//   pitch theta = atan2(-u_d, h),  h = sqrt(u_n^2 + u_e^2).
// With q_true = q (x) exp(dtheta): C_nb,true b = C_nb (b + dtheta x b), so
// du/ddtheta = -C_nb [b]x, and
//   dpsi/du   = [-u_e, u_n, 0] / h^2
//   dtheta/du = [u_n u_d / h, u_e u_d / h, -h] / (h^2 + u_d^2).
// The local frame's turn with a position error (about 1.6e-7 rad per metre)
// is left out of H.
#pragma once

#include <cmath>

#include "gpsins/aiding/measurement.hpp"
#include "gpsins/earth.hpp"
#include "gpsins/eskf.hpp"

namespace gpsins {

struct BaselineAngles {
  double yaw_rad = 0.0;
  double pitch_rad = 0.0;
  Eigen::Matrix<double, 2, 3> d_du = Eigen::Matrix<double, 2, 3>::Zero();  // rows yaw, pitch
};

// The baseline's angles for a direction u in NED, and their derivatives.
inline BaselineAngles baseline_angles(const Vec3& u) {
  BaselineAngles a;
  const double h2 = u.x() * u.x() + u.y() * u.y();
  const double h = std::sqrt(h2);
  a.yaw_rad = std::atan2(u.y(), u.x());
  a.pitch_rad = std::atan2(-u.z(), h);
  if (h2 > 0.0) {
    a.d_du.row(0) << -u.y() / h2, u.x() / h2, 0.0;
    a.d_du.row(1) << u.x() * u.z() / h, u.y() * u.z() / h, -h;
    a.d_du.row(1) /= h2 + u.z() * u.z();
  }
  return a;
}

inline double wrap_pi(double a) { return std::remainder(a, 2.0 * M_PI); }

// Rows: yaw, then pitch when use_pitch. Innovations are z - h, the yaw wrapped.
template <int M, int NB, int NC, int NT>
Measurement<M, Eskf<NB, NC, NT>::N> baseline_attitude(const Eskf<NB, NC, NT>& f, const Vec3& baseline_body,
                                                      double yaw_rad, double pitch_rad, double sigma_yaw_rad,
                                                      double sigma_pitch_rad) {
  static_assert(M == 1 || M == 2, "yaw, or yaw and pitch");
  Measurement<M, Eskf<NB, NC, NT>::N> m;
  const Geodetic llh = ecef_to_geodetic(f.nav.r_ecef_m);
  const Mat3 c_nb = rot_ned_to_ecef(llh.lat_rad, llh.lon_rad).transpose() * f.nav.q_eb.toRotationMatrix();
  const Vec3 b = baseline_body.normalized();
  const BaselineAngles a = baseline_angles(c_nb * b);
  const Eigen::Matrix<double, 2, 3> d_att = a.d_du * (-c_nb * skew(b));
  m.y(0) = wrap_pi(yaw_rad - a.yaw_rad);
  m.H.template block<1, 3>(0, es::att) = d_att.row(0);
  m.R(0, 0) = sigma_yaw_rad * sigma_yaw_rad;
  if constexpr (M == 2) {
    m.y(1) = pitch_rad - a.pitch_rad;
    m.H.template block<1, 3>(1, es::att) = d_att.row(1);
    m.R(1, 1) = sigma_pitch_rad * sigma_pitch_rad;
  }
  return m;
}

}  // namespace gpsins

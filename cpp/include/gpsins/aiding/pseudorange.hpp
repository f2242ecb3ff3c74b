// One satellite's pseudorange at the antenna r_a = r + C l (the FOI report, eqs. 7.18-7.19):
// P = |r_s - r_a| + Sagnac + b - c (dt_s - T_GD) + I + T + noise, b the receiver
// clock bias state (m). With u the unit vector from antenna to satellite,
// dP/d(dr) = -u^T, dP/d(dtheta) = u^T C [l]x, dP/db = 1.
#pragma once

#include "gpsins/aiding/measurement.hpp"
#include "gpsins/eskf.hpp"

namespace gpsins {

template <int NB, int NC, int NT>
Measurement<1, Eskf<NB, NC, NT>::N> pseudorange(const Eskf<NB, NC, NT>& f, const Vec3& lever_body_m,
                                                const Vec3& sat_ecef, double corrected_pr_m, double sagnac_m,
                                                double variance_m2) {
  static_assert(Eskf<NB, NC, NT>::kHasClock, "pseudoranges need the receiver clock states");
  Measurement<1, Eskf<NB, NC, NT>::N> m;
  const Mat3 c = f.nav.q_eb.toRotationMatrix();
  const Vec3 r_a = f.nav.r_ecef_m + c * lever_body_m;
  const Vec3 d = sat_ecef - r_a;
  const double range = d.norm();
  const Vec3 u = d / range;
  m.y(0) = corrected_pr_m - (range + sagnac_m + f.clock(0));
  m.H.template block<1, 3>(0, es::pos) = -u.transpose();
  m.H.template block<1, 3>(0, es::att) = u.transpose() * c * skew(lever_body_m);
  m.H(0, Eskf<NB, NC, NT>::kClock) = 1.0;
  m.R(0, 0) = variance_m2;
  return m;
}

}  // namespace gpsins

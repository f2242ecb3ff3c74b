// GNSS position fix at the antenna, offset from the IMU by a body-frame lever
// arm l: z = r + C l, so with q_true = q (x) exp(dtheta),
// z - (r + C l) = dr - C [l]x dtheta  (seed 003, lever arm slide).
// With the fix-error states (NC == 3) the fix is z = r + C l + b + white, b the
// time-correlated error: y = z - (r + C l + b), and H gains I on db.
#pragma once

#include "gpsins/aiding/measurement.hpp"
#include "gpsins/eskf.hpp"

namespace gpsins {

template <int NB, int NC>
Measurement<3, Eskf<NB, NC>::N> position_fix(const Eskf<NB, NC>& f, const Vec3& r_antenna_ecef_m,
                                              const Mat3& cov_ecef_m2, const Vec3& lever_body_m) {
  Measurement<3, Eskf<NB, NC>::N> m;
  const Mat3 c = f.nav.q_eb.toRotationMatrix();
  m.y = r_antenna_ecef_m - (f.nav.r_ecef_m + c * lever_body_m);
  m.H.template block<3, 3>(0, es::pos).setIdentity();
  m.H.template block<3, 3>(0, es::att) = -c * skew(lever_body_m);
  if constexpr (NC == 3) {
    m.y -= f.fix_error;
    m.H.template block<3, 3>(0, Eskf<NB, NC>::kFixError).setIdentity();
  }
  m.R = cov_ecef_m2;
  return m;
}

}  // namespace gpsins

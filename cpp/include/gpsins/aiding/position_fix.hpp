// GNSS position fix at the antenna, offset from the IMU by a body-frame lever
// arm l: z = r + C l, so with q_true = q (x) exp(dtheta),
// z - (r + C l) = dr - C [l]x dtheta  (the ESKF notes' lever arm).
// With the fix-error states (NC == 3) the fix is z = r + C l + M b + white, b the
// time-correlated error state and M its map to metres for this fix (identity, or
// the fix's DOP per local axis when the error is carried per unit of DOP):
// y = z - (r + C l + M b), and H gains M on db.
#pragma once

#include "gpsins/aiding/measurement.hpp"
#include "gpsins/eskf.hpp"

namespace gpsins {

template <int NB, int NC, int NT>
Measurement<3, Eskf<NB, NC, NT>::N> position_fix(const Eskf<NB, NC, NT>& f, const Vec3& r_antenna_ecef_m,
                                                 const Mat3& cov_ecef_m2, const Vec3& lever_body_m,
                                                 const Mat3& fix_error_map = Mat3::Identity()) {
  Measurement<3, Eskf<NB, NC, NT>::N> m;
  const Mat3 c = f.nav.q_eb.toRotationMatrix();
  m.y = r_antenna_ecef_m - (f.nav.r_ecef_m + c * lever_body_m);
  m.H.template block<3, 3>(0, es::pos).setIdentity();
  m.H.template block<3, 3>(0, es::att) = -c * skew(lever_body_m);
  if constexpr (NC == 3) {
    m.y -= fix_error_map * f.fix_error;
    m.H.template block<3, 3>(0, Eskf<NB, NC, NT>::kFixError) = fix_error_map;
  } else {
    (void)fix_error_map;
  }
  m.R = cov_ecef_m2;
  return m;
}

}  // namespace gpsins

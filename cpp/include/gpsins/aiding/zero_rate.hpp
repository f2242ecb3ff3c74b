// Zero angular rate update: standing still, the gyros see only the Earth's
// rotation, C^T w_ie. The corrected mean rate w_c over a window is
// w_true + dbg, and w_true = (I - [dtheta]x) C^T w_ie, so
// w_c - C^T w_ie = [C^T w_ie]x dtheta + dbg.
#pragma once

#include "gpsins/aiding/measurement.hpp"
#include "gpsins/eskf.hpp"

namespace gpsins {

template <int NB, int NC>
Measurement<3, Eskf<NB, NC>::N> zero_rate(const Eskf<NB, NC>& f, const Vec3& mean_corrected_rate_rad_per_s,
                                           const Vec3& var_rad2_per_s2) {
  Measurement<3, Eskf<NB, NC>::N> m;
  const Vec3 earth_b = f.nav.q_eb.conjugate() * earth_rate_ecef();
  m.y = mean_corrected_rate_rad_per_s - earth_b;
  m.H.template block<3, 3>(0, es::att) = skew(earth_b);
  m.H.template block<3, 3>(0, es::bg).setIdentity();
  m.R = var_rad2_per_s2.asDiagonal();
  return m;
}

}  // namespace gpsins

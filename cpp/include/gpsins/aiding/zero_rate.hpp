// Zero angular rate update: standing still, the gyros see only the Earth's
// rotation. The gyro reports m = (1 + s_true) w_true + b_true with
// w_true = (I - [dtheta]x) C^T w_ie; corrected by the state's bias and scale
// factor, w_c = (m - b) / (1 + s), so to first order
//   w_c - C^T w_ie = [C^T w_ie]x dtheta + diag(1 / (1 + s)) dbg + diag(C^T w_ie / (1 + s)) dsg.
#pragma once

#include "gpsins/aiding/measurement.hpp"
#include "gpsins/eskf.hpp"

namespace gpsins {

template <int NB, int NC, int NT>
Measurement<3, Eskf<NB, NC, NT>::N> zero_rate(const Eskf<NB, NC, NT>& f, const Vec3& mean_corrected_rate_rad_per_s,
                                              const Vec3& var_rad2_per_s2) {
  Measurement<3, Eskf<NB, NC, NT>::N> m;
  const Vec3 earth_b = f.nav.q_eb.conjugate() * earth_rate_ecef();
  const Vec3 inv_1s = (Vec3::Ones() + f.imu.gyro_scale_factor).cwiseInverse();
  m.y = mean_corrected_rate_rad_per_s - earth_b;
  m.H.template block<3, 3>(0, es::att) = skew(earth_b);
  m.H.template block<3, 3>(0, es::bg) = inv_1s.asDiagonal();
  if constexpr (NB == 7) m.H.template block<3, 3>(0, es::sg) = earth_b.cwiseProduct(inv_1s).asDiagonal();
  m.R = var_rad2_per_s2.asDiagonal();
  return m;
}

}  // namespace gpsins

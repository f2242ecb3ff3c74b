// GNSS velocity at the antenna: v_a = v + C (w x l), w = w_ib - C^T w_ie the body
// rate relative to the Earth, w_ib = (m - b) / (1 + s) the gyro rate m (after the
// configured calibration) corrected by the bias and scale-factor states. With
// q_true = q (x) exp(dtheta), b_true = b + dbg, s_true = s + dsg:
//   dw_ib = -(dbg + w_ib .* dsg) ./ (1 + s),  C_true^T w_ie = C^T w_ie + [C^T w_ie]x dtheta,
//   v_a - h(x) = dv + C (-[w x l]x + [l]x [C^T w_ie]x) dtheta
//                + C [l]x diag(1 / (1 + s)) dbg + C [l]x diag(w_ib / (1 + s)) dsg.
#pragma once

#include "gpsins/aiding/measurement.hpp"
#include "gpsins/earth.hpp"
#include "gpsins/eskf.hpp"

namespace gpsins {

// w_ib: the gyro rate corrected by the bias and scale-factor states.
template <int NB, int NC, int NT>
Vec3 corrected_gyro_rate(const Eskf<NB, NC, NT>& f, const Vec3& gyro_rate_rad_per_s) {
  return (gyro_rate_rad_per_s - f.imu.gyro_bias_rad_per_s)
      .cwiseProduct((Vec3::Ones() + f.imu.gyro_scale_factor).cwiseInverse());
}

template <int NB, int NC, int NT>
Measurement<3, Eskf<NB, NC, NT>::N> gnss_velocity(const Eskf<NB, NC, NT>& f, const Vec3& v_antenna_ecef_mps,
                                                  const Mat3& cov, const Vec3& lever_body_m,
                                                  const Vec3& gyro_rate_rad_per_s) {
  Measurement<3, Eskf<NB, NC, NT>::N> m;
  const Mat3 c = f.nav.q_eb.toRotationMatrix();
  const Vec3 inv_1s = (Vec3::Ones() + f.imu.gyro_scale_factor).cwiseInverse();
  const Vec3 w_ib = corrected_gyro_rate(f, gyro_rate_rad_per_s);
  const Vec3 w_ie_b = c.transpose() * earth_rate_ecef();
  const Vec3 wl = (w_ib - w_ie_b).cross(lever_body_m);
  const Mat3 c_l = c * skew(lever_body_m);
  m.y = v_antenna_ecef_mps - (f.nav.v_ecef_mps + c * wl);
  m.H.template block<3, 3>(0, es::vel).setIdentity();
  m.H.template block<3, 3>(0, es::att) = -c * skew(wl) + c_l * skew(w_ie_b);
  m.H.template block<3, 3>(0, es::bg) = c_l * inv_1s.asDiagonal();
  if constexpr (NB == 7) m.H.template block<3, 3>(0, es::sg) = c_l * w_ib.cwiseProduct(inv_1s).asDiagonal();
  m.R = cov;
  return m;
}

// The body's rate relative to the Earth as the nominal state has it (body axes),
// and the antenna's velocity v + C (w x l) it gives (ECEF).
template <int NB, int NC, int NT>
Vec3 body_rate_wrt_earth(const Eskf<NB, NC, NT>& f, const Vec3& gyro_rate_rad_per_s) {
  return corrected_gyro_rate(f, gyro_rate_rad_per_s) - f.nav.q_eb.conjugate() * earth_rate_ecef();
}
template <int NB, int NC, int NT>
Vec3 antenna_velocity(const Eskf<NB, NC, NT>& f, const Vec3& lever_body_m, const Vec3& gyro_rate_rad_per_s) {
  return f.nav.v_ecef_mps + f.nav.q_eb * body_rate_wrt_earth(f, gyro_rate_rad_per_s).cross(lever_body_m);
}

}  // namespace gpsins

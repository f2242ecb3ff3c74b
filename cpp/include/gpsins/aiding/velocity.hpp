// GNSS velocity at the antenna: v_a = v + C (w x l), w the body rate relative to
// the Earth. With w = w_c - dbg (w_c the corrected gyro rate minus Earth rate),
// v_a - h(x) = dv - C [w x l]x dtheta + C [l]x dbg.
#pragma once

#include "gpsins/aiding/measurement.hpp"
#include "gpsins/eskf.hpp"

namespace gpsins {

template <int NB, int NC>
Measurement<3, Eskf<NB, NC>::N> gnss_velocity(const Eskf<NB, NC>& f, const Vec3& v_antenna_ecef_mps,
                                               const Mat3& cov, const Vec3& lever_body_m,
                                               const Vec3& w_eb_body_rad_per_s) {
  Measurement<3, Eskf<NB, NC>::N> m;
  const Mat3 c = f.nav.q_eb.toRotationMatrix();
  const Vec3 wl = w_eb_body_rad_per_s.cross(lever_body_m);
  m.y = v_antenna_ecef_mps - (f.nav.v_ecef_mps + c * wl);
  m.H.template block<3, 3>(0, es::vel).setIdentity();
  m.H.template block<3, 3>(0, es::att) = -c * skew(wl);
  m.H.template block<3, 3>(0, es::bg) = c * skew(lever_body_m);
  m.R = cov;
  return m;
}

}  // namespace gpsins

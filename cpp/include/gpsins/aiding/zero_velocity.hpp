// Zero-velocity update: while the vehicle stands still its IMU velocity is zero.
#pragma once

#include "gpsins/aiding/measurement.hpp"
#include "gpsins/eskf.hpp"

namespace gpsins {

template <int NB, int NC, int NT>
Measurement<3, Eskf<NB, NC, NT>::N> zero_velocity(const Eskf<NB, NC, NT>& f, double sigma_mps) {
  Measurement<3, Eskf<NB, NC, NT>::N> m;
  m.y = -f.nav.v_ecef_mps;
  m.H.template block<3, 3>(0, es::vel).setIdentity();
  m.R = Mat3::Identity() * sigma_mps * sigma_mps;
  return m;
}

}  // namespace gpsins

// The IMU time offset state (eskf.hpp, NT = 1) in a GNSS measurement. The
// measurement sees the vehicle at GNSS time t while the nominal state stands for
// true time t + dt, so to first order h(t) = h(nominal) - h_dot dt, h_dot the
// predicted measurement's rate along the trajectory: the innovation gains
// h_dot dt and H's offset column is -h_dot. For a measurement of the antenna's
// position (a fix, a pseudorange) h_dot = H_r v_a, H_r its position block and v_a
// the antenna's velocity (a fix: -v_a; a pseudorange: u . v_a, u the line of
// sight to the satellite); for one of its velocity h_dot = H_v a_a, a_a its
// acceleration (a fix velocity: -a_a).
#pragma once

#include "gpsins/aiding/measurement.hpp"
#include "gpsins/eskf.hpp"

namespace gpsins {

// block: es::pos with rate v_a, or es::vel with rate a_a. Nothing without the state.
// learn = false moves the prediction but leaves the column zero: the offset is not
// learnt while the motion the column stands for is unknown (heading not yet known).
template <int M, int NB, int NC, int NT>
void add_time_offset(Measurement<M, Eskf<NB, NC, NT>::N>& m, const Eskf<NB, NC, NT>& f, int block, const Vec3& rate,
                     bool learn = true) {
  if constexpr (NT == 1) {
    const Eigen::Matrix<double, M, 1> h_dot = m.H.template middleCols<3>(block) * rate;
    m.y += h_dot * f.time_offset_s;
    if (learn) m.H.col(Eskf<NB, NC, NT>::kTimeOffset) = -h_dot;
  } else {
    (void)m, (void)f, (void)block, (void)rate, (void)learn;
  }
}

// The antenna's acceleration (ECEF) from the IMU point's a (m/s^2) and the body
// rate relative to the Earth w (rad/s, body axes): a + C (w x (w x l)); the
// angular acceleration's part is left out.
inline Vec3 antenna_acceleration(const Vec3& a_ecef, const Mat3& c_eb, const Vec3& w_eb, const Vec3& lever_body_m) {
  return a_ecef + c_eb * w_eb.cross(w_eb.cross(lever_body_m));
}

}  // namespace gpsins

// InsFilter's restart after an IMU gap too long to bridge, as a definition that
// two files instantiate, gap_restart.cpp without the IMU time offset state and
// gap_restart_time_offset.cpp with it: the constant-velocity coast's dense N x N
// products make this one member 1.8 GB of compile memory for all twelve state
// layouts in one file, 0.45 GB for one.
#pragma once

#include <algorithm>
#include <cmath>

#include "internal.hpp"

namespace gpsins {

// An IMU gap too long to bridge: the motion over it is unknown. Attitude and
// biases are carried; the heading becomes unknown (the vehicle may have turned),
// roll and pitch get their initial spread on top, velocity and position the
// spread of an unknown acceleration over the gap. Fixes inside the gap are used
// at their times on a constant-velocity coast; they set no heading. Before
// initialisation the levelling starts over.
template <int NB, int NC, int NT>
void InsFilter<NB, NC, NT>::restart_after_gap(double gap_s, double t_end) {
  using filter_detail::square;
  core_.flush_covariance();
  ++counters_.imu_gap_restarts;
  event(kImuGapRestart, gap_s);
  detector_.reset();
  standstill_ = false;
  standstill_blocks_ = 0;
  last_inc_ = Increment{};
  if (!initialised()) {  // the levelling starts over
    level_f_sum_.setZero();
    level_time_ = 0.0;
    while (!pending_.empty() && pending_.front().t_s < t_end) {
      pending_.pop_front();
      ++counters_.fixes_before_alignment;
    }
    t_last_ = t_end;
    return;
  }
  auto& P = core_.P;
  const Geodetic llh = ecef_to_geodetic(core_.nav.r_ecef_m);
  const Mat3 c_bn = core_.nav.q_eb.toRotationMatrix().transpose() * rot_ned_to_ecef(llh.lat_rad, llh.lon_rad);
  const Mat3 att_ned = c_bn.transpose() * P.template block<3, 3>(es::att, es::att) * c_bn;
  const double a = cfg_.gap_accel_sigma_mps2;
  const double sv = cfg_.velocity_sigma_mps + a * gap_s, sp = cfg_.position_sigma_m + 0.5 * a * gap_s * gap_s;
  P.template topRows<9>().setZero();
  P.template leftCols<9>().setZero();
  const Vec3 att_var(att_ned(0, 0) + square(cfg_.attitude_sigma_rad).x(),
                     att_ned(1, 1) + square(cfg_.attitude_sigma_rad).y(), M_PI * M_PI);
  P.template block<3, 3>(es::att, es::att) = c_bn * att_var.asDiagonal() * c_bn.transpose();
  P.template block<3, 3>(es::vel, es::vel) = Mat3::Identity() * sv * sv;
  P.template block<3, 3>(es::pos, es::pos) = Mat3::Identity() * sp * sp;
  P.template block<3, 3>(es::bg, es::bg).diagonal() += core_.noise.gyro_bias_drive_var * gap_s;
  P.template block<3, 3>(es::ba, es::ba).diagonal() += core_.noise.accel_bias_drive_var * gap_s;
  if constexpr (Core::kHasClock) {
    P.template middleRows<2>(Core::kClock).setZero();
    P.template middleCols<2>(Core::kClock).setZero();
    P(Core::kClock, Core::kClock) = cfg_.clock_bias_sigma_m * cfg_.clock_bias_sigma_m;
    P(Core::kClock + 1, Core::kClock + 1) = cfg_.clock_drift_sigma_mps * cfg_.clock_drift_sigma_mps;
    clock_set_ = false;
    pending_pr_.clear();  // the clock restarts from the next epoch after the gap
    core_.note_restart(Core::kClock, 2);
  }
  core_.note_restart(0, 9);                      // the time offset is kept: a property of the sensors
  if constexpr (NT == 1) accel_ecef_.setZero();  // the coast below has none
  rejecting_ = false;
  auto coast = [&](double dt) {
    if (!(dt > 0.0)) return;
    core_.nav.r_ecef_m += core_.nav.v_ecef_mps * dt;
    core_.nav.t_s += dt;
    if constexpr (Core::kHasClock) core_.clock(0) += core_.clock(1) * dt;
    // The error moves as the state does (position by velocity, clock bias by drift):
    // P <- A P A^T, and the smoother is told A.
    typename Core::MatN move = Core::MatN::Identity();
    move.template block<3, 3>(es::pos, es::vel) = Mat3::Identity() * dt;
    if constexpr (Core::kHasClock) move(Core::kClock, Core::kClock + 1) = dt;
    P = (move * P * move.transpose()).eval();
    core_.note_transition(move);
    t_last_ += dt;
  };
  // No heading from these fixes: without the IMU the attitude cannot follow the vehicle
  // to the gap's end (a turn through it left the yaw 11 deg off), and a heading known would
  // let the constant-velocity coast's misfit teach the time offset. The first fix after
  // the gap sets it, as at the start.
  advance(PhaseEvent::GapCoast);
  while (!pending_.empty() && pending_.front().t_s < t_end) {
    const FixInput fix = pending_.pop_front();
    coast(fix.t_s - t_last_);
    process_fix(fix);
  }
  advance(PhaseEvent::GapEnd);
  coast(t_end - t_last_);
  t_last_ = t_end;
}

}  // namespace gpsins

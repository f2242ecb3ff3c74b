#include "gpsins/ins_filter.hpp"

#include <algorithm>
#include <cmath>
#include <numeric>

#include <Eigen/Cholesky>

#include "gpsins/aiding/baseline_attitude.hpp"
#include "gpsins/aiding/measurement.hpp"
#include "gpsins/aiding/nonholonomic.hpp"
#include "gpsins/aiding/position_fix.hpp"
#include "gpsins/aiding/pseudorange.hpp"
#include "gpsins/aiding/range_rate.hpp"
#include "gpsins/aiding/time_offset.hpp"
#include "gpsins/gnss/spp.hpp"
#include "gpsins/aiding/velocity.hpp"
#include "gpsins/aiding/zero_rate.hpp"
#include "gpsins/aiding/zero_velocity.hpp"
#include "gpsins/chi2.hpp"

namespace gpsins {

// ins_filter_time_offset.cpp compiles this file again for the instantiations with
// the time offset state (NT = 1), so that the two halves build in parallel.
#ifndef GPSINS_INS_FILTER_TIME_OFFSET
const char* input_status_text(InputStatus s) {
  switch (s) {
    case InputStatus::Ok: return "ok";
    case InputStatus::NonFinite: return "value is NaN or infinite";
    case InputStatus::TimeNotIncreasing: return "time does not increase";
    case InputStatus::BadValue: return "value out of range";
  }
  return "unknown";
}
#endif

namespace {

Vec3 square(const Vec3& v) { return v.cwiseProduct(v); }

ProcessNoise noise_of(const InsConfig& c) {
  ProcessNoise q;
  q.gyro_white_var = square(c.gyro_arw_rad_per_sqrt_s) + square(c.gyro_flicker_white_rad_per_sqrt_s);
  q.accel_white_var = square(c.accel_vrw_mps_per_sqrt_s) + square(c.accel_flicker_white_mps_per_sqrt_s);
  auto bias = [](const BiasConfig& b, Vec3& drive, Vec3& inv_tau) {
    switch (b.model) {
      case BiasModel::RandomWalk:
        drive = square(b.random_walk_per_sqrt_s);
        inv_tau.setZero();
        break;
      case BiasModel::GaussMarkov:  // driving noise 2 sigma^2 / T (seed 003)
        inv_tau = b.gm_tau_s.cwiseInverse();
        drive = 2.0 * square(b.gm_sigma).cwiseProduct(inv_tau);
        break;
      case BiasModel::Constant:
        drive.setZero();
        inv_tau.setZero();
        break;
    }
  };
  bias(c.gyro_bias, q.gyro_bias_drive_var, q.gyro_bias_inv_tau);
  bias(c.accel_bias, q.accel_bias_drive_var, q.accel_bias_inv_tau);
  q.gyro_misalignment_var = c.gyro_misalignment_sigma_rad * c.gyro_misalignment_sigma_rad;
  q.clock_bias_var = c.clock_bias_noise_m_per_sqrt_s * c.clock_bias_noise_m_per_sqrt_s;
  q.clock_drift_var = c.clock_drift_noise_mps_per_sqrt_s * c.clock_drift_noise_mps_per_sqrt_s;
  q.fix_error_var_ned = square(c.fix_error_gm_sigma_m);
  q.fix_error_inv_tau = c.fix_error_gm_tau_s > 0.0 ? 1.0 / c.fix_error_gm_tau_s : 0.0;
  q.time_offset_var = c.time_offset_rw_s_per_sqrt_s * c.time_offset_rw_s_per_sqrt_s;
  q.sis_inv_tau = c.pseudorange_sis_tau_s > 0.0 ? 1.0 / c.pseudorange_sis_tau_s : 0.0;
  return q;
}

StandstillThresholds thresholds_of(const InsConfig& c) {
  StandstillThresholds t;
  t.window_s = c.standstill_window_s;
  t.block_s = c.standstill_block_s;
  t.accel_std_mps2 = c.standstill_accel_std_mps2;
  t.gyro_std_rad_per_s = c.standstill_gyro_std_rad_per_s;
  t.gyro_mean_rad_per_s = c.standstill_gyro_mean_rad_per_s;
  t.accel_shift_mps2 = c.standstill_accel_shift_mps2;
  t.holdoff_s = c.standstill_holdoff_s;
  t.accel_vrw_mps_per_sqrt_s = c.accel_vrw_mps_per_sqrt_s;
  return t;
}

// Per axis: the stated sigma when it is one (finite, > 0), else the fallback.
Vec3 stated_or(const Vec3& stated, const Vec3& fallback) {
  Vec3 s = fallback;
  for (int i = 0; i < 3; ++i)
    if (std::isfinite(stated(i)) && stated(i) > 0.0) s(i) = stated(i);
  return s;
}

Euler levelled(const Vec3& f_mean) {
  Euler e;  // at rest f = -g in body axes (forward-right-down)
  e.roll_rad = std::atan2(-f_mean.y(), -f_mean.z());
  e.pitch_rad = std::atan2(f_mean.x(), std::hypot(f_mean.y(), f_mean.z()));
  return e;
}

// At rest the window's mean specific force, in the filter's attitude and less
// its bias, cancels gravity. Smooth braking or creeping at constant speed is
// quiet too, but leaves the acceleration in it (0.7 m/s^2 braking at 0.9 m/s
// began a standstill that pinned the velocity there). Tested against the
// spread the filter's tilt and bias allow, the window mean's noise and the
// configured at-rest shift.
template <class Core>
bool force_at_rest(const Core& core, const StandstillDetector& det, const InsConfig& cfg) {
  const Vec3 f_b = (det.mean_f() - core.imu.accel_bias_mps2).cwiseQuotient(Vec3::Ones() + core.imu.accel_scale_factor);
  const Mat3 c_eb = core.nav.q_eb.toRotationMatrix();
  const Vec3 f_e = c_eb * f_b;
  const Vec3 a = f_e + normal_gravity_ecef(core.nav.r_ecef_m);
  Eigen::Matrix<double, 3, 6> J;
  J.template leftCols<3>() = skew(f_e);
  J.template rightCols<3>() = c_eb;
  Eigen::Matrix<double, 6, 6> Pab;
  Pab.template block<3, 3>(0, 0) = core.P.template block<3, 3>(es::att, es::att);
  Pab.template block<3, 3>(0, 3) = core.P.template block<3, 3>(es::att, es::ba);
  Pab.template block<3, 3>(3, 0) = core.P.template block<3, 3>(es::ba, es::att);
  Pab.template block<3, 3>(3, 3) = core.P.template block<3, 3>(es::ba, es::ba);
  const double noise = cfg.accel_vrw_mps_per_sqrt_s.squaredNorm() / 3.0 / std::max(det.window_duration_s(), 1e-3);
  const Mat3 S = J * Pab * J.transpose() +
                 Mat3::Identity() * (noise + cfg.standstill_accel_shift_mps2 * cfg.standstill_accel_shift_mps2);
  const double d2 = a.dot(S.ldlt().solve(a));
  return std::isfinite(d2) && d2 < 16.27;  // chi-square, 3 dof, 0.999
}

}  // namespace

template <int NB, int NC, int NT>
InsFilter<NB, NC, NT>::InsFilter(const InsConfig& cfg) : cfg_(cfg), detector_(thresholds_of(cfg)) {
  core_.noise = noise_of(cfg);
  dt_nominal_ = cfg.imu_rate_hz > 0.0 ? 1.0 / cfg.imu_rate_hz : 1.0 / 64.0;
  const bool chi2 = cfg.update_check == UpdateCheck::ChiSquare || cfg.update_check == UpdateCheck::Both;
  const bool gating = chi2 && cfg.gate_probability > 0.0 && cfg.gate_probability < 1.0;
  for (int d = 1; d < static_cast<int>(gates_.size()); ++d)
    gates_[static_cast<std::size_t>(d)] = gating ? chi2_quantile(cfg.gate_probability, d) : 0.0;
  heading_known_ = std::isfinite(cfg.initial_yaw_rad);
  Euler v;
  v.yaw_rad = cfg.body_to_vehicle_ypr_rad.x();
  v.pitch_rad = cfg.body_to_vehicle_ypr_rad.y();
  v.roll_rad = cfg.body_to_vehicle_ypr_rad.z();
  c_vb_ = dcm_from_euler(v);
  pr_used_t_.fill(std::numeric_limits<double>::quiet_NaN());
  sis_prn_.fill(-1);
  sis_iode_.fill(-1);
  sis_used_t_.fill(-std::numeric_limits<double>::infinity());
}

template <int NB, int NC, int NT>
Increment InsFilter<NB, NC, NT>::calibrated(double dt, const Vec3& dtheta, const Vec3& dv) const {
  Increment inc;
  inc.dt_s = dt;
  inc.dtheta_rad = (dtheta - cfg_.gyro_bias_cal_rad_per_s * dt).cwiseQuotient(Vec3::Ones() + cfg_.gyro_scale_factor_cal);
  inc.dv_mps = (dv - cfg_.accel_bias_cal_mps2 * dt).cwiseQuotient(Vec3::Ones() + cfg_.accel_scale_factor_cal);
  return inc;
}

template <int NB, int NC, int NT>
InputStatus InsFilter<NB, NC, NT>::push_fix(const FixInput& given) {
  FixInput fix = given;
  if (!std::isfinite(fix.t_s)) return InputStatus::NonFinite;
  const bool solution = fix.mode == 2 || fix.mode == 3;
  // A fix that states its sigmas needs no DOP: the DOP (used when a reset has no
  // other figure) is then the one those sigmas stand for.
  auto stated = [](double s) { return std::isfinite(s) && s > 0.0; };
  if (!(std::isfinite(fix.hdop) && fix.hdop > 0.0) && stated(fix.sigma_ned_m.x()) && stated(fix.sigma_ned_m.y()))
    fix.hdop = std::hypot(fix.sigma_ned_m.x(), fix.sigma_ned_m.y()) / cfg_.fix_uere_m;
  if (!(std::isfinite(fix.vdop) && fix.vdop > 0.0) && stated(fix.sigma_ned_m.z()))
    fix.vdop = fix.sigma_ned_m.z() / cfg_.fix_uere_m;
  if (solution && (!fix.r_ecef_m.allFinite() || !std::isfinite(fix.hdop) || !std::isfinite(fix.vdop)))
    return InputStatus::NonFinite;
  if (solution && (fix.hdop <= 0.0 || fix.vdop <= 0.0)) return InputStatus::BadValue;
  if (have_fix_time_ && fix.t_s < last_fix_t_) return InputStatus::TimeNotIncreasing;
  have_fix_time_ = true;
  last_fix_t_ = fix.t_s;
  ++counters_.fixes;
  if (!solution) {
    ++counters_.fixes_without_solution;
    return InputStatus::Ok;
  }
  if (have_time_ && fix.t_s <= t_last_) {
    // Already past it: use it now (its latency is below one IMU interval when
    // measurements arrive in order).
    ++counters_.fixes_late;
    if (initialised_) process_fix(fix); else ++counters_.fixes_before_alignment;
    return InputStatus::Ok;
  }
  if (pending_count_ == kPending) {  // keep the newest; the oldest is used now
    const FixInput oldest = pending_[0];
    std::copy(pending_.begin() + 1, pending_.end(), pending_.begin());
    --pending_count_;
    if (have_time_ && oldest.t_s - t_last_ > cfg_.max_gap_s) {
      // The IMU has stopped for longer than a gap is bridged: used now, on a state that has not
      // moved, it would be rejected (and a run of them reset the filter onto a stale state); the
      // restart after the gap coasts through the newest queued ones.
      ++counters_.fixes_in_imu_gap;
    } else {
      ++counters_.fixes_late;
      if (initialised_) process_fix(oldest); else ++counters_.fixes_before_alignment;
    }
  }
  pending_[static_cast<std::size_t>(pending_count_++)] = fix;
  return InputStatus::Ok;
}

template <int NB, int NC, int NT>
InputStatus InsFilter<NB, NC, NT>::push_imu(double t_s, const Vec3& dtheta_rad, const Vec3& dv_mps) {
  if (!std::isfinite(t_s) || !dtheta_rad.allFinite() || !dv_mps.allFinite()) return InputStatus::NonFinite;
  if (have_time_ && !(t_s > t_last_)) return InputStatus::TimeNotIncreasing;
  double span = have_time_ ? t_s - t_last_ : dt_nominal_;
  double cover = 1.0;  // the share of this sample's increments its step stands for
  ++counters_.imu_samples;
  if (!have_time_) {
    have_time_ = true;
    t_last_ = t_s - span;
  } else if (span > cfg_.max_gap_s) {
    restart_after_gap(span - dt_nominal_, t_s - dt_nominal_);
    // Increments that cover every step cover the gap too: the navigation restarts one
    // nominal step before this sample, so only that step's share of them is applied (all
    // of them in one step were beyond the range and replaced by nothing, 10 ms of free fall
    // after a 2 s gap; without a range they left 19 m/s of climb and a 2 deg tilt).
    if (cfg_.imu_increments_cover_gaps) cover = dt_nominal_ / span;
    span = dt_nominal_;
  } else {
    track_step(span);
  }

  // The frame's increments cover its own interval; a longer span means frames
  // were lost: bridged with the previous rates. So is a sample beyond the range.
  const bool gap = !cfg_.imu_increments_cover_gaps && span > 1.5 * dt_nominal_;
  const double dt = gap ? dt_nominal_ : span;
  const Vec3 dtheta_s = dtheta_rad * cover, dv_s = dv_mps * cover;
  const double over = out_of_range(dtheta_s, dv_s, dt);
  const bool bad = over > 1.05;
  if (bad) {
    ++counters_.imu_samples_rejected;
    event(kImuSampleRejected, over);
  }
  const Increment inc = calibrated(dt, dtheta_s, dv_s);
  if (gap || bad) {
    if (gap) ++counters_.imu_gaps_bridged;
    Increment bridge;
    bridge.dt_s = bad ? span : span - dt;
    if (last_inc_.dt_s > 0.0) {
      const double scale = bridge.dt_s / last_inc_.dt_s;
      bridge.dtheta_rad = last_inc_.dtheta_rad * scale;
      bridge.dv_mps = last_inc_.dv_mps * scale;
    }
    propagate_to(bridge);
  }
  if (!bad) {
    const bool was_initialised = initialised_;
    propagate_to(inc);
    if (!was_initialised && !initialised_) {
      level_f_sum_ += inc.dv_mps;
      level_time_ += inc.dt_s;
    }
    last_inc_ = inc;
    detect_standstill(inc);
  }
  t_last_ = t_s;
  while (pending_att_count_ > 0 && pending_att_[0].t_s <= t_last_) {
    const AttitudeInput a = pending_att_[0];
    std::copy(pending_att_.begin() + 1, pending_att_.begin() + pending_att_count_, pending_att_.begin());
    --pending_att_count_;
    process_attitude(a, inc);
  }
  return InputStatus::Ok;
}

template <int NB, int NC, int NT>
InputStatus InsFilter<NB, NC, NT>::push_attitude(const AttitudeInput& a) {
  if (!std::isfinite(a.t_s) || !std::isfinite(a.yaw_rad) || !std::isfinite(a.sigma_yaw_rad))
    return InputStatus::NonFinite;
  if (!(a.sigma_yaw_rad > 0.0) || (std::isfinite(a.pitch_rad) && !(a.sigma_pitch_rad > 0.0)))
    return InputStatus::BadValue;
  if (a.t_s < last_att_t_) return InputStatus::TimeNotIncreasing;
  last_att_t_ = a.t_s;
  if (have_time_ && a.t_s <= t_last_) {
    process_attitude(a, last_inc_);
    return InputStatus::Ok;
  }
  if (pending_att_count_ == kPending) {  // keep the newest
    std::copy(pending_att_.begin() + 1, pending_att_.end(), pending_att_.begin());
    --pending_att_count_;
  }
  pending_att_[static_cast<std::size_t>(pending_att_count_++)] = a;
  return InputStatus::Ok;
}

// A dual-antenna heading (and pitch), carried from its time to now with the
// turn the gyros measured over the last increment. While the heading is not
// yet known its variance is pi^2 about the vertical (decouple_yaw), and a
// heading measurement sets it through the ordinary update: the yaw row is
// linear in the attitude error about the vertical, so one update moves the
// yaw by the whole (wrapped) innovation.
template <int NB, int NC, int NT>
void InsFilter<NB, NC, NT>::process_attitude(const AttitudeInput& a, const Increment& inc) {
  if (!initialised_) return;
  ++counters_.baseline_attitude_updates;
  const Vec3 b = cfg_.antenna_baseline_body.normalized();
  double yaw = a.yaw_rad, pitch = a.pitch_rad;
  if (inc.dt_s > 0.0) {
    const Geodetic llh = ecef_to_geodetic(core_.nav.r_ecef_m);
    const Mat3 c_nb = rot_ned_to_ecef(llh.lat_rad, llh.lon_rad).transpose() * core_.nav.q_eb.toRotationMatrix();
    const BaselineAngles now = baseline_angles(c_nb * b);
    const Vec3 u_dot = c_nb * (inc.dtheta_rad / inc.dt_s).cross(b);
    const Eigen::Vector2d rates = now.d_du * u_dot;
    const double lag = t_last_ - a.t_s;
    yaw += rates(0) * lag;
    pitch += rates(1) * lag;
  }
  const bool was_known = heading_known_;
  heading_known_ = true;  // so that record() does not decouple the yaw just measured
  // The first heading may turn the attitude by anything: not a divergence.
  const double limit = was_known ? attitude_limit() : 0.0;
  auto use = [&](const auto& m, int dof) {
    const auto r = core_.update(m.y, m.H, m.R, gate(dof), limit);
    heading_known_ = was_known || r.accepted;
    record(kBaselineAttitude, r, dof);
  };
  if (std::isfinite(pitch))
    use(baseline_attitude<2>(core_, b, yaw, pitch, a.sigma_yaw_rad, a.sigma_pitch_rad), 2);
  else
    use(baseline_attitude<1>(core_, b, yaw, pitch, a.sigma_yaw_rad, 0.0), 1);
  if (heading_known_ && !was_known) event(kHeadingSet, yaw);
}

// The nominal step: the median of the last kSteps steps of the time stamps.
template <int NB, int NC, int NT>
void InsFilter<NB, NC, NT>::track_step(double span) {
  steps_[static_cast<std::size_t>(steps_head_)] = span;
  steps_head_ = (steps_head_ + 1) % kSteps;
  steps_count_ = std::min(steps_count_ + 1, kSteps);
  std::array<double, kSteps> v = steps_;
  const auto mid = v.begin() + steps_count_ / 2;
  std::nth_element(v.begin(), mid, v.begin() + steps_count_);
  dt_nominal_ = *mid;
}

// The sample's largest rate or specific force as a fraction of its range (0: no range set).
template <int NB, int NC, int NT>
double InsFilter<NB, NC, NT>::out_of_range(const Vec3& dtheta, const Vec3& dv, double dt) const {
  double r = 0.0;
  if (cfg_.gyro_range_rad_per_s > 0.0) r = std::max(r, dtheta.cwiseAbs().maxCoeff() / dt / cfg_.gyro_range_rad_per_s);
  if (cfg_.accel_range_mps2 > 0.0) r = std::max(r, dv.cwiseAbs().maxCoeff() / dt / cfg_.accel_range_mps2);
  return r;
}

template <int NB, int NC, int NT>
void InsFilter<NB, NC, NT>::event(int kind, double value) {
  if (events_) events_->push_back(FilterEvent{t_last_, kind, value});
}

// An IMU gap too long to bridge: the motion over it is unknown. Attitude and
// biases are carried; the heading becomes unknown (the vehicle may have turned),
// roll and pitch get their initial spread on top, velocity and position the
// spread of an unknown acceleration over the gap. Fixes inside the gap are used
// at their times on a constant-velocity coast; they set no heading. Before
// initialisation the levelling starts over.
template <int NB, int NC, int NT>
void InsFilter<NB, NC, NT>::restart_after_gap(double gap_s, double t_end) {
  ++counters_.imu_gap_restarts;
  event(kImuGapRestart, gap_s);
  detector_.reset();
  standstill_ = false;
  standstill_blocks_ = 0;
  last_inc_ = Increment{};
  if (!initialised_) {
    level_f_sum_.setZero();
    level_time_ = 0.0;
    while (pending_count_ > 0 && pending_[0].t_s < t_end) {
      std::copy(pending_.begin() + 1, pending_.begin() + pending_count_, pending_.begin());
      --pending_count_;
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
  const Vec3 att_var(att_ned(0, 0) + square(cfg_.attitude_sigma_rad).x(), att_ned(1, 1) + square(cfg_.attitude_sigma_rad).y(),
                     M_PI * M_PI);
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
    pending_pr_count_ = 0;  // the clock restarts from the next epoch after the gap
    core_.note_restart(Core::kClock, 2);
  }
  core_.note_restart(0, 9);  // the time offset is kept: a property of the sensors
  if constexpr (NT == 1) accel_ecef_.setZero();  // the coast below has none
  heading_known_ = false;
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
  coasting_ = true;
  while (pending_count_ > 0 && pending_[0].t_s < t_end) {
    const FixInput fix = pending_[0];
    std::copy(pending_.begin() + 1, pending_.begin() + pending_count_, pending_.begin());
    --pending_count_;
    coast(fix.t_s - t_last_);
    process_fix(fix);
  }
  coasting_ = false;
  coast(t_end - t_last_);
  t_last_ = t_end;
}

// Sustained rejection while the receiver reports solutions: true when a reset is due.
template <int NB, int NC, int NT>
void InsFilter<NB, NC, NT>::note_gnss(bool accepted, double t) {
  if (accepted) {
    rejecting_ = false;
  } else if (!rejecting_) {
    rejecting_ = true;
    rejected_since_ = t;
  }
}

// Position and velocity from GNSS with their initial spread (PX4 EKF2's reset
// after its fusion timeout); cross terms with the other states dropped. The attitude
// that let the filter drift off is suspect too: its tilt and yaw variances grow by the
// initial levelling's and heading's, so the fixes after the reset can correct it (a
// reset that kept the attitude's old confidence left a car's pitch 2-3 deg off).
template <int NB, int NC, int NT>
void InsFilter<NB, NC, NT>::reset_to_fix(const FixInput& fix) {
  ++counters_.gnss_resets;
  counters_.diverged = true;
  event(kGnssReset, fix.t_s - rejected_since_);
  rejecting_ = false;
  auto& P = core_.P;
  core_.nav.r_ecef_m = fix.r_ecef_m - core_.nav.q_eb * cfg_.lever_arm_body_m - fix_error_estimate(fix);
  double var_v = cfg_.velocity_sigma_mps * cfg_.velocity_sigma_mps;
  if (fix.v_ecef_mps.allFinite()) {
    core_.nav.v_ecef_mps = fix.v_ecef_mps;
  } else if (have_prev_fix_ && fix.t_s - prev_fix_.t_s > 0.0 && fix.t_s - prev_fix_.t_s <= 2.0) {
    core_.nav.v_ecef_mps = (fix.r_ecef_m - prev_fix_.r_ecef_m) / (fix.t_s - prev_fix_.t_s);
    const double dt = fix.t_s - prev_fix_.t_s, s = cfg_.fix_uere_m * fix.hdop;
    var_v += 2.0 * s * s / (dt * dt);
  } else {
    var_v += core_.nav.v_ecef_mps.squaredNorm() + 100.0;
  }
  // The nominal stands for the fix's time plus the IMU time offset.
  if constexpr (NT == 1) core_.nav.r_ecef_m += core_.nav.v_ecef_mps * core_.time_offset_s;
  const Geodetic llh = ecef_to_geodetic(core_.nav.r_ecef_m);
  const Mat3 c_bn = core_.nav.q_eb.toRotationMatrix().transpose() * rot_ned_to_ecef(llh.lat_rad, llh.lon_rad);
  const Mat3 att_ned = c_bn.transpose() * P.template block<3, 3>(es::att, es::att) * c_bn;
  const Vec3 att_var = att_ned.diagonal() + square(Vec3(cfg_.attitude_sigma_rad.x(), cfg_.attitude_sigma_rad.y(),
                                                        heading_known_ ? cfg_.heading_sigma_rad : cfg_.attitude_sigma_rad.z()));
  P.template topRows<9>().setZero();
  P.template leftCols<9>().setZero();
  P.template block<3, 3>(es::att, es::att) = c_bn * att_var.asDiagonal() * c_bn.transpose();
  P.template block<3, 3>(es::vel, es::vel) = Mat3::Identity() * var_v;
  // The fix's own spread where it is wider than the configured initial one.
  const double s_fix = cfg_.fix_uere_m * std::max(fix.hdop, fix.vdop);
  P.template block<3, 3>(es::pos, es::pos) =
      Mat3::Identity() * std::max(cfg_.position_sigma_m * cfg_.position_sigma_m, s_fix * s_fix);
  core_.note_restart(es::att, 9);
  rejections_in_row_.fill(0);
  if constexpr (Core::kHasClock) clock_set_ = false;
}

// While the heading is unknown the horizontal acceleration is applied in a
// wrong direction: the velocity error grows by up to twice its size. Its
// variance grows accordingly (as a random walk over one second). The part of
// the horizontal specific force a tilt error explains (0.1 m/s^2, about half a
// degree) is left to the attitude states; standing still there is none.
template <int NB, int NC, int NT>
void InsFilter<NB, NC, NT>::inflate_unknown_heading(const Increment& inc) {
  if (!(inc.dt_s > 0.0)) return;
  const Vec3 u = core_.nav.r_ecef_m.normalized();
  const Vec3 f = core_.nav.q_eb * (inc.dv_mps / inc.dt_s - core_.imu.accel_bias_mps2);
  const double a = std::max(0.0, (f - f.dot(u) * u).norm() - 0.1);
  const double q = 4.0 * a * a * inc.dt_s;
  core_.P.template block<3, 3>(es::vel, es::vel) += q * (Mat3::Identity() - u * u.transpose());
}

// The core's propagation over `inc` (which ends at t_end), keeping its velocity
// change when fix velocities lag.
template <int NB, int NC, int NT>
void InsFilter<NB, NC, NT>::propagate_nav(const Increment& inc, double t_end) {
  const Vec3 v0 = core_.nav.v_ecef_mps;
  core_.propagate(inc);
  // The acceleration the mechanisation applied: the velocity fix's offset column.
  if constexpr (NT == 1)
    if (inc.dt_s > 0.0) accel_ecef_ = (core_.nav.v_ecef_mps - v0) / inc.dt_s;
  if (!(cfg_.fix_velocity_lag_s > 0.0)) return;
  if (velocity_steps_.empty()) velocity_steps_.resize(kVelocitySteps);
  velocity_steps_[static_cast<std::size_t>(velocity_steps_head_)] = {t_end, inc.dt_s, core_.nav.v_ecef_mps - v0};
  velocity_steps_head_ = (velocity_steps_head_ + 1) % kVelocitySteps;
  velocity_steps_count_ = std::min(velocity_steps_count_ + 1, kVelocitySteps);
}

// The navigation velocity's change by propagation from t0 to now (a step across t0
// counts in proportion).
template <int NB, int NC, int NT>
Vec3 InsFilter<NB, NC, NT>::velocity_change_since(double t0) const {
  Vec3 sum = Vec3::Zero();
  for (int i = 1; i <= velocity_steps_count_; ++i) {
    const int at = (velocity_steps_head_ - i + kVelocitySteps) % kVelocitySteps;
    const auto& st = velocity_steps_[static_cast<std::size_t>(at)];
    if (st.t_end <= t0) break;
    const double start = st.t_end - st.dt_s;
    sum += start >= t0 || st.dt_s <= 0.0 ? st.dv : Vec3(st.dv * ((st.t_end - t0) / st.dt_s));
  }
  return sum;
}

// Propagate across `inc`, which starts at t_last_, stopping at every pending
// fix inside it; t_last_ ends at its end.
template <int NB, int NC, int NT>
void InsFilter<NB, NC, NT>::propagate_to(const Increment& inc) {
  Increment rest = inc;
  for (;;) {
    // The earliest held measurement inside this increment, fixes first on a tie.
    const double t_end = t_last_ + rest.dt_s;
    const bool fix_due = pending_count_ > 0 && pending_[0].t_s <= t_end;
    const bool pr_due = pending_pr_count_ > 0 && pending_pr_[0].t_s <= t_end;
    if (!fix_due && !pr_due) break;
    const bool take_fix = fix_due && (!pr_due || pending_[0].t_s <= pending_pr_[0].t_s);
    const double t_meas = take_fix ? pending_[0].t_s : pending_pr_[0].t_s;
    const double frac = std::clamp((t_meas - t_last_) / rest.dt_s, 0.0, 1.0);
    Increment first, second;
    split_increment(rest, frac, first, second);
    if (initialised_) propagate_nav(first, t_last_ + first.dt_s);
    t_last_ += first.dt_s;
    if (take_fix) {
      const FixInput fix = pending_[0];
      std::copy(pending_.begin() + 1, pending_.begin() + pending_count_, pending_.begin());
      --pending_count_;
      if (initialised_) {
        process_fix(fix);
      } else if (level_time_ + first.dt_s >= cfg_.level_time_s - 0.5 * dt_nominal_) {
        level_f_sum_ += first.dv_mps;
        level_time_ += first.dt_s;
        initialise(fix);
      } else {
        ++counters_.fixes_before_alignment;
      }
    } else {
      const PseudorangeEpoch ep = pending_pr_[0];
      std::copy(pending_pr_.begin() + 1, pending_pr_.begin() + pending_pr_count_, pending_pr_.begin());
      --pending_pr_count_;
      if (initialised_) process_pseudoranges(ep);
    }
    rest = second;
  }
  t_last_ += rest.dt_s;
  if (!initialised_) return;
  propagate_nav(rest, t_last_);
  if (!heading_known_) {
    if (!standstill_) inflate_unknown_heading(rest);
    decouple_yaw();
  } else if (cfg_.nonholonomic_constraint) {
    constrain_vehicle(rest);
  }
  const double pos_var = core_.P.template block<3, 3>(es::pos, es::pos).trace();
  if (!std::isfinite(pos_var) || pos_var > 3.0 * cfg_.max_position_sigma_m * cfg_.max_position_sigma_m ||
      !core_.nav.r_ecef_m.allFinite())
    counters_.diverged = true;
}

// The land-vehicle constraint while moving (standing, the zero-velocity update
// says more); at most every nhc_interval_s.
template <int NB, int NC, int NT>
void InsFilter<NB, NC, NT>::constrain_vehicle(const Increment& inc) {
  if (!(inc.dt_s > 0.0) || standstill_ || t_last_ - last_nhc_t_ < cfg_.nhc_interval_s - 1e-9) return;
  if (core_.nav.v_ecef_mps.norm() < cfg_.nhc_min_speed_mps) return;
  last_nhc_t_ = t_last_;
  const auto m = nonholonomic(core_, c_vb_, cfg_.vehicle_point_body_m, inc.dtheta_rad / inc.dt_s, cfg_.nhc_sigma_mps);
  record(kNonholonomic, apply(m, 2, kNonholonomic), 2);
  ++counters_.nonholonomic_updates;
}

template <int NB, int NC, int NT>
InputStatus InsFilter<NB, NC, NT>::push_pseudoranges(const PseudorangeEpoch& ep) {
  if constexpr (NC == 0) {
    return InputStatus::BadValue;
  } else {
    if (!std::isfinite(ep.t_s)) return InputStatus::NonFinite;
    if (ep.n < 0 || ep.n > PseudorangeEpoch::kMaxSats) return InputStatus::BadValue;
    for (int i = 0; i < ep.n; ++i)
      if (!std::isfinite(ep.pr_m[static_cast<std::size_t>(i)])) return InputStatus::NonFinite;
    if (ep.t_s <= last_pr_t_) return InputStatus::TimeNotIncreasing;
    last_pr_t_ = ep.t_s;
    ++counters_.pseudorange_epochs;
    track_locks(ep);
    PseudorangeEpoch e = ep;
    if (counters_.pseudorange_epochs % std::max(1, cfg_.pseudorange_decimation) != 0) {
      // The decimation is for the ranges' correlated errors; the Doppler's are white, so every epoch gives it.
      if (!(cfg_.doppler_sigma_mps > 0.0) || !ep.has_doppler()) return InputStatus::Ok;
      e.ranges = false;
    }
    if (have_time_ && e.t_s <= t_last_) {
      if (initialised_) process_pseudoranges(e);
      return InputStatus::Ok;
    }
    if (pending_pr_count_ == kPendingPr) {
      const PseudorangeEpoch oldest = pending_pr_[0];
      std::copy(pending_pr_.begin() + 1, pending_pr_.end(), pending_pr_.begin());
      --pending_pr_count_;
      if (initialised_) process_pseudoranges(oldest);
    }
    pending_pr_[static_cast<std::size_t>(pending_pr_count_++)] = e;
    return InputStatus::Ok;
  }
}

// (1 + a) / (1 - a), a = exp(-dt / tau): what a Gauss-Markov error's stationary
// variance is multiplied by when a satellite's updates dt apart are treated as
// independent. a = 0 (factor 1) without a previous update or for a white error.
static double gm_update_factor(double dt, double tau) {
  if (!(dt > 0.0) || !(tau > 0.0)) return 1.0;  // dt NaN: none since acquisition
  const double one_minus_a = -std::expm1(-dt / tau);  // accurate for dt << tau
  return (2.0 - one_minus_a) / one_minus_a;
}

// The variance a pseudorange's correlated errors add to this update: multipath
// (pseudorange_error_gm_*, growing as 1 / sin(elevation)) and signal in space
// (sigma sis_m, the same at any elevation; 0 when a state carries it), each
// sigma^2 (1 + a) / (1 - a) with its own tau, dt since the satellite's previous update.
template <int NB, int NC, int NT>
double InsFilter<NB, NC, NT>::correlated_variance(int prn, double t, double el_rad, double sis_m) const {
  const bool known = gnss::is_sat_id(prn);
  const double dt = known ? t - pr_used_t_[static_cast<std::size_t>(prn)] : std::numeric_limits<double>::quiet_NaN();
  double var = 0.0;
  if (cfg_.pseudorange_error_gm_sigma_m > 0.0 && known) {
    const double s = cfg_.pseudorange_error_gm_sigma_m / std::max(std::sin(el_rad), 0.1);
    var += s * s * gm_update_factor(dt, cfg_.pseudorange_error_gm_tau_s);
  }
  if (sis_m > 0.0) var += sis_m * sis_m * gm_update_factor(dt, cfg_.pseudorange_sis_tau_s);
  return var;
}

// Signal-in-space slots (pseudorange_sis_states). A satellite keeps its slot while
// it is away (its broadcast error is still the same when it returns); a new
// ephemeris issue restarts it (a new upload, a new error). A satellite without one
// takes a free slot, else the one used longest ago, never one whose satellite was
// ranged at this epoch or the one before: a tracked satellite is not robbed (each
// theft would restart an error the filter has learnt, and the robbed one would rob
// the next), a satellite gone for an epoch may be.
template <int NB, int NC, int NT>
int InsFilter<NB, NC, NT>::sis_slot(int prn, int iode, double t, double var_m2) {
  if constexpr (Core::kSisCount > 0) {
    int pick = -1;
    for (int s = 0; s < kSisSlots; ++s) {
      const auto k = static_cast<std::size_t>(s);
      if (sis_prn_[k] == prn) {
        if (sis_iode_[k] != iode) {
          restart_sis_slot(s, var_m2);
          ++counters_.sis_slots_restarted;
        }
        sis_iode_[k] = iode;
        sis_used_t_[k] = t;
        return s;
      }
      if (sis_used_t_[k] < sis_prev_epoch_t_ || sis_prn_[k] < 0)
        if (pick < 0 || sis_used_t_[k] < sis_used_t_[static_cast<std::size_t>(pick)]) pick = s;
    }
    if (pick < 0) {
      ++counters_.pseudoranges_without_sis_slot;
      return -1;
    }
    const auto k = static_cast<std::size_t>(pick);
    restart_sis_slot(pick, var_m2);
    ++counters_.sis_slots_taken;
    sis_prn_[k] = prn;
    sis_iode_[k] = iode;
    sis_used_t_[k] = t;
    return pick;
  } else {
    (void)prn, (void)iode, (void)t, (void)var_m2;
    return -1;
  }
}

// With more satellites than slots the highest keep them: they are ranged first, so
// they take what is free. A range without a slot carries its signal-in-space error in
// its variance when that error is Gauss-Markov; a constant one (tau <= 0) would average
// into the position as if white, so that range is not used (its Doppler is).
template <int NB, int NC, int NT>
void InsFilter<NB, NC, NT>::assign_sis(PrUse* use, int n, const PseudorangeEpoch& ep) {
  if (ep.t_s > sis_epoch_t_) {
    sis_prev_epoch_t_ = sis_epoch_t_;
    sis_epoch_t_ = ep.t_s;
  }
  std::array<int, PseudorangeEpoch::kMaxSats> order{};
  std::iota(order.begin(), order.begin() + n, 0);
  std::stable_sort(order.begin(), order.begin() + n, [&](int a, int b) { return use[a].el_rad > use[b].el_rad; });
  for (int j = 0; j < n; ++j) {
    PrUse& u = use[order[static_cast<std::size_t>(j)]];
    const double sis = cfg_.pseudorange_sis_use_ura ? gnss::ura_m(u.eph->ura_index) : cfg_.pseudorange_sis_sigma_m;
    if (cfg_.pseudorange_sis_states && sis > 0.0) {
      u.sis_slot = sis_slot(u.prn, u.eph->iode, ep.t_s, sis * sis);
      u.range = u.sis_slot >= 0 || cfg_.pseudorange_sis_tau_s > 0.0;
    }
    u.var += correlated_variance(u.prn, ep.t_s, u.el_rad, u.sis_slot >= 0 ? 0.0 : sis);
  }
}

// A slot's error restarts unknown within its stationary spread, uncorrelated.
template <int NB, int NC, int NT>
void InsFilter<NB, NC, NT>::restart_sis_slot(int slot, double var_m2) {
  if constexpr (Core::kSisCount > 0) {
    const int i = Core::kSis + slot;
    core_.P.row(i).setZero();
    core_.P.col(i).setZero();
    core_.P(i, i) = var_m2;
    core_.noise.sis_var(slot) = var_m2;
    core_.sis(slot) = 0.0;
    core_.note_restart(i, 1);
  } else {
    (void)slot, (void)var_m2;
  }
}

// One pseudorange as a measurement: geometry, clock, the IMU time offset's range
// rate and, when it has a slot, the satellite's signal-in-space error.
template <int NB, int NC, int NT>
Measurement<1, InsFilter<NB, NC, NT>::N> InsFilter<NB, NC, NT>::range_measurement(const PrUse& u, const Vec3& v_a) const {
  if constexpr (Core::kHasClock) {
    auto m = pseudorange(core_, cfg_.lever_arm_body_m, u.sat, u.pr_corr, u.sagnac, u.var);
    add_time_offset(m, core_, es::pos, v_a, heading_known_);  // the range rate the receiver's motion gives
    if constexpr (Core::kSisCount > 0) {
      if (u.sis_slot >= 0) {
        m.y(0) -= core_.sis(u.sis_slot);
        m.H(0, Core::kSis + u.sis_slot) = 1.0;
      }
    }
    return m;
  } else {
    (void)u, (void)v_a;
    return Measurement<1, N>{};
  }
}

// The receiver's lock counter grows while a satellite stays locked (saturating);
// a drop, or a satellite missing from an epoch, means the lock was lost.
template <int NB, int NC, int NT>
void InsFilter<NB, NC, NT>::track_locks(const PseudorangeEpoch& ep) {
  std::array<bool, gnss::kMaxSatId + 1> seen{};
  for (int i = 0; i < ep.n; ++i) {
    const int prn = ep.prn[static_cast<std::size_t>(i)];
    if (!gnss::is_sat_id(prn)) continue;
    const auto p = static_cast<std::size_t>(prn);
    const int lock = ep.lock_count[static_cast<std::size_t>(i)];
    if (!tracked_[p] || lock < last_lock_[p]) {
      locked_since_[p] = ep.t_s;
      pr_used_t_[p] = std::numeric_limits<double>::quiet_NaN();  // a new track: its errors start afresh
    }
    last_lock_[p] = lock;
    seen[p] = true;
  }
  tracked_ = seen;
}

// The clock states describe the receiver's clock only while the epoch's
// median residual (pseudorange minus range: the clock seen through all
// satellites at once) agrees with them. It cannot on the first epoch; it does
// not after a clock jump (receivers that steer their clock step it by whole
// milliseconds) or when the oscillator drifts far beyond the drift's prior
// (1.4 us/s, 12.5 km between 30 s epochs, on a geodetic receiver): every
// pseudorange would then be gated out. So the bias is re-seeded from the
// median when it lies beyond the gate on two epochs in a row (one is a tail
// event) or far beyond it once; the drift too, from the last two medians,
// unless the step is a whole number of milliseconds.
template <int NB, int NC, int NT>
void InsFilter<NB, NC, NT>::check_clock(const PrUse* use, int n, double t) {
  if constexpr (Core::kHasClock) {
    std::array<double, PseudorangeEpoch::kMaxSats> res{}, var{};
    const Vec3 r_a = core_.nav.r_ecef_m + core_.nav.q_eb * cfg_.lever_arm_body_m;
    for (int i = 0; i < n; ++i) {
      const auto k = static_cast<std::size_t>(i);
      res[k] = use[k].pr_corr - ((use[k].sat - r_a).norm() + use[k].sagnac);
      var[k] = use[k].var;
    }
    std::nth_element(res.begin(), res.begin() + n / 2, res.begin() + n);
    std::nth_element(var.begin(), var.begin() + n / 2, var.begin() + n);
    const double median = res[static_cast<std::size_t>(n / 2)];
    const double d = median - core_.clock(0);
    const double var_d = core_.P(Core::kClock, Core::kClock) + var[static_cast<std::size_t>(n / 2)] +
                         core_.P.template block<3, 3>(es::pos, es::pos).trace() / 3.0;
    const double bound = gate(1) > 0.0 ? gate(1) : 25.0;  // squared, in sigmas
    const double z2 = d * d / var_d;
    const bool beyond = z2 > bound;
    const bool reseed = !clock_set_ || (beyond && (clock_suspect_ || z2 > 4.0 * bound));
    clock_suspect_ = clock_set_ && beyond && !reseed;
    if (reseed) {
      const double ms_m = 1e-3 * gnss::kSpeedOfLight;
      const double whole_ms = std::round(d / ms_m);
      const double rest = d - whole_ms * ms_m;
      const bool ms_jump = clock_set_ && whole_ms != 0.0 && rest * rest <= bound * var_d;
      const double dt = t - last_clock_t_;
      const bool drift_from_medians = clock_set_ && !ms_jump && dt > 0.0 && dt <= cfg_.clock_reseed_window_s;
      core_.clock(0) = median;
      core_.P.row(Core::kClock).setZero();
      core_.P.col(Core::kClock).setZero();
      core_.P(Core::kClock, Core::kClock) = cfg_.clock_bias_sigma_m * cfg_.clock_bias_sigma_m;
      if (drift_from_medians) {  // centred on the two epochs' rate, within the drift's prior
        core_.clock(1) = (median - last_clock_median_m_) / dt;
        core_.P.row(Core::kClock + 1).setZero();
        core_.P.col(Core::kClock + 1).setZero();
        core_.P(Core::kClock + 1, Core::kClock + 1) = cfg_.clock_drift_sigma_mps * cfg_.clock_drift_sigma_mps;
      }
      core_.note_restart(Core::kClock, drift_from_medians ? 2 : 1);
      if (clock_set_) {
        ++counters_.clock_reseeds;
        event(kClockReseed, d);
      }
      clock_set_ = true;
    }
    last_clock_median_m_ = median;
    last_clock_t_ = t;
  } else {
    (void)use, (void)n, (void)t;
  }
}

// Galileo pseudoranges see the receiver clock plus the GPS-Galileo time offset
// and the receiver's own inter-system bias, neither known here. The epoch's
// differences from one Galileo satellite (the one with the smallest variance)
// carry neither: the unknown is eliminated, as a state with no prior and no
// memory would be, and Galileo adds geometry without touching the clock
// states. The differences share the reference satellite's noise, so they are
// whitened (R_d = L L^T, rows of L^-1 D) into independent scalar updates. Each
// row is formed again from the state the previous rows left (the innovations
// move with every injection; L does not depend on the state).
template <int NB, int NC, int NT>
bool InsFilter<NB, NC, NT>::update_galileo(const PrUse* use, int n, const Vec3& v_a, double t) {
  if constexpr (Core::kHasClock) {
    constexpr int kMax = PseudorangeEpoch::kMaxSats;
    using MatD = Eigen::Matrix<double, Eigen::Dynamic, Eigen::Dynamic, 0, kMax, kMax>;
    int ref = 0;
    for (int i = 1; i < n; ++i)
      if (use[i].var < use[ref].var) ref = i;
    std::array<int, kMax> other{};
    for (int i = 0, k = 0; i < n; ++i)
      if (i != ref) other[static_cast<std::size_t>(k++)] = i;
    const int nd = n - 1;
    MatD r_d = MatD::Constant(nd, nd, use[ref].var);
    for (int k = 0; k < nd; ++k) r_d(k, k) += use[other[static_cast<std::size_t>(k)]].var;
    const Eigen::LLT<MatD> llt(r_d);
    if (llt.info() != Eigen::Success) return false;
    const MatD l_inv = llt.matrixL().solve(MatD::Identity(nd, nd));
    bool any = false;
    for (int k = 0; k < nd; ++k) {
      const auto single = [&](int i) { return range_measurement(use[i], v_a); };
      const auto m_ref = single(ref);
      Measurement<1, N> m;
      for (int j = 0; j <= k; ++j) {  // L^-1 is lower triangular
        const auto m_j = single(other[static_cast<std::size_t>(j)]);
        m.y += l_inv(k, j) * (m_j.y - m_ref.y);
        m.H += l_inv(k, j) * (m_j.H - m_ref.H);
      }
      m.R(0, 0) = 1.0;
      const int prn = use[other[static_cast<std::size_t>(k)]].prn;
      const auto r = apply(m, 1);
      record(kPseudorange, r, 1, prn);
      ++(r.accepted ? counters_.pseudoranges_used : counters_.pseudoranges_rejected);
      if (r.accepted) {
        pr_used_t_[static_cast<std::size_t>(prn)] = t;
        pr_used_t_[static_cast<std::size_t>(use[ref].prn)] = t;
      }
      any = any || r.accepted;
    }
    return any;
  } else {
    (void)use, (void)n, (void)v_a, (void)t;
    return false;
  }
}

template <int NB, int NC, int NT>
void InsFilter<NB, NC, NT>::process_pseudoranges(const PseudorangeEpoch& ep) {
  if constexpr (Core::kHasClock) {
    // A satellite settles for a while after (re)acquisition (see track_locks).
    std::array<bool, PseudorangeEpoch::kMaxSats> settled{};
    for (int i = 0; i < ep.n; ++i) {
      const int prn = ep.prn[static_cast<std::size_t>(i)];
      settled[static_cast<std::size_t>(i)] =
          gnss::is_sat_id(prn) && ep.t_s - locked_since_[static_cast<std::size_t>(prn)] >= cfg_.pseudorange_settle_s;
    }

    const double t_abs = ep.t_s + cfg_.gps_time_offset_s;
    const double tow = std::fmod(t_abs, gnss::kSecondsPerWeek);
    const Mat3 c = core_.nav.q_eb.toRotationMatrix();
    const Vec3 r_a = core_.nav.r_ecef_m + c * cfg_.lever_arm_body_m;
    const Geodetic llh = ecef_to_geodetic(r_a);
    std::array<PrUse, PseudorangeEpoch::kMaxSats> use{};
    int n = 0;
    for (int i = 0; i < ep.n; ++i) {
      const auto k = static_cast<std::size_t>(i);
      const bool doppler = cfg_.doppler_sigma_mps > 0.0 && std::isfinite(ep.doppler_hz[k]);
      if (!ep.ranges && !doppler) continue;
      gnss::SatState st;
      const gnss::Ephemeris* eph = nullptr;
      if (!gnss::sat_at_transmission(store_, ep.prn[k], t_abs, ep.pr_m[k], st, &eph)) {
        if (ep.ranges) ++counters_.pseudoranges_no_ephemeris;
        continue;
      }
      const gnss::AzEl ae = gnss::az_el(llh, r_a, st.r_ecef_m);
      if (ae.el_rad < cfg_.pseudorange_elevation_mask_rad || ep.cn0_dbhz[k] < cfg_.pseudorange_min_cn0_dbhz ||
          !settled[k]) {
        if (ep.ranges) ++counters_.pseudoranges_masked;
        continue;
      }
      PrUse& u = use[static_cast<std::size_t>(n++)];
      u = PrUse{st.r_ecef_m, 0.0, gnss::sagnac_m(st.r_ecef_m, r_a), 0.0, ep.prn[k]};
      if (ep.ranges) {
        const double iono = cfg_.pseudorange_ionosphere ? gnss::klobuchar_m(iono_, llh, ae, tow) : 0.0;
        const double trop = cfg_.pseudorange_troposphere ? gnss::saastamoinen_m(llh, ae.el_rad) : 0.0;
        // The white part without the broadcast URA: orbit and clock errors are slow (assign_sis).
        u.var = cfg_.pseudorange_sigma_m > 0.0 ? cfg_.pseudorange_sigma_m * cfg_.pseudorange_sigma_m
                                               : gnss::pseudorange_variance_m2(ae.el_rad, 0.0, iono);
        u.el_rad = ae.el_rad;
        u.eph = eph;
        // Everything but geometry and the receiver clock moved to the measurement side.
        u.pr_corr = ep.pr_m[k] + gnss::kSpeedOfLight * (st.clock_s - eph->tgd_s) - iono - trop;
      }
      if (doppler) {
        const gnss::SatMotion sm = gnss::sat_motion(*eph, t_abs - ep.pr_m[k] / gnss::kSpeedOfLight - st.clock_s);
        const double s_el = std::sin(ae.el_rad);
        u.sat_v = sm.v_ecef_mps;
        u.rate_corr = -gnss::kL1WavelengthM * ep.doppler_hz[k] + gnss::kSpeedOfLight * sm.clock_drift;
        u.rate_var = 0.5 * cfg_.doppler_sigma_mps * cfg_.doppler_sigma_mps * (1.0 + 1.0 / (s_el * s_el));
      }
    }
    if (n == 0) return;
    if (ep.ranges) assign_sis(use.data(), n, ep);
    // GPS first, Galileo after it (see update_galileo): the clock states are GPS's. In
    // each, the ranges to use before those only the Doppler is used of.
    const auto galileo_first = std::stable_partition(use.begin(), use.begin() + n,
                                                     [](const PrUse& u) { return !gnss::is_galileo(u.prn); });
    const auto ranged = [](const PrUse& u) { return u.range; };
    const auto gps_end = std::stable_partition(use.begin(), galileo_first, ranged);
    const auto galileo_end = std::stable_partition(galileo_first, use.begin() + n, ranged);
    const int n_gps = ep.ranges ? static_cast<int>(gps_end - use.begin()) : 0;
    if (n_gps > 0) check_clock(use.data(), n_gps, ep.t_s);
    bool any = false;
    const Vec3 v_a = NT == 1 ? antenna_velocity_now() : Vec3::Zero();
    for (int i = 0; i < n_gps; ++i) {
      const auto& u = use[static_cast<std::size_t>(i)];
      const auto r = apply(range_measurement(u, v_a), 1);
      record(kPseudorange, r, 1, u.prn);
      ++(r.accepted ? counters_.pseudoranges_used : counters_.pseudoranges_rejected);
      if (r.accepted) pr_used_t_[static_cast<std::size_t>(u.prn)] = ep.t_s;
      any = any || r.accepted;
    }
    const int n_gal = ep.ranges ? static_cast<int>(galileo_end - galileo_first) : 0;
    if (n_gal >= 2) any = update_galileo(&*galileo_first, n_gal, v_a, ep.t_s) || any;
    // Every system's Doppler shares the one drift: the receiver's oscillator (GGTO's rate is nil).
    if (heading_known_) any = update_range_rates(use.data(), n) || any;
    note_gnss(any, ep.t_s);
  } else {
    (void)ep;
  }
}

template <int NB, int NC, int NT>
bool InsFilter<NB, NC, NT>::update_range_rates(const PrUse* use, int n) {
  bool any = false;
  if constexpr (Core::kHasClock) {
    const Vec3 rate = gyro_rate_now();
    const Vec3 a_a = NT == 1 ? antenna_acceleration_now() : Vec3::Zero();
    for (int i = 0; i < n; ++i) {
      const PrUse& u = use[i];
      if (!std::isfinite(u.rate_corr)) continue;
      auto m = range_rate(core_, cfg_.lever_arm_body_m, rate, u.sat, u.sat_v, u.rate_corr, u.rate_var);
      add_time_offset(m, core_, es::vel, a_a);
      const auto r = apply(m, 1);
      record(kRangeRate, r, 1, u.prn);
      ++(r.accepted ? counters_.range_rates_used : counters_.range_rates_rejected);
      any = any || r.accepted;
    }
  } else {
    (void)use, (void)n;
  }
  return any;
}

template <int NB, int NC, int NT>
void InsFilter<NB, NC, NT>::initialise(const FixInput& fix) {
  const Vec3 f_mean = level_f_sum_ / level_time_;
  Euler e = levelled(f_mean);
  e.yaw_rad = heading_known_ ? cfg_.initial_yaw_rad : 0.0;
  const Geodetic llh = ecef_to_geodetic(fix.r_ecef_m);
  core_.nav.q_eb = quat_body_to_ecef(e, llh.lat_rad, llh.lon_rad);
  core_.nav.r_ecef_m = fix.r_ecef_m - core_.nav.q_eb * cfg_.lever_arm_body_m;
  core_.nav.v_ecef_mps = fix.v_ecef_mps.allFinite() ? fix.v_ecef_mps : Vec3::Zero();
  core_.nav.t_s = fix.t_s;
  core_.imu = ImuErrorEstimate{};

  auto& P = core_.P;
  P.setZero();
  const Mat3 c_bn = core_.nav.q_eb.toRotationMatrix().transpose() * rot_ned_to_ecef(llh.lat_rad, llh.lon_rad);
  Vec3 att = cfg_.attitude_sigma_rad;
  if (!heading_known_) att.z() = M_PI;
  P.template block<3, 3>(es::att, es::att) = c_bn * square(att).asDiagonal() * c_bn.transpose();
  P.template block<3, 3>(es::vel, es::vel) = Mat3::Identity() * cfg_.velocity_sigma_mps * cfg_.velocity_sigma_mps;
  P.template block<3, 3>(es::pos, es::pos) = Mat3::Identity() * cfg_.position_sigma_m * cfg_.position_sigma_m;
  P.template block<3, 3>(es::bg, es::bg) = square(cfg_.gyro_bias_sigma_rad_per_s).asDiagonal();
  P.template block<3, 3>(es::ba, es::ba) = square(cfg_.accel_bias_sigma_mps2).asDiagonal();
  if constexpr (NB == 7) {
    P.template block<3, 3>(es::sg, es::sg) = square(cfg_.gyro_scale_factor_sigma).asDiagonal();
    P.template block<3, 3>(es::sa, es::sa) = square(cfg_.accel_scale_factor_sigma).asDiagonal();
  }
  if constexpr (Core::kHasClock) {
    P(Core::kClock, Core::kClock) = cfg_.clock_bias_sigma_m * cfg_.clock_bias_sigma_m;
    P(Core::kClock + 1, Core::kClock + 1) = cfg_.clock_drift_sigma_mps * cfg_.clock_drift_sigma_mps;
  }
  if constexpr (Core::kSisCount > 0) {  // every slot free; a free slot sits at a spread no update touches
    const double s = cfg_.pseudorange_sis_sigma_m > 0.0 ? cfg_.pseudorange_sis_sigma_m : 1.0;
    core_.sis.setZero();
    core_.noise.sis_var.setConstant(s * s);
    P.diagonal().template segment<Core::kSisCount>(Core::kSis).setConstant(s * s);
    sis_prn_.fill(-1);
    sis_iode_.fill(-1);
    sis_used_t_.fill(-std::numeric_limits<double>::infinity());
  }
  if constexpr (NC == 3) {  // the fix error starts unknown within its stationary spread
    core_.fix_error.setZero();
    P.template block<3, 3>(Core::kFixError, Core::kFixError) = core_.fix_error_stationary_cov();
  }
  if constexpr (NT == 1) {  // the residual offset starts at zero: the data set's declared one is applied
    core_.time_offset_s = 0.0;
    P(Core::kTimeOffset, Core::kTimeOffset) = cfg_.time_offset_sigma_s * cfg_.time_offset_sigma_s;
  }
  core_.note_restart(0, N);
  initialised_ = true;
  have_prev_fix_ = true;
  prev_fix_ = fix;
  ++counters_.fixes_accepted;
}

// Until a heading is known its error is anything but small, so the linear
// model must not couple it to the other states: keep the attitude error about
// the local vertical uncorrelated and at its initial spread.
template <int NB, int NC, int NT>
void InsFilter<NB, NC, NT>::decouple_yaw() {
  const Vec3 up_b = core_.nav.q_eb.conjugate() * core_.nav.r_ecef_m.normalized();
  const Mat3 keep = Mat3::Identity() - up_b * up_b.transpose();
  auto& P = core_.P;
  P.template middleRows<3>(es::att) = (keep * P.template middleRows<3>(es::att)).eval();
  P.template middleCols<3>(es::att) = (P.template middleCols<3>(es::att) * keep).eval();
  P.template block<3, 3>(es::att, es::att) += up_b * up_b.transpose() * (M_PI * M_PI);
  core_.note_attitude_map(keep);
}

// First heading from the course over ground: velocity and position restart at
// the fix (what the filter did before, without a heading, is not trustworthy
// once moving); the tilt and the IMU error estimates learnt so far are kept.
template <int NB, int NC, int NT>
void InsFilter<NB, NC, NT>::set_heading(const FixInput& fix, const Vec3& v_ecef, double course_rad, double sigma_rad) {
  const Geodetic llh = ecef_to_geodetic(fix.r_ecef_m);
  Euler e = euler_from_body_to_ecef(core_.nav.q_eb, llh.lat_rad, llh.lon_rad);
  e.yaw_rad = course_rad;
  // The tilt is kept (roll and pitch are, so the body's up is too): the
  // attitude error's part across the up axis carries over with its
  // correlations (the accelerometer biases' in particular), the part about it
  // starts afresh. Velocity and position restart at the fix.
  const Vec3 up_b = core_.nav.q_eb.conjugate() * core_.nav.r_ecef_m.normalized();
  const Mat3 keep = Mat3::Identity() - up_b * up_b.transpose();
  const Mat3 c_old = core_.nav.q_eb.toRotationMatrix();
  core_.nav.q_eb = quat_body_to_ecef(e, llh.lat_rad, llh.lon_rad);
  if constexpr (NT == 1) {
    // The last step's acceleration (the offset column of the velocity fix that follows) was
    // mechanised with the old heading: its specific-force part turns with the attitude.
    const Vec3 gamma = normal_gravity_ecef(core_.nav.r_ecef_m), w_ie = earth_rate_ecef();
    const Vec3 f_e = accel_ecef_ - gamma + 2.0 * w_ie.cross(core_.nav.v_ecef_mps);
    accel_ecef_ = core_.nav.q_eb.toRotationMatrix() * c_old.transpose() * f_e + gamma - 2.0 * w_ie.cross(v_ecef);
  }
  core_.nav.r_ecef_m = fix.r_ecef_m - core_.nav.q_eb * cfg_.lever_arm_body_m - fix_error_estimate(fix);
  core_.nav.v_ecef_mps = v_ecef;
  if constexpr (NT == 1) core_.nav.r_ecef_m += v_ecef * core_.time_offset_s;  // as in reset_to_fix
  event(kHeadingSet, course_rad);
  auto& P = core_.P;
  P.template middleRows<3>(es::att) = (keep * P.template middleRows<3>(es::att)).eval();
  P.template middleCols<3>(es::att) = (P.template middleCols<3>(es::att) * keep).eval();
  P.template block<3, 3>(es::att, es::att) += up_b * up_b.transpose() * (sigma_rad * sigma_rad);
  P.template middleRows<6>(es::vel).setZero();
  P.template middleCols<6>(es::vel).setZero();
  P.template block<3, 3>(es::vel, es::vel) = Mat3::Identity() * cfg_.velocity_sigma_mps * cfg_.velocity_sigma_mps;
  P.template block<3, 3>(es::pos, es::pos) = Mat3::Identity() * cfg_.position_sigma_m * cfg_.position_sigma_m;
  core_.note_attitude_map(keep);
  core_.note_restart(es::vel, 6);
  heading_known_ = true;
}

template <int NB, int NC, int NT>
template <int M>
void InsFilter<NB, NC, NT>::record(int kind, const UpdateResult<M>& r, int dof, int id) {
  UpdateRecord u;
  u.t_s = core_.nav.t_s;
  u.kind = kind;
  u.id = id;
  u.dof = dof;
  u.nis = r.nis;
  u.gate = gate(dof);
  u.log_det_s = r.log_det_s;
  u.r_scale = r.r_scale;
  u.accepted = r.accepted;
  u.guarded = r.guarded;
  u.innovation.fill(std::numeric_limits<double>::quiet_NaN());
  u.innovation_sigma.fill(std::numeric_limits<double>::quiet_NaN());
  for (int i = 0; i < M && i < 3; ++i) {
    u.innovation[static_cast<std::size_t>(i)] = r.innovation(i);
    u.innovation_sigma[static_cast<std::size_t>(i)] = r.innovation_sigma(i);
  }
  if (!heading_known_ && initialised_) decouple_yaw();
  if (!r.accepted) ++counters_.updates_rejected;
  if (r.guarded) ++counters_.updates_guarded;
  if (r.attitude_refused) ++counters_.updates_attitude_refused;
  last_update_ = u;
  if (log_) log_->push_back(u);
}

template <int NB, int NC, int NT>
template <int M, int K>
UpdateResult<M> InsFilter<NB, NC, NT>::apply(const Measurement<M, K>& m, int dof, int robust_kind) {
  const auto r = core_.update(m.y, m.H, m.R, gate(dof), attitude_limit());
  if (robust_kind <= 0 || cfg_.robust_after_rejections <= 0) return r;
  int& in_row = rejections_in_row_[static_cast<std::size_t>(robust_kind)];
  const bool beyond_gate = !r.accepted && !r.guarded && !r.attitude_refused;
  if (!beyond_gate) {
    if (r.accepted) in_row = 0;
    return r;
  }
  if (++in_row <= cfg_.robust_after_rejections) return r;
  // A run of rejections says the filter, not this measurement, is off: use it with R
  // scaled so that its NIS would sit at the gate were the prediction exact.
  const double scale = r.nis / gate(dof);
  auto used = core_.update(m.y, m.H, (m.R * scale).eval(), 0.0, attitude_limit());
  used.nis = r.nis;  // the measurement's consistency, as the unscaled model saw it
  used.log_det_s = r.log_det_s;
  used.r_scale = scale;
  if (used.accepted) ++counters_.updates_downweighted;
  return used;
}

template <int NB, int NC, int NT>
void InsFilter<NB, NC, NT>::process_fix(const FixInput& fix) {
  if (cfg_.fix_max_dop > 0.0 && (fix.hdop > cfg_.fix_max_dop || (fix.mode == 2 && fix.vdop > cfg_.fix_max_dop))) {
    // A 3D fix 300 m off at HDOP 99.9 passed the gate on the simulated motorway and pulled
    // the filter onto the 2D fixes 200 m off that followed. Its velocity is no better: it
    // sets no heading and no speed, and it is no previous fix to difference with.
    ++counters_.fixes_dop_masked;
    return;
  }
  const Geodetic llh = ecef_to_geodetic(fix.r_ecef_m);
  if (!(llh.height_m >= cfg_.fix_min_height_m && llh.height_m <= cfg_.fix_max_height_m)) {
    // Off the Earth: no gate or reset may take it (30 fixes 1e7 m off outlasted the reset's
    // timeout and the filter was reset onto them).
    ++counters_.fixes_implausible;
    return;
  }
  const Mat3 c_en = rot_ned_to_ecef(llh.lat_rad, llh.lon_rad);

  // Heading from the course over ground once moving, if not configured: at
  // heading_min_speed_mps from any course, below it from a measured velocity
  // whose course is accurate enough (sigma_v / speed), as a walk's must be.
  if (!heading_known_ && !coasting_) {
    Vec3 v = fix.v_ecef_mps;
    double sigma_v_mps = std::numeric_limits<double>::infinity();  // per horizontal axis
    if (v.allFinite())
      sigma_v_mps = fix_speed_sigma(fix);
    else if (have_prev_fix_ && fix.t_s - prev_fix_.t_s > 0.0 && fix.t_s - prev_fix_.t_s <= 2.0)
      v = (fix.r_ecef_m - prev_fix_.r_ecef_m) / (fix.t_s - prev_fix_.t_s);
    const Vec3 v_ned = c_en.transpose() * v;
    const double speed = std::hypot(v_ned.x(), v_ned.y());
    const double course_sigma_rad = speed > 0.0 ? sigma_v_mps / speed : std::numeric_limits<double>::infinity();
    const bool accurate = cfg_.heading_max_course_sigma_rad > 0.0 && course_sigma_rad <= cfg_.heading_max_course_sigma_rad;
    if (v.allFinite() && (speed >= cfg_.heading_min_speed_mps || accurate))
      set_heading(fix, v, std::atan2(v_ned.y(), v_ned.x()),
                  std::isfinite(course_sigma_rad) ? std::max(cfg_.heading_sigma_rad, course_sigma_rad) : cfg_.heading_sigma_rad);
  }
  if (fix.v_ecef_mps.allFinite()) {
    const Vec3 v_ned = c_en.transpose() * fix.v_ecef_mps;
    gnss_speed_mps_ = std::hypot(v_ned.x(), v_ned.y());
    gnss_speed_t_ = fix.t_s;
    gnss_speed_sigma_mps_ = fix_speed_sigma(fix);
  }
  // Only a 3D fix may take over the position: a 2D fix's height is the receiver's
  // assumption, and its horizontal position is off with it (on the roller coaster's
  // 3-satellite stretches 70-100 m at HDOP 4-9, rightly rejected; resetting onto one
  // made the good fixes after it look like outliers).
  const bool reset_due = rejecting_ && fix.mode == 2 && cfg_.gnss_reset_timeout_s > 0.0 &&
                         fix.t_s - rejected_since_ >= cfg_.gnss_reset_timeout_s &&
                         fix.hdop <= cfg_.gnss_reset_max_dop && fix.vdop <= cfg_.gnss_reset_max_dop;
  if constexpr (Core::kHasClock) {  // tight: the receiver's fixes only start the filter, give the heading, reset it
    if (reset_due) reset_to_fix(fix);
    prev_fix_ = fix;
    have_prev_fix_ = true;
    return;
  }

  Mat3 r_cov;
  if ((cfg_.fix_sigma_ecef_m.array() > 0.0).all()) {
    r_cov = square(cfg_.fix_sigma_ecef_m).asDiagonal();
  } else {
    const double uere = fix.mode == 3 && cfg_.fix_uere_2d_m > 0.0 ? cfg_.fix_uere_2d_m : cfg_.fix_uere_m;
    const double sh = uere * std::max(fix.hdop, cfg_.fix_min_dop) / std::sqrt(2.0),
                 sv = uere * std::max(fix.vdop, cfg_.fix_min_dop);
    const Vec3 s = stated_or(fix.sigma_ned_m, Vec3(sh, sh, sv));
    r_cov = c_en * square(s).asDiagonal() * c_en.transpose();
  }
  r_cov += fast_fix_error_cov(fix, c_en);
  auto m = position_fix(core_, fix.r_ecef_m, r_cov, cfg_.lever_arm_body_m, fix_error_map(fix));
  // Until the heading is known the motion the offset's column stands for is not (the first seconds,
  // a gap restart's coast): the prediction is moved, but the offset is not learnt from it.
  if constexpr (NT == 1) add_time_offset(m, core_, es::pos, antenna_velocity_now(), heading_known_);
  bool accepted;
  if (fix.mode == 3) {
    const Eigen::Matrix<double, 2, 3> ne = c_en.transpose().template topRows<2>();
    const auto m2 = project(m, ne);
    const auto r = apply(m2, 2);
    record(kFix2D, r, 2);
    accepted = r.accepted;
  } else {
    const auto r = apply(m, 3, kFix3D);
    record(kFix3D, r, 3);
    // One used down-weighted still failed the gate: it counts as rejected, and a run of them
    // (a jump the receiver is right about) still leads to the reset.
    accepted = r.accepted && !(r.r_scale > 1.0);
  }
  ++(accepted ? counters_.fixes_accepted : counters_.fixes_rejected);
  note_gnss(accepted, fix.t_s);
  if (reset_due && !accepted) {
    reset_to_fix(fix);
    prev_fix_ = fix;
    have_prev_fix_ = true;
    return;
  }
  prev_fix_ = fix;
  have_prev_fix_ = true;

  if (cfg_.use_fix_velocity && fix.v_ecef_mps.allFinite() && heading_known_) {
    const Vec3 sv = stated_or(fix.sigma_v_ned_mps, Vec3::Constant(fix_velocity_sigma(fix)));
    const Mat3 r_v = c_en * square(sv).asDiagonal() * c_en.transpose();
    const Vec3 rate = gyro_rate_now();
    // A lagged velocity, moved to now by what the navigation's velocity did since.
    const Vec3 v_meas = cfg_.fix_velocity_lag_s > 0.0
                            ? Vec3(fix.v_ecef_mps + velocity_change_since(fix.t_s - cfg_.fix_velocity_lag_s))
                            : fix.v_ecef_mps;
    auto mv = gnss_velocity(core_, v_meas, r_v, cfg_.lever_arm_body_m, rate);
    if constexpr (NT == 1) add_time_offset(mv, core_, es::vel, antenna_acceleration_now());
    record(kFixVelocity, apply(mv, 3, kFixVelocity), 3);
  }
}

template <int NB, int NC, int NT>
Vec3 InsFilter<NB, NC, NT>::antenna_velocity_now() const {
  return antenna_velocity(core_, cfg_.lever_arm_body_m, gyro_rate_now());
}

// NT == 1: what a GNSS velocity's or range rate's time offset column needs.
template <int NB, int NC, int NT>
Vec3 InsFilter<NB, NC, NT>::antenna_acceleration_now() const {
  return antenna_acceleration(accel_ecef_, core_.nav.q_eb.toRotationMatrix(), body_rate_wrt_earth(core_, gyro_rate_now()),
                              cfg_.lever_arm_body_m);
}

template <int NB, int NC, int NT>
double InsFilter<NB, NC, NT>::fix_speed_sigma(const FixInput& fix) const {
  const Vec3 sv = stated_or(fix.sigma_v_ned_mps, Vec3::Constant(fix_velocity_sigma(fix)));
  return std::max(sv.x(), sv.y());
}

// The variance the fix's fast correlated part adds to its update (ECEF; see
// fix_error_fast_sigma_m): sigma^2 (1 + a) / (1 - a), a = exp(-dt / tau), dt since the
// previous fix (none before: a = 0), per axis times its DOP when DOP-scaled.
template <int NB, int NC, int NT>
Mat3 InsFilter<NB, NC, NT>::fast_fix_error_cov(const FixInput& fix, const Mat3& c_en) const {
  if (!(cfg_.fix_error_fast_sigma_m.array() > 0.0).any()) return Mat3::Zero();
  Vec3 s = cfg_.fix_error_fast_sigma_m;
  if (cfg_.fix_error_gm_dop_scaled) s = s.cwiseProduct(fix_error_dops(fix));
  double factor = 1.0;
  const double dt = fix.t_s - prev_fix_.t_s;
  if (have_prev_fix_ && dt > 0.0 && cfg_.fix_error_fast_tau_s > 0.0) {
    const double one_minus_a = -std::expm1(-dt / cfg_.fix_error_fast_tau_s);  // accurate for dt << tau
    factor = (2.0 - one_minus_a) / one_minus_a;
  }
  return c_en * (square(s) * factor).asDiagonal() * c_en.transpose();
}

// The DOP per local axis (north, east, down) that scales a fix's correlated errors.
// A 2D fix's vertical row is projected out by its update, so its VDOP does not matter.
template <int NB, int NC, int NT>
Vec3 InsFilter<NB, NC, NT>::fix_error_dops(const FixInput& fix) {
  const double h = fix.hdop / std::sqrt(2.0);
  return Vec3(h, h, fix.mode == 3 ? 1.0 : fix.vdop);
}

// How the fix-error states reach this fix (metres per state unit, ECEF): identity,
// or its DOP per local axis (fix_error_gm_dop_scaled).
template <int NB, int NC, int NT>
Mat3 InsFilter<NB, NC, NT>::fix_error_map(const FixInput& fix) const {
  if (!cfg_.fix_error_gm_dop_scaled) return Mat3::Identity();
  const Geodetic llh = ecef_to_geodetic(fix.r_ecef_m);
  const Mat3 c_en = rot_ned_to_ecef(llh.lat_rad, llh.lon_rad);
  return c_en * fix_error_dops(fix).asDiagonal() * c_en.transpose();
}

template <int NB, int NC, int NT>
void InsFilter<NB, NC, NT>::detect_standstill(const Increment& inc) {
  const bool fresh = detector_.add(inc.dv_mps / inc.dt_s, inc.dtheta_rad / inc.dt_s, inc.dt_s);
  if (!initialised_ || !cfg_.zero_velocity_updates) {
    standstill_ = false;
    standstill_blocks_ = 0;
    return;
  }
  if (!fresh) {
    if (standstill_) ++counters_.standstill_samples;
    return;
  }
  const Vec3 rate = (detector_.mean_w() - core_.imu.gyro_bias_rad_per_s).cwiseQuotient(Vec3::Ones() + core_.imu.gyro_scale_factor);
  const Vec3 earth_b = core_.nav.q_eb.conjugate() * earth_rate_ecef();
  // The filter's speed may start a standstill (no zero-velocity update has pinned
  // it yet); a recent GNSS speed above its limit bars or ends one.
  // A recent GNSS speed below it, while the IMU is quiet, may also start one
  // (the filter's velocity after a stop can be off by more than its limit), if
  // that velocity is accurate enough to tell rest (a 2D fix at HDOP 20 once read
  // 0.3 m/s on a walk at 0.8 m/s, which looks like rest to the IMU).
  // A refused zero-velocity update is motion the detector missed (pulling away
  // smoothly): no standstill for the hold-off after it.
  const bool gnss_fresh = t_last_ - gnss_speed_t_ <= 1.5;
  // Once it has moved, the filter's speed counts as slow only with its sigma: on a
  // smooth slow walk its velocity drifted to 0.2 m/s (sigma 0.34) at a true
  // 0.75 m/s, and the IMU, with no vibration, looked at rest. Before that its
  // velocity is the levelling's at-rest assumption, and its sigma the initial one.
  const bool gnss_moving = gnss_fresh && gnss_speed_mps_ > cfg_.standstill_max_gnss_speed_mps;
  const double speed_mps = core_.nav.v_ecef_mps.norm();
  if (speed_mps >= cfg_.standstill_max_speed_mps || gnss_moving) moved_ = true;
  const double v_sigma_mps = std::sqrt(core_.P.template block<3, 3>(es::vel, es::vel).trace());
  const bool slow_for_sure = speed_mps + (moved_ ? v_sigma_mps : 0.0) < cfg_.standstill_max_speed_mps;
  const bool zupt_refused = t_last_ - zupt_refused_t_ < cfg_.standstill_holdoff_s;
  const bool veto = gnss_moving || zupt_refused;
  // The detector reads may_begin only when nothing vetoes and it is not standing already: only
  // then is the force test (a 3x3 solve every sample otherwise) worth doing.
  const bool may_begin = !veto && !detector_.standing() &&
                         (slow_for_sure ||
                          (gnss_fresh && gnss_speed_sigma_mps_ <= cfg_.standstill_max_gnss_speed_mps)) &&
                         force_at_rest(core_, detector_, cfg_);
  standstill_ = detector_.decide(rate - earth_b, may_begin, veto, t_last_);
  if (!standstill_) {
    standstill_blocks_ = 0;
    return;
  }
  ++counters_.standstill_samples;
  ++standstill_blocks_;
  // Zero velocity at every block; zero rate once per window of new blocks (its
  // mean's noise is independent between windows), with the noise measured from
  // the spread of the block means (vibration included), at least the ARW's.
  const auto m = zero_velocity(core_, cfg_.zero_velocity_sigma_mps);
  const auto r = apply(m, 3);
  record(kZeroVelocity, r, 3);
  ++counters_.zero_velocity_updates;
  if (!r.accepted) {
    zupt_refused_t_ = t_last_;
    return;
  }
  if (standstill_blocks_ % detector_.window_blocks() == 0) {
    const Vec3 var = detector_.mean_rate_variance().cwiseMax(square(cfg_.gyro_arw_rad_per_sqrt_s) / detector_.window_duration_s()) +
                     Vec3::Constant(cfg_.zero_rate_sigma_rad_per_s * cfg_.zero_rate_sigma_rad_per_s);
    auto mz = zero_rate(core_, rate, var);
    // Without a heading the attitude coupling (Earth rate seen through a wrong
    // yaw) is far outside the linear range: use the update for the biases only.
    if (!heading_known_) mz.H.template middleCols<3>(es::att).setZero();
    record(kZeroRate, apply(mz, 3), 3);
    ++counters_.zero_rate_updates;
  }
}

#ifndef GPSINS_INS_FILTER_TIME_OFFSET
template class InsFilter<5, 0>;
template class InsFilter<7, 0>;
template class InsFilter<5, kTightAugmented>;
template class InsFilter<7, kTightAugmented>;
template class InsFilter<5, 3>;
template class InsFilter<7, 3>;
#else
template class InsFilter<5, 0, 1>;
template class InsFilter<7, 0, 1>;
template class InsFilter<5, kTightAugmented, 1>;
template class InsFilter<7, kTightAugmented, 1>;
template class InsFilter<5, 3, 1>;
template class InsFilter<7, 3, 1>;
#endif

}  // namespace gpsins

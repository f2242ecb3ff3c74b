// InsFilter's inputs: construction from the configuration, the push_* calls
// (checked, then used at once or queued until the IMU reaches their time), and
// the IMU's own timing (nominal step, gaps bridged, samples beyond the range).
#include <algorithm>
#include <cmath>
#include <limits>

#include "gpsins/chi2.hpp"
#include "internal.hpp"

namespace gpsins {

using filter_detail::square;

namespace {

// A span over this many nominal steps is lost frames, bridged with the previous rates.
constexpr double kLostFramesSteps = 1.5;
// A sample this far beyond the sensor's range (its largest rate or specific force over the
// range) is rejected and replaced like a lost frame.
constexpr double kOverRange = 1.05;

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
      case BiasModel::GaussMarkov:  // driving noise 2 sigma^2 / T (the ESKF notes)
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

}  // namespace

template <int NB, int NC, int NT>
InsFilter<NB, NC, NT>::InsFilter(const InsConfig& cfg) : cfg_(cfg), detector_(thresholds_of(cfg)) {
  core_.noise = noise_of(cfg);
  core_.covariance_interval_s = cfg.covariance_interval_s;
  dt_nominal_ = cfg.imu_rate_hz > 0.0 ? 1.0 / cfg.imu_rate_hz : 1.0 / kDefaultImuRateHz;
  const bool chi2 = cfg.update_check == UpdateCheck::ChiSquare || cfg.update_check == UpdateCheck::Both;
  const bool gating = chi2 && cfg.gate_probability > 0.0 && cfg.gate_probability < 1.0;
  for (int d = 1; d < static_cast<int>(gates_.size()); ++d)
    gates_[static_cast<std::size_t>(d)] = gating ? chi2_quantile(cfg.gate_probability, d) : 0.0;
  Euler v;
  v.yaw_rad = cfg.body_to_vehicle_ypr_rad.x();
  v.pitch_rad = cfg.body_to_vehicle_ypr_rad.y();
  v.roll_rad = cfg.body_to_vehicle_ypr_rad.z();
  c_vb_ = dcm_from_euler(v);
  pr_used_t_.fill(std::numeric_limits<double>::quiet_NaN());
}

template <int NB, int NC, int NT>
InputStatus InsFilter<NB, NC, NT>::push_fix(const FixInput& given) {
  FixInput fix = given;
  if (!std::isfinite(fix.t_s)) return InputStatus::NonFinite;
  const bool solution = fix.mode == kFixMode3D || fix.mode == kFixMode2D;
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
  if (have_time() && fix.t_s <= t_last_) {
    // Already past it: use it now (its latency is below one IMU interval when
    // measurements arrive in order).
    ++counters_.fixes_late;
    if (initialised())
      process_fix(fix);
    else
      ++counters_.fixes_before_alignment;
    return InputStatus::Ok;
  }
  if (pending_.full()) {  // keep the newest; the oldest is used now
    const FixInput oldest = pending_.pop_front();
    if (have_time() && oldest.t_s - t_last_ > cfg_.max_gap_s) {
      // The IMU has stopped for longer than a gap is bridged: used now, on a state that has not
      // moved, it would be rejected (and a run of them reset the filter onto a stale state); the
      // restart after the gap coasts through the newest queued ones.
      ++counters_.fixes_in_imu_gap;
    } else {
      ++counters_.fixes_late;
      if (initialised())
        process_fix(oldest);
      else
        ++counters_.fixes_before_alignment;
    }
  }
  pending_.push_back(fix);
  return InputStatus::Ok;
}

template <int NB, int NC, int NT>
InputStatus InsFilter<NB, NC, NT>::push_imu(double t_s, const Vec3& dtheta_rad, const Vec3& dv_mps) {
  if (!std::isfinite(t_s) || !dtheta_rad.allFinite() || !dv_mps.allFinite()) return InputStatus::NonFinite;
  if (have_time() && !(t_s > t_last_)) return InputStatus::TimeNotIncreasing;
  double span = have_time() ? t_s - t_last_ : dt_nominal_;
  double cover = 1.0;  // the share of this sample's increments its step stands for
  ++counters_.imu_samples;
  if (!have_time()) {
    advance(PhaseEvent::FirstImuSample);
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
  const bool gap = !cfg_.imu_increments_cover_gaps && span > kLostFramesSteps * dt_nominal_;
  const double dt = gap ? dt_nominal_ : span;
  const Vec3 dtheta_s = dtheta_rad * cover, dv_s = dv_mps * cover;
  const double over = out_of_range(dtheta_s, dv_s, dt);
  const bool bad = over > kOverRange;
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
    const bool was_levelling = phase_ == Phase::Levelling;
    propagate_to(inc);
    if (was_levelling && phase_ == Phase::Levelling) {
      level_f_sum_ += inc.dv_mps;
      level_time_ += inc.dt_s;
    }
    last_inc_ = inc;
    detect_standstill(inc);
  }
  t_last_ = t_s;
  while (!pending_att_.empty() && pending_att_.front().t_s <= t_last_) {
    const AttitudeInput a = pending_att_.pop_front();
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
  if (have_time() && a.t_s <= t_last_) {
    process_attitude(a, last_inc_);
    return InputStatus::Ok;
  }
  if (pending_att_.full()) pending_att_.pop_front();  // keep the newest
  pending_att_.push_back(a);
  return InputStatus::Ok;
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
    if (have_time() && e.t_s <= t_last_) {
      if (initialised()) process_pseudoranges(e);
      return InputStatus::Ok;
    }
    if (pending_pr_.full()) {
      const PseudorangeEpoch oldest = pending_pr_.pop_front();
      if (initialised()) process_pseudoranges(oldest);
    }
    pending_pr_.push_back(e);
    return InputStatus::Ok;
  }
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

#define GPSINS_INSTANTIATE(NB, NC, NT)                                                    \
  template InsFilter<NB, NC, NT>::InsFilter(const InsConfig&);                            \
  template InputStatus InsFilter<NB, NC, NT>::push_fix(const FixInput&);                  \
  template InputStatus InsFilter<NB, NC, NT>::push_imu(double, const Vec3&, const Vec3&); \
  template InputStatus InsFilter<NB, NC, NT>::push_attitude(const AttitudeInput&);        \
  template InputStatus InsFilter<NB, NC, NT>::push_pseudoranges(const PseudorangeEpoch&); \
  template void InsFilter<NB, NC, NT>::track_step(double);                                \
  template double InsFilter<NB, NC, NT>::out_of_range(const Vec3&, const Vec3&, double) const;
GPSINS_FOR_EACH_FILTER(GPSINS_INSTANTIATE)
#undef GPSINS_INSTANTIATE

}  // namespace gpsins

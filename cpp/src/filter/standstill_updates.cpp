// InsFilter's standstill: the detector's decision with what the filter and
// GNSS know of the motion, and the zero-velocity and zero-rate updates while
// standing.
#include <algorithm>
#include <cmath>

#include <Eigen/Cholesky>

#include "gpsins/aiding/zero_rate.hpp"
#include "gpsins/chi2.hpp"
#include "gpsins/aiding/zero_velocity.hpp"
#include "internal.hpp"

namespace gpsins {

using filter_detail::square;

namespace {

// The at-rest test's bound on the squared Mahalanobis distance: chi-square, 3 dof (the
// specific force's axes), at this probability. (Written as 16.27 until it was derived here:
// chi2_quantile(0.999, 3) = 16.266.)
constexpr double kAtRestProbability = 0.999;
constexpr int kAtRestDof = 3;
// The window's duration the mean's noise is taken over is at least this (s).
constexpr double kMinWindow_s = 1e-3;
// A GNSS speed this recent (s) counts in the standstill decision.
constexpr double kGnssSpeedFresh_s = 1.5;

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
  const double noise = cfg.accel_vrw_mps_per_sqrt_s.squaredNorm() / filter_detail::kAxes /
                       std::max(det.window_duration_s(), kMinWindow_s);
  const Mat3 S = J * Pab * J.transpose() +
                 Mat3::Identity() * (noise + cfg.standstill_accel_shift_mps2 * cfg.standstill_accel_shift_mps2);
  const double d2 = a.dot(S.ldlt().solve(a));
  static const double bound = chi2_quantile(kAtRestProbability, kAtRestDof);
  return std::isfinite(d2) && d2 < bound;
}

}  // namespace

template <int NB, int NC, int NT>
void InsFilter<NB, NC, NT>::detect_standstill(const Increment& inc) {
  const bool fresh = detector_.add(inc.dv_mps / inc.dt_s, inc.dtheta_rad / inc.dt_s, inc.dt_s);
  if (!initialised() || !cfg_.zero_velocity_updates) {
    standstill_ = false;
    standstill_blocks_ = 0;
    return;
  }
  if (!fresh) {
    if (standstill_) ++counters_.standstill_samples;
    return;
  }
  const Vec3 rate =
      (detector_.mean_w() - core_.imu.gyro_bias_rad_per_s).cwiseQuotient(Vec3::Ones() + core_.imu.gyro_scale_factor);
  const Vec3 earth_b = core_.nav.q_eb.conjugate() * earth_rate_ecef();
  // The filter's speed may start a standstill (no zero-velocity update has pinned
  // it yet); a recent GNSS speed above its limit bars or ends one.
  // A recent GNSS speed below it, while the IMU is quiet, may also start one
  // (the filter's velocity after a stop can be off by more than its limit), if
  // that velocity is accurate enough to tell rest (a 2D fix at HDOP 20 once read
  // 0.3 m/s on a walk at 0.8 m/s, which looks like rest to the IMU).
  // A refused zero-velocity update is motion the detector missed (pulling away
  // smoothly): no standstill for the hold-off after it.
  const bool gnss_fresh = t_last_ - gnss_speed_t_ <= kGnssSpeedFresh_s;
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
  const bool may_begin =
      !veto && !detector_.standing() &&
      (slow_for_sure || (gnss_fresh && gnss_speed_sigma_mps_ <= cfg_.standstill_max_gnss_speed_mps)) &&
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
  const auto r = apply(m, 3, 0, true);
  record(kZeroVelocity, r, 3);
  ++counters_.zero_velocity_updates;
  if (!r.accepted) {
    zupt_refused_t_ = t_last_;
    return;
  }
  if (standstill_blocks_ % detector_.window_blocks() == 0) {
    const Vec3 var =
        detector_.mean_rate_variance().cwiseMax(square(cfg_.gyro_arw_rad_per_sqrt_s) / detector_.window_duration_s()) +
        Vec3::Constant(cfg_.zero_rate_sigma_rad_per_s * cfg_.zero_rate_sigma_rad_per_s);
    auto mz = zero_rate(core_, rate, var);
    // Without a heading the attitude coupling (Earth rate seen through a wrong
    // yaw) is far outside the linear range: use the update for the biases only.
    if (!heading_known()) mz.H.template middleCols<3>(es::att).setZero();
    record(kZeroRate, apply(mz, 3, 0, true), 3);
    ++counters_.zero_rate_updates;
  }
}

#define GPSINS_INSTANTIATE(NB, NC, NT) template void InsFilter<NB, NC, NT>::detect_standstill(const Increment&);
GPSINS_FOR_EACH_FILTER(GPSINS_INSTANTIATE)
#undef GPSINS_INSTANTIATE

}  // namespace gpsins

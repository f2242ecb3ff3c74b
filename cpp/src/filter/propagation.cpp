// InsFilter's propagation: calibrated increments, the core's propagation split
// at every queued measurement's time, the velocity steps a lagged fix velocity
// is moved by, the covariance growth while the heading is unknown, and the
// antenna's motion now (what GNSS velocities and time offsets need).
#include <algorithm>
#include <cmath>

#include "gpsins/aiding/time_offset.hpp"
#include "gpsins/aiding/velocity.hpp"
#include "gpsins/strapdown.hpp"
#include "internal.hpp"

namespace gpsins {

using filter_detail::kAxes;

namespace {

// While the heading is unknown the velocity error grows by up to this multiple of the
// horizontal acceleration less what a tilt error explains (inflate_unknown_heading).
constexpr double kUnknownHeadingGrowth = 2.0;
constexpr double kUnknownHeadingGrowthSq = kUnknownHeadingGrowth * kUnknownHeadingGrowth;
constexpr double kTiltExplainedAccel_mps2 = 0.1;  // about half a degree of tilt

}  // namespace

template <int NB, int NC, int NT>
Increment InsFilter<NB, NC, NT>::calibrated(double dt, const Vec3& dtheta, const Vec3& dv) const {
  Increment inc;
  inc.dt_s = dt;
  inc.dtheta_rad =
      (dtheta - cfg_.gyro_bias_cal_rad_per_s * dt).cwiseQuotient(Vec3::Ones() + cfg_.gyro_scale_factor_cal);
  inc.dv_mps = (dv - cfg_.accel_bias_cal_mps2 * dt).cwiseQuotient(Vec3::Ones() + cfg_.accel_scale_factor_cal);
  return inc;
}

// Propagate across `inc`, which starts at t_last_, stopping at every pending
// fix inside it; t_last_ ends at its end.
template <int NB, int NC, int NT>
void InsFilter<NB, NC, NT>::propagate_to(const Increment& inc) {
  Increment rest = inc;
  for (;;) {
    // The earliest held measurement inside this increment, fixes first on a tie.
    const double t_end = t_last_ + rest.dt_s;
    const bool fix_due = !pending_.empty() && pending_.front().t_s <= t_end;
    const bool pr_due = !pending_pr_.empty() && pending_pr_.front().t_s <= t_end;
    if (!fix_due && !pr_due) break;
    const bool take_fix = fix_due && (!pr_due || pending_.front().t_s <= pending_pr_.front().t_s);
    const double t_meas = take_fix ? pending_.front().t_s : pending_pr_.front().t_s;
    const double frac = std::clamp((t_meas - t_last_) / rest.dt_s, 0.0, 1.0);
    Increment first, second;
    split_increment(rest, frac, first, second);
    if (initialised()) {
      propagate_nav(first, t_last_ + first.dt_s);
      core_.flush_covariance();  // what the measurement's processing reads or resets
    }
    t_last_ += first.dt_s;
    if (take_fix) {
      const FixInput fix = pending_.pop_front();
      if (initialised()) {
        process_fix(fix);
      } else if (level_time_ + first.dt_s >= cfg_.level_time_s - 0.5 * dt_nominal_) {
        level_f_sum_ += first.dv_mps;
        level_time_ += first.dt_s;
        initialise(fix);
      } else {
        ++counters_.fixes_before_alignment;
      }
    } else {
      const PseudorangeEpoch ep = pending_pr_.pop_front();
      if (initialised()) process_pseudoranges(ep);
    }
    rest = second;
  }
  t_last_ += rest.dt_s;
  if (!initialised()) return;
  propagate_nav(rest, t_last_);
  if (!heading_known()) {
    core_.flush_covariance();
    if (!standstill_) inflate_unknown_heading(rest);
    decouple_yaw();
  } else if (cfg_.nonholonomic_constraint) {
    constrain_vehicle(rest);
  }
  const double pos_var = core_.P.template block<3, 3>(es::pos, es::pos).trace();
  if (!std::isfinite(pos_var) || pos_var > kAxes * cfg_.max_position_sigma_m * cfg_.max_position_sigma_m ||
      !core_.nav.r_ecef_m.allFinite())
    counters_.diverged = true;
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
  const double a = std::max(0.0, (f - f.dot(u) * u).norm() - kTiltExplainedAccel_mps2);
  const double q = kUnknownHeadingGrowthSq * a * a * inc.dt_s;
  core_.P.template block<3, 3>(es::vel, es::vel) += q * (Mat3::Identity() - u * u.transpose());
}

template <int NB, int NC, int NT>
Vec3 InsFilter<NB, NC, NT>::antenna_velocity_now() const {
  return antenna_velocity(core_, cfg_.lever_arm_body_m, gyro_rate_now());
}

// NT == 1: what a GNSS velocity's or range rate's time offset column needs.
template <int NB, int NC, int NT>
Vec3 InsFilter<NB, NC, NT>::antenna_acceleration_now() const {
  return antenna_acceleration(accel_ecef_, core_.nav.q_eb.toRotationMatrix(),
                              body_rate_wrt_earth(core_, gyro_rate_now()), cfg_.lever_arm_body_m);
}

#define GPSINS_INSTANTIATE(NB, NC, NT)                                                          \
  template Increment InsFilter<NB, NC, NT>::calibrated(double, const Vec3&, const Vec3&) const; \
  template void InsFilter<NB, NC, NT>::propagate_to(const Increment&);                          \
  template void InsFilter<NB, NC, NT>::propagate_nav(const Increment&, double);                 \
  template Vec3 InsFilter<NB, NC, NT>::velocity_change_since(double) const;                     \
  template void InsFilter<NB, NC, NT>::inflate_unknown_heading(const Increment&);               \
  template Vec3 InsFilter<NB, NC, NT>::antenna_velocity_now() const;                            \
  template Vec3 InsFilter<NB, NC, NT>::antenna_acceleration_now() const;
GPSINS_FOR_EACH_FILTER(GPSINS_INSTANTIATE)
#undef GPSINS_INSTANTIATE

}  // namespace gpsins

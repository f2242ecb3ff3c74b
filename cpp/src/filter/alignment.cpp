// InsFilter's alignment: levelling from the mean specific force, the
// initialisation at the first fix after it, the yaw kept decoupled while the
// heading is unknown, and the first heading from the course over ground.
#include <cmath>
#include <limits>

#include "internal.hpp"

namespace gpsins {

using filter_detail::square;

namespace {

Euler levelled(const Vec3& f_mean) {
  Euler e;  // at rest f = -g in body axes (forward-right-down)
  e.roll_rad = std::atan2(-f_mean.y(), -f_mean.z());
  e.pitch_rad = std::atan2(f_mean.x(), std::hypot(f_mean.y(), f_mean.z()));
  return e;
}

}  // namespace

template <int NB, int NC, int NT>
void InsFilter<NB, NC, NT>::initialise(const FixInput& fix) {
  const Vec3 f_mean = level_f_sum_ / level_time_;
  Euler e = levelled(f_mean);
  e.yaw_rad = heading_known() ? cfg_.initial_yaw_rad : 0.0;  // while levelling: configured
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
  if (!heading_known()) att.z() = M_PI;
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
    sis_slots_.free_all();
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
  advance(PhaseEvent::Initialised);
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
  advance(PhaseEvent::HeadingMeasured);
}

#define GPSINS_INSTANTIATE(NB, NC, NT)                              \
  template void InsFilter<NB, NC, NT>::initialise(const FixInput&); \
  template void InsFilter<NB, NC, NT>::decouple_yaw();              \
  template void InsFilter<NB, NC, NT>::set_heading(const FixInput&, const Vec3&, double, double);
GPSINS_FOR_EACH_FILTER(GPSINS_INSTANTIATE)
#undef GPSINS_INSTANTIATE

}  // namespace gpsins

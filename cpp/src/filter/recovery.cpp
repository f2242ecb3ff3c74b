// InsFilter's recovery from sustained GNSS rejection: its tracking, and the reset
// onto a fix it leads to (gap_restart.cpp: the restart after an IMU gap).
#include <algorithm>
#include <cmath>

#include "internal.hpp"

namespace gpsins {

using filter_detail::kMaxFixDifferenceSpan_s;
using filter_detail::square;

namespace {

// The velocity variance added when neither the fix nor its difference with the previous one
// gives a velocity ((10 m/s)^2, on top of the initial spread and the speed itself).
constexpr double kUnknownVelocityVar_m2ps2 = 100.0;

}  // namespace

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
  } else if (fix.t_s - prev_fix_.t_s > 0.0 && fix.t_s - prev_fix_.t_s <= kMaxFixDifferenceSpan_s) {
    core_.nav.v_ecef_mps = (fix.r_ecef_m - prev_fix_.r_ecef_m) / (fix.t_s - prev_fix_.t_s);
    const double dt = fix.t_s - prev_fix_.t_s, s = cfg_.fix_uere_m * fix.hdop;
    var_v += 2.0 * s * s / (dt * dt);
  } else {
    var_v += core_.nav.v_ecef_mps.squaredNorm() + kUnknownVelocityVar_m2ps2;
  }
  // The nominal stands for the fix's time plus the IMU time offset.
  if constexpr (NT == 1) core_.nav.r_ecef_m += core_.nav.v_ecef_mps * core_.time_offset_s;
  const Geodetic llh = ecef_to_geodetic(core_.nav.r_ecef_m);
  const Mat3 c_bn = core_.nav.q_eb.toRotationMatrix().transpose() * rot_ned_to_ecef(llh.lat_rad, llh.lon_rad);
  const Mat3 att_ned = c_bn.transpose() * P.template block<3, 3>(es::att, es::att) * c_bn;
  const Vec3 att_var =
      att_ned.diagonal() + square(Vec3(cfg_.attitude_sigma_rad.x(), cfg_.attitude_sigma_rad.y(),
                                       heading_known() ? cfg_.heading_sigma_rad : cfg_.attitude_sigma_rad.z()));
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

#define GPSINS_INSTANTIATE(NB, NC, NT)                          \
  template void InsFilter<NB, NC, NT>::note_gnss(bool, double); \
  template void InsFilter<NB, NC, NT>::reset_to_fix(const FixInput&);
GPSINS_FOR_EACH_FILTER(GPSINS_INSTANTIATE)
#undef GPSINS_INSTANTIATE

}  // namespace gpsins

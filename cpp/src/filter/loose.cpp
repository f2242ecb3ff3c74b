// InsFilter's loose coupling: a receiver fix's position (3D, or 2D horizontal)
// and velocity updates, its noise (stated or from the DOP, the fast correlated
// part, the fix-error states' map), and the heading and GNSS speed it gives.
#include <algorithm>
#include <cmath>
#include <limits>

#include "gpsins/aiding/measurement.hpp"
#include "gpsins/aiding/position_fix.hpp"
#include "gpsins/aiding/time_offset.hpp"
#include "gpsins/aiding/velocity.hpp"
#include "internal.hpp"

namespace gpsins {

using filter_detail::kMaxFixDifferenceSpan_s;
using filter_detail::square;

namespace {

// Per axis: the stated sigma when it is one (finite, > 0), else the fallback.
Vec3 stated_or(const Vec3& stated, const Vec3& fallback) {
  Vec3 s = fallback;
  for (int i = 0; i < 3; ++i)
    if (std::isfinite(stated(i)) && stated(i) > 0.0) s(i) = stated(i);
  return s;
}

}  // namespace

template <int NB, int NC, int NT>
void InsFilter<NB, NC, NT>::process_fix(const FixInput& fix) {
  if (cfg_.fix_max_dop > 0.0 &&
      (fix.hdop > cfg_.fix_max_dop || (fix.mode == kFixMode3D && fix.vdop > cfg_.fix_max_dop))) {
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
  if (phase_ == Phase::HeadingUnknown) {
    Vec3 v = fix.v_ecef_mps;
    double sigma_v_mps = std::numeric_limits<double>::infinity();  // per horizontal axis
    if (v.allFinite())
      sigma_v_mps = fix_speed_sigma(fix);
    else if (fix.t_s - prev_fix_.t_s > 0.0 && fix.t_s - prev_fix_.t_s <= kMaxFixDifferenceSpan_s)
      v = (fix.r_ecef_m - prev_fix_.r_ecef_m) / (fix.t_s - prev_fix_.t_s);
    const Vec3 v_ned = c_en.transpose() * v;
    const double speed = std::hypot(v_ned.x(), v_ned.y());
    const double course_sigma_rad = speed > 0.0 ? sigma_v_mps / speed : std::numeric_limits<double>::infinity();
    const bool accurate =
        cfg_.heading_max_course_sigma_rad > 0.0 && course_sigma_rad <= cfg_.heading_max_course_sigma_rad;
    if (v.allFinite() && (speed >= cfg_.heading_min_speed_mps || accurate))
      set_heading(fix, v, std::atan2(v_ned.y(), v_ned.x()),
                  std::isfinite(course_sigma_rad) ? std::max(cfg_.heading_sigma_rad, course_sigma_rad)
                                                  : cfg_.heading_sigma_rad);
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
  const bool reset_due = rejecting_ && fix.mode == kFixMode3D && cfg_.gnss_reset_timeout_s > 0.0 &&
                         fix.t_s - rejected_since_ >= cfg_.gnss_reset_timeout_s &&
                         fix.hdop <= cfg_.gnss_reset_max_dop && fix.vdop <= cfg_.gnss_reset_max_dop;
  if constexpr (Core::kHasClock) {  // tight: the receiver's fixes only start the filter, give the heading, reset it
    if (reset_due) reset_to_fix(fix);
    prev_fix_ = fix;
    return;
  }

  Mat3 r_cov;
  if ((cfg_.fix_sigma_ecef_m.array() > 0.0).all()) {
    r_cov = square(cfg_.fix_sigma_ecef_m).asDiagonal();
  } else {
    const double uere = fix.mode == kFixMode2D && cfg_.fix_uere_2d_m > 0.0 ? cfg_.fix_uere_2d_m : cfg_.fix_uere_m;
    const double sh = uere * std::max(fix.hdop, cfg_.fix_min_dop) / std::sqrt(2.0),
                 sv = uere * std::max(fix.vdop, cfg_.fix_min_dop);
    const Vec3 s = stated_or(fix.sigma_ned_m, Vec3(sh, sh, sv));
    r_cov = c_en * square(s).asDiagonal() * c_en.transpose();
  }
  r_cov += fast_fix_error_cov(fix, c_en);
  auto m = position_fix(core_, fix.r_ecef_m, r_cov, cfg_.lever_arm_body_m, fix_error_map(fix));
  // Until the heading is known the motion the offset's column stands for is not (the first seconds,
  // a gap restart's coast): the prediction is moved, but the offset is not learnt from it.
  if constexpr (NT == 1) add_time_offset(m, core_, es::pos, antenna_velocity_now(), heading_known());
  bool accepted;
  if (fix.mode == kFixMode2D) {
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
    return;
  }
  prev_fix_ = fix;

  if (cfg_.use_fix_velocity && fix.v_ecef_mps.allFinite() && heading_known()) {
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
  if (dt > 0.0 && cfg_.fix_error_fast_tau_s > 0.0) {
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
  return Vec3(h, h, fix.mode == kFixMode2D ? 1.0 : fix.vdop);
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

#define GPSINS_INSTANTIATE(NB, NC, NT)                                                         \
  template void InsFilter<NB, NC, NT>::process_fix(const FixInput&);                           \
  template double InsFilter<NB, NC, NT>::fix_speed_sigma(const FixInput&) const;               \
  template Mat3 InsFilter<NB, NC, NT>::fast_fix_error_cov(const FixInput&, const Mat3&) const; \
  template Vec3 InsFilter<NB, NC, NT>::fix_error_dops(const FixInput&);                        \
  template Mat3 InsFilter<NB, NC, NT>::fix_error_map(const FixInput&) const;
GPSINS_FOR_EACH_FILTER(GPSINS_INSTANTIATE)
#undef GPSINS_INSTANTIATE

}  // namespace gpsins

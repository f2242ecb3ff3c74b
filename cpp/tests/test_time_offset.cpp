// The IMU time offset state (eskf.hpp, NT = 1): its measurement columns against
// finite differences along a mechanised trajectory, the innovation's sign, and
// its propagation (constant plus random walk, the rest of P untouched).
//
// The nominal at filter time t stands for true time t + dt, so a GNSS
// measurement at true time t sees the trajectory at filter time t - dt: its
// offset column is -dh/dt along the trajectory.
#include <doctest/doctest.h>

#include "gpsins/aiding/position_fix.hpp"
#include "gpsins/aiding/pseudorange.hpp"
#include "gpsins/aiding/time_offset.hpp"
#include "gpsins/aiding/velocity.hpp"
#include "gpsins/eskf.hpp"
#include "gpsins/gnss/models.hpp"

using namespace gpsins;

namespace {
constexpr double kDeg = M_PI / 180.0;
using Core = Eskf<5, 2, 1>;
constexpr int kT = Core::kTimeOffset;

const Vec3 kLever(0.6, -0.3, -1.1);
const Vec3 kRate(0.05, -0.08, 0.3);  // rad/s, body: turning
const Vec3 kForce(1.5, -0.8, -9.6);  // m/s^2, body: accelerating while turning
constexpr double kStep = 0.002;      // s

Core moving_core() {
  Core f;
  const Geodetic site{59.37 * kDeg, 17.95 * kDeg, 30.0};
  f.nav.r_ecef_m = geodetic_to_ecef(site);
  f.nav.v_ecef_mps = rot_ned_to_ecef(site.lat_rad, site.lon_rad) * Vec3(8.0, -6.0, 0.2);
  f.nav.q_eb = quat_body_to_ecef({-37.0 * kDeg, 3.0 * kDeg, -2.0 * kDeg}, site.lat_rad, site.lon_rad);
  f.P = Core::MatN::Identity() * 1e-4;
  return f;
}

Increment step() {
  Increment inc;
  inc.dt_s = kStep;
  inc.dtheta_rad = kRate * kStep;
  inc.dv_mps = kForce * kStep;
  return inc;
}

// The trajectory one step before, at and after t0 (filter time).
struct Trajectory {
  Core before, at, after;
};
Trajectory trajectory() {
  Trajectory t{moving_core(), {}, {}};
  t.at = t.before;
  t.at.propagate(step());
  t.after = t.at;
  t.after.propagate(step());
  return t;
}

Vec3 antenna(const Core& f) { return f.nav.r_ecef_m + f.nav.q_eb * kLever; }
Vec3 antenna_v(const Core& f) { return antenna_velocity(f, kLever, kRate); }
const Vec3 kSat(1.52e7, 0.61e7, 2.05e7);
double range(const Core& f) {
  const Vec3 r_a = antenna(f);
  return (kSat - r_a).norm() + gnss::sagnac_m(kSat, r_a) + f.clock(0);
}
// As the filter takes it: the last step's velocity change.
Vec3 accel(const Trajectory& t) { return (t.at.nav.v_ecef_mps - t.before.nav.v_ecef_mps) / kStep; }
Vec3 antenna_a(const Trajectory& t) {
  return antenna_acceleration(accel(t), t.at.nav.q_eb.toRotationMatrix(), body_rate_wrt_earth(t.at, kRate), kLever);
}

}  // namespace

TEST_CASE("time offset: position fix column is minus the antenna's velocity, as the trajectory moves") {
  const Trajectory t = trajectory();
  auto m = position_fix(t.at, antenna(t.at), Mat3::Identity(), kLever);
  add_time_offset(m, t.at, es::pos, antenna_v(t.at));
  const Vec3 h_dot = (antenna(t.after) - antenna(t.before)) / (2.0 * kStep);
  const Vec3 col = m.H.col(kT);
  CHECK((col + h_dot).norm() < 1e-4 * h_dot.norm());
  CHECK(h_dot.norm() > 9.0);  // the lever arm's turn included: the vehicle's 10 m/s and 0.3 rad/s x 1.2 m
}

TEST_CASE("time offset: fix velocity column is minus the antenna's acceleration") {
  const Trajectory t = trajectory();
  auto m = gnss_velocity(t.at, antenna_v(t.at), Mat3::Identity(), kLever, kRate);
  add_time_offset(m, t.at, es::vel, antenna_a(t));
  const Vec3 h_dot = (antenna_v(t.after) - antenna_v(t.before)) / (2.0 * kStep);
  const Vec3 col = m.H.col(kT);
  // The backward difference the filter uses lags the central one by half a step of jerk.
  CHECK((col + h_dot).norm() < 5e-3 * h_dot.norm());
  CHECK(h_dot.norm() > 1.0);
}

TEST_CASE("time offset: pseudorange column is the line of sight's component of the antenna's velocity") {
  const Trajectory t = trajectory();
  auto m = pseudorange(t.at, kLever, kSat, 0.0, gnss::sagnac_m(kSat, antenna(t.at)), 1.0);
  add_time_offset(m, t.at, es::pos, antenna_v(t.at));
  const double h_dot = (range(t.after) - range(t.before)) / (2.0 * kStep);
  const Vec3 u = (kSat - antenna(t.at)).normalized();
  CHECK(m.H(0, kT) == doctest::Approx(-h_dot).epsilon(1e-4));
  CHECK(m.H(0, kT) == doctest::Approx(u.dot(antenna_v(t.at))).epsilon(1e-6));
  CHECK(std::abs(h_dot) > 1.0);
}

TEST_CASE("time offset: the innovation vanishes when the estimate is the true offset, either sign") {
  // Measured at true time t0: the vehicle the nominal shows at filter time t0 - dt.
  const Trajectory t = trajectory();
  for (const double dt : {kStep, -kStep}) {
    const Core& seen = dt > 0.0 ? t.before : t.after;
    Core f = t.at;
    f.time_offset_s = dt;
    auto m = position_fix(f, antenna(seen), Mat3::Identity(), kLever);
    add_time_offset(m, f, es::pos, antenna_v(f));
    CHECK(m.y.norm() < 1e-3 * antenna_v(f).norm() * kStep);
    // Without the estimate the innovation is the motion over dt.
    f.time_offset_s = 0.0;
    auto m0 = position_fix(f, antenna(seen), Mat3::Identity(), kLever);
    add_time_offset(m0, f, es::pos, antenna_v(f));
    CHECK(m0.y.norm() == doctest::Approx(antenna_v(f).norm() * kStep).epsilon(1e-3));
    auto p = pseudorange(f, kLever, kSat, range(seen) - f.clock(0), gnss::sagnac_m(kSat, antenna(f)), 1.0);
    f.time_offset_s = dt;
    auto p1 = pseudorange(f, kLever, kSat, range(seen) - f.clock(0), gnss::sagnac_m(kSat, antenna(f)), 1.0);
    add_time_offset(p1, f, es::pos, antenna_v(f));
    CHECK(std::abs(p1.y(0)) < 1e-2 * std::abs(p.y(0)));
  }
}

TEST_CASE("time offset: propagated as a constant with its random walk, the other states as without it") {
  Eskf<5, 3> without;
  Eskf<5, 3, 1> with;
  const Core m = moving_core();
  for (auto* nav : {&without.nav, &with.nav}) *nav = m.nav;
  without.noise.fix_error_var_ned = with.noise.fix_error_var_ned = Vec3(1.0, 1.0, 2.0);
  without.noise.fix_error_inv_tau = with.noise.fix_error_inv_tau = 1.0 / 12.0;
  without.noise.accel_white_var = with.noise.accel_white_var = Vec3::Constant(1e-4);
  with.noise.time_offset_var = 1e-8;
  without.P = Eskf<5, 3>::MatN::Identity() * 1e-2;
  with.P.setZero();
  with.P.topLeftCorner<18, 18>() = without.P;
  with.P(18, 18) = 2.5e-3;
  with.P(6, 18) = with.P(18, 6) = 1e-3;  // correlated with the position
  for (int i = 0; i < 50; ++i) {
    without.propagate(step());
    with.propagate(step());
  }
  CHECK((with.P.topLeftCorner<18, 18>() - without.P).cwiseAbs().maxCoeff() < 1e-15);
  CHECK(with.P(18, 18) == doctest::Approx(2.5e-3 + 1e-8 * 50 * kStep).epsilon(1e-12));
  // The correlation moves as the position error does: Phi's position row times the column.
  CHECK(with.P(6, 18) == doctest::Approx(1e-3).epsilon(1e-6));
  CHECK(with.time_offset_s == 0.0);
}

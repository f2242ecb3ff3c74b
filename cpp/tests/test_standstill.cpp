// The standstill detector at several IMU rates, and the filter's recovery
// paths (long IMU gap, sustained GNSS rejection, out-of-range sample) on a
// synthetic vehicle standing at a known place.
#include <doctest/doctest.h>

#include <cmath>
#include <limits>
#include <random>
#include <vector>

#include "gpsins/earth.hpp"
#include "gpsins/ins_filter.hpp"
#include "gpsins/standstill.hpp"

using namespace gpsins;

namespace {
constexpr double kDeg = M_PI / 180.0;
const Vec3 kVrw(78.4e-4, 61.0e-4, 69.7e-4);  // the BP3010's white noise (report Table 5.9)
const Vec3 kArw(8.8e-4, 8.7e-4, 8.1e-4);

struct Run {
  double first_standing_s = -1.0;  // first time it stood
  double standing_fraction = 0.0;  // of the decisions at rest after the first window
  double end_after_s = -1.0;       // latency of the end after the pull-away began
};

// rest for 10 s, then a forward acceleration accel_mps2 for 3 s.
Run rest_then_pull(double rate_hz, double accel_mps2, unsigned seed) {
  StandstillThresholds th;
  th.accel_vrw_mps_per_sqrt_s = kVrw;
  StandstillDetector d(th);
  std::mt19937 rng(seed);
  std::normal_distribution<double> n01;
  const double dt = 1.0 / rate_hz;
  const Vec3 g(0.3, -0.2, -9.81);  // slightly tilted
  Run r;
  int at_rest = 0, standing = 0;
  for (int k = 1; k * dt < 13.0; ++k) {
    const double t = k * dt;
    const bool moving = t > 10.0;
    Vec3 f = g + (moving ? Vec3(accel_mps2, 0.0, 0.0) : Vec3::Zero());
    Vec3 w = Vec3::Zero();
    for (int i = 0; i < 3; ++i) {
      f(i) += kVrw(i) / std::sqrt(dt) * n01(rng);
      w(i) += kArw(i) / std::sqrt(dt) * n01(rng);
    }
    if (!d.add(f, w, dt)) continue;
    const bool s = d.decide(d.mean_w(), true, false, t);
    if (s && r.first_standing_s < 0.0) r.first_standing_s = t;
    if (!moving && t > 1.0) {
      ++at_rest;
      standing += s ? 1 : 0;
    }
    if (moving && !s && r.end_after_s < 0.0) r.end_after_s = t - 10.0;
  }
  r.standing_fraction = static_cast<double>(standing) / at_rest;
  return r;
}
}  // namespace

TEST_CASE("standstill: the same decisions at 50, 64, 200 and 400 Hz") {
  for (double rate : {50.0, 64.0, 200.0, 400.0}) {
    for (unsigned seed = 1; seed <= 5; ++seed) {
      const Run r = rest_then_pull(rate, 0.3, seed);
      INFO("rate " << rate << " seed " << seed);
      CHECK(r.first_standing_s > 0.0);
      CHECK(r.first_standing_s < 0.6);    // one window (0.5 s) and a block
      CHECK(r.standing_fraction == 1.0);  // no missed standstill at rest
      // A smooth 0.3 m/s^2 pull-away (speed 0.15 m/s after 0.5 s) ends it quickly.
      CHECK(r.end_after_s > 0.0);
      CHECK(r.end_after_s < 0.5);
    }
  }
}

TEST_CASE("standstill: does not begin again on the pinned speed while the vehicle accelerates") {
  StandstillThresholds th;
  th.accel_vrw_mps_per_sqrt_s = kVrw;
  StandstillDetector d(th);
  const double dt = 1.0 / 200.0;
  int restarted = 0;
  for (int k = 1; k * dt < 6.0; ++k) {
    const double t = k * dt;
    const double a = t > 2.0 ? std::min(0.4, 0.2 * (t - 2.0)) : 0.0;  // ramp to 0.4 m/s^2
    if (!d.add(Vec3(a, 0.0, -9.81), Vec3::Zero(), dt)) continue;
    const bool was = d.standing();
    // may_begin = true throughout: the filter's speed would still read zero.
    if (d.decide(Vec3::Zero(), true, false, t) && !was && t > 2.5 && t < 4.0) ++restarted;
  }
  CHECK(restarted == 0);
}

namespace {
// A vehicle standing at a known place: 64 Hz increments, 1 Hz fixes.
struct Stand {
  Geodetic site{59.37 * kDeg, 17.95 * kDeg, 30.0};
  Vec3 r = geodetic_to_ecef(site);
  Quat q = quat_body_to_ecef({0.5, 0.0, 0.0}, site.lat_rad, site.lon_rad);
  Vec3 f_body = -(q.conjugate() * normal_gravity_ecef(site));
  Vec3 w_body = q.conjugate() * earth_rate_ecef();
};

FixInput fix_at(double t, const Vec3& r) {
  FixInput x;
  x.t_s = t;
  x.r_ecef_m = r;
  x.v_ecef_mps = Vec3::Zero();
  return x;
}

InsConfig stand_config() {
  InsConfig c;
  c.initial_yaw_rad = 0.5;
  c.gyro_arw_rad_per_sqrt_s = Vec3::Constant(1e-4);
  c.accel_vrw_mps_per_sqrt_s = Vec3::Constant(1e-3);
  c.gyro_range_rad_per_s = 300.0 * kDeg;
  c.accel_range_mps2 = 98.0;
  return c;
}
}  // namespace

TEST_CASE("a long IMU gap restarts the filter instead of failing, and an out-of-range sample is not integrated") {
  const Stand s;
  InsFilter<5, 0> f(stand_config());
  const double dt = 1.0 / 64.0;
  double t = 0.0;
  int next_fix = 1;
  auto step = [&](double until, bool spike = false) {
    while (t < until) {
      t += dt;
      while (next_fix <= t) f.push_fix(fix_at(next_fix++, s.r));
      Vec3 dth = s.w_body * dt;
      if (spike) {
        dth.x() = 1e6;
        spike = false;
      }
      REQUIRE(f.push_imu(t, dth, s.f_body * dt) == InputStatus::Ok);
    }
  };
  step(20.0);
  CHECK(f.nominal_step_s() == doctest::Approx(dt));
  step(20.5, true);
  CHECK(f.counters().imu_samples_rejected == 1);
  CHECK((f.core().nav.r_ecef_m - s.r).norm() < 0.5);
  // 8 s without IMU samples; the fixes go on.
  t += 8.0;
  next_fix = static_cast<int>(t) + 1;
  step(40.0);
  CHECK(f.counters().imu_gap_restarts == 1);
  CHECK(f.counters().imu_samples_rejected == 1);
  CHECK_FALSE(f.counters().diverged);
  CHECK((f.core().nav.r_ecef_m - s.r).norm() < 1.0);
  CHECK(f.core().nav.v_ecef_mps.norm() < 0.1);
}

// 40 s standing; from t = 20 s the fixes sit `offset_m` north with the given DOPs
// (the receiver is right, the INS was carried off, or the receiver is wrong).
InsFilter<5, 0> stand_with_moved_fixes(double offset_m, double dop) {
  const Stand s;
  InsConfig c = stand_config();
  c.gnss_reset_timeout_s = 5.0;
  c.gnss_reset_max_dop = 10.0;
  InsFilter<5, 0> f(c);
  const double dt = 1.0 / 64.0;
  double t = 0.0;
  int next_fix = 1;
  const Vec3 moved = s.r + rot_ned_to_ecef(s.site.lat_rad, s.site.lon_rad) * Vec3(offset_m, 0.0, 0.0);
  while (t < 40.0) {
    t += dt;
    while (next_fix <= t) {
      FixInput x = fix_at(next_fix, next_fix >= 20 ? moved : s.r);
      if (next_fix >= 20) x.hdop = x.vdop = dop;
      f.push_fix(x);
      ++next_fix;
    }
    f.push_imu(t, s.w_body * dt, s.f_body * dt);
  }
  return f;
}

TEST_CASE("sustained GNSS rejection resets position and velocity to GNSS and flags divergence") {
  const Stand s;
  const auto f = stand_with_moved_fixes(400.0, 1.0);
  CHECK(f.counters().gnss_resets == 1);
  CHECK(f.counters().diverged);
  CHECK(f.counters().fixes_rejected >= 5);
  CHECK(f.counters().fixes_rejected <= 7);
  const Vec3 moved = s.r + rot_ned_to_ecef(s.site.lat_rad, s.site.lon_rad) * Vec3(400.0, 0.0, 0.0);
  CHECK((f.core().nav.r_ecef_m - moved).norm() < 1.0);
}

TEST_CASE("no reset onto fixes whose DOP the receiver saturates") {
  // A 4-satellite geometry at DOP 99.9 (the receiver's largest value), 40 km off:
  // every such fix is rejected, and none may take over the position.
  const Stand s;
  const auto f = stand_with_moved_fixes(40e3, 99.9);
  CHECK(f.counters().gnss_resets == 0);
  CHECK(f.counters().fixes_rejected >= 20);
  CHECK((f.core().nav.r_ecef_m - s.r).norm() < 5.0);
}

TEST_CASE("fixes inside a long IMU gap set no heading, and increments covering the gap count for one step") {
  // Driving straight at 10 m/s on yaw 0.5 rad, the body fixed in ECEF: 100 Hz increments
  // that cover their whole step (rates integrated), 5 Hz fixes with velocity, and 2 s of
  // IMU samples missing at 20 s while the fixes go on.
  const Stand s;
  const Vec3 v =
      rot_ned_to_ecef(s.site.lat_rad, s.site.lon_rad) * Vec3(10.0 * std::cos(0.5), 10.0 * std::sin(0.5), 0.0);
  auto r_at = [&](double t) { return Vec3(s.r + v * t); };
  auto f_body = [&](double t) {  // at constant ECEF velocity C f = -gamma + 2 w_ie x v
    return Vec3(s.q.conjugate() * (2.0 * earth_rate_ecef().cross(v) - normal_gravity_ecef(r_at(t))));
  };
  InsConfig c = stand_config();
  c.initial_yaw_rad = std::numeric_limits<double>::quiet_NaN();
  c.imu_rate_hz = 100.0;
  c.imu_increments_cover_gaps = true;
  c.use_fix_velocity = true;
  c.zero_velocity_updates = false;  // a quiet IMU at constant velocity looks like standing
  InsFilter<5, 0, 1> f(c);
  std::vector<FilterEvent> events;
  f.set_event_log(&events);
  const double dt = 0.01;
  double t_prev = 0.0;
  int next_fix = 1;
  auto sample = [&](double t) {
    while (0.2 * next_fix <= t + 1e-9) {
      FixInput x = fix_at(0.2 * next_fix, r_at(0.2 * next_fix));
      x.v_ecef_mps = v;
      f.push_fix(x);
      ++next_fix;
    }
    const double span = t - t_prev;  // what the increments cover
    REQUIRE(f.push_imu(t, s.w_body * span, f_body(t - 0.5 * span) * span) == InputStatus::Ok);
    t_prev = t;
  };
  CHECK(f.phase() == Phase::WaitingForImu);
  sample(dt);
  CHECK(f.phase() == Phase::Levelling);
  for (int k = 2; k <= 2000; ++k) sample(k * dt);
  REQUIRE(f.heading_known());
  CHECK(f.phase() == Phase::Navigating);
  const double offset_var = f.core().P(InsFilter<5, 0, 1>::Core::kTimeOffset, InsFilter<5, 0, 1>::Core::kTimeOffset);
  sample(22.05);  // the first sample after the gap
  CHECK(f.counters().imu_gap_restarts == 1);
  CHECK(f.counters().imu_samples_rejected == 0);
  // Not the course at a fix inside the gap: without the IMU the attitude could not follow a turn to its end.
  CHECK_FALSE(f.heading_known());
  CHECK(f.phase() == Phase::HeadingUnknown);           // through Coasting, over the gap's fixes
  CHECK((f.core().nav.v_ecef_mps - v).norm() < 0.02);  // the 2 s increment over 10 ms: 10 ms of free fall
  // The offset is carried over the coast, its variance too (plus one step of its random walk).
  CHECK(f.core().P(InsFilter<5, 0, 1>::Core::kTimeOffset, InsFilter<5, 0, 1>::Core::kTimeOffset) ==
        doctest::Approx(offset_var).epsilon(1e-3));
  for (int k = 2206; k <= 3000; ++k) sample(k * dt);
  std::vector<double> heading_set;
  for (const auto& e : events)
    if (e.kind == kHeadingSet) heading_set.push_back(e.t_s);
  REQUIRE(heading_set.size() == 2);
  CHECK(heading_set[1] == doctest::Approx(22.2));  // the first fix after the gap
  CHECK(f.heading_known());
  CHECK(f.phase() == Phase::Navigating);
  CHECK(f.counters().imu_samples_rejected == 0);
  CHECK_FALSE(f.counters().diverged);
  CHECK((f.core().nav.r_ecef_m - r_at(30.0)).norm() < 0.5);
  CHECK((f.core().nav.v_ecef_mps - v).norm() < 0.05);
}

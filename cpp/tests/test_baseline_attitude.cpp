// Dual-antenna heading and pitch (aiding/baseline_attitude.hpp): the measured
// angles against the attitude's own Euler angles (a baseline along the body's
// forward axis points where the body's yaw and pitch say), and H against
// central differences of the attitude error injected as the filter injects it.
#include <doctest/doctest.h>

#include "gpsins/aiding/baseline_attitude.hpp"
#include "gpsins/attitude.hpp"
#include "gpsins/earth.hpp"

using namespace gpsins;

namespace {
constexpr double kDeg = M_PI / 180.0;
const Geodetic kSite{59.37 * kDeg, 17.95 * kDeg, 30.0};

Eskf<5, 0> filter_at(const Euler& e) {
  Eskf<5, 0> f;
  f.nav.r_ecef_m = geodetic_to_ecef(kSite);
  f.nav.q_eb = quat_body_to_ecef(e, kSite.lat_rad, kSite.lon_rad);
  return f;
}
}  // namespace

TEST_CASE("baseline along the body's forward axis: its yaw and pitch are the body's") {
  for (const Euler e : {Euler{-37.0 * kDeg, 3.0 * kDeg, -2.0 * kDeg}, Euler{170.0 * kDeg, -25.0 * kDeg, 60.0 * kDeg},
                        Euler{-179.5 * kDeg, 45.0 * kDeg, -81.0 * kDeg}}) {
    const auto f = filter_at(e);
    const auto m = baseline_attitude<2>(f, Vec3(1.0, 0.0, 0.0), e.yaw_rad, e.pitch_rad, 1e-3, 1e-3);
    CHECK(std::abs(m.y(0)) < 1e-12);
    CHECK(std::abs(m.y(1)) < 1e-12);
  }
}

TEST_CASE("baseline attitude: H matches finite differences of the injected attitude error") {
  const Vec3 baseline = Vec3(0.8, -0.5, 0.1).normalized();  // a skewed mounting
  for (const Euler e : {Euler{-37.0 * kDeg, 3.0 * kDeg, -2.0 * kDeg}, Euler{120.0 * kDeg, -30.0 * kDeg, 50.0 * kDeg}}) {
    const auto f = filter_at(e);
    const auto m = baseline_attitude<2>(f, baseline, 0.3, 0.1, 1e-3, 1e-3);
    const double h = 1e-6;
    for (int k = 0; k < 3; ++k) {
      Vec3 d = Vec3::Zero();
      d(k) = h;
      auto plus = f, minus = f;
      plus.nav.q_eb = (f.nav.q_eb * quat_from_rotvec(d)).normalized();
      minus.nav.q_eb = (f.nav.q_eb * quat_from_rotvec(-d)).normalized();
      const auto mp = baseline_attitude<2>(plus, baseline, 0.3, 0.1, 1e-3, 1e-3);
      const auto mm = baseline_attitude<2>(minus, baseline, 0.3, 0.1, 1e-3, 1e-3);
      // y = z - h(x): H dx = h(x + dx) - h(x) = y(x) - y(x + dx).
      const Eigen::Vector2d numeric = (mm.y - mp.y) / (2.0 * h);
      CHECK(std::abs(m.H(0, es::att + k) - numeric(0)) < 1e-7);
      CHECK(std::abs(m.H(1, es::att + k) - numeric(1)) < 1e-7);
    }
    // Nothing but the attitude enters.
    CHECK(m.H.block(0, 3, 2, Eskf<5, 0>::N - 3).cwiseAbs().maxCoeff() == 0.0);
  }
}

TEST_CASE("baseline attitude: the yaw innovation is wrapped") {
  const auto f = filter_at(Euler{179.0 * kDeg, 0.0, 0.0});
  const auto m = baseline_attitude<1>(f, Vec3(1.0, 0.0, 0.0), -179.0 * kDeg, 0.0, 1e-3, 0.0);
  CHECK(m.y(0) == doctest::Approx(2.0 * kDeg).epsilon(1e-9));
}

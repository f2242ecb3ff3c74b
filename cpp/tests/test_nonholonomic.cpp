#include <doctest/doctest.h>

#include "gpsins/aiding/nonholonomic.hpp"
#include "gpsins/attitude.hpp"
#include "gpsins/earth.hpp"

using namespace gpsins;

namespace {
constexpr double kDeg = M_PI / 180.0;

Eskf<5, 0> moving_filter() {
  Eskf<5, 0> f;
  const Geodetic site{59.37 * kDeg, 17.95 * kDeg, 30.0};
  f.nav.r_ecef_m = geodetic_to_ecef(site);
  f.nav.v_ecef_mps = rot_ned_to_ecef(site.lat_rad, site.lon_rad) * Vec3(8.0, -6.0, 0.2);
  f.nav.q_eb = quat_body_to_ecef({-37.0 * kDeg, 3.0 * kDeg, -2.0 * kDeg}, site.lat_rad, site.lon_rad);
  f.imu.gyro_bias_rad_per_s = Vec3(0.01, -0.02, 0.005);
  return f;
}

const Mat3 kCvb = dcm_from_euler(Euler{1.5 * kDeg, -2.0 * kDeg, 0.7 * kDeg});
const Vec3 kPoint(-1.4, 0.3, 0.9);
const Vec3 kRate(0.05, -0.2, 0.4);  // rad/s, turning over a bump

// y(x) - y(x + d) over the step: what H dx predicts (y = z - h(x)).
template <class Perturb>
Vec3 numeric_column(const Eskf<5, 0>& f, Perturb perturb, double step) {
  auto g = f;
  perturb(g, step);
  const auto m0 = vehicle_velocity(f, kCvb, kPoint, kRate);
  const auto m1 = vehicle_velocity(g, kCvb, kPoint, kRate);
  return (m0.y - m1.y) / step;
}
}  // namespace

TEST_CASE("vehicle velocity: the Jacobian matches finite differences (velocity, attitude, gyro bias)") {
  const auto f = moving_filter();
  const auto m = vehicle_velocity(f, kCvb, kPoint, kRate);
  for (int k = 0; k < 3; ++k) {
    const Vec3 dv = numeric_column(
        f, [k](auto& g, double h) { g.nav.v_ecef_mps(k) += h; }, 1e-4);
    CHECK((dv - m.H.col(es::vel + k)).norm() < 1e-8);
    const Vec3 dth = numeric_column(
        f,
        [k](auto& g, double h) {
          Vec3 d = Vec3::Zero();
          d(k) = h;
          g.nav.q_eb = g.nav.q_eb * quat_from_rotvec(d);
        },
        1e-7);
    CHECK((dth - m.H.col(es::att + k)).norm() < 1e-5);  // second order: |v| 1e-7
    const Vec3 dbg = numeric_column(
        f, [k](auto& g, double h) { g.imu.gyro_bias_rad_per_s(k) += h; }, 1e-6);
    CHECK((dbg - m.H.col(es::bg + k)).norm() < 1e-8);
  }
  // Nothing else moves the vehicle velocity.
  CHECK(m.H.middleCols<3>(es::pos).norm() == 0.0);
  CHECK(m.H.middleCols<3>(es::ba).norm() == 0.0);
}

TEST_CASE("non-holonomic constraint: lateral and vertical rows, zero innovation for a vehicle moving straight ahead") {
  auto f = moving_filter();
  f.imu.gyro_bias_rad_per_s.setZero();
  // Velocity along the vehicle's forward axis: body forward rotated back from vehicle axes.
  const Mat3 c_eb = f.nav.q_eb.toRotationMatrix();
  const Vec3 fwd_body = kCvb.transpose() * Vec3(1.0, 0.0, 0.0);
  f.nav.v_ecef_mps = c_eb * fwd_body * 12.0;
  const Vec3 earth_b = c_eb.transpose() * earth_rate_ecef();
  const auto m = nonholonomic(f, kCvb, Vec3::Zero(), earth_b, 0.1, 0.3);  // no rotation relative to the Earth
  CHECK(m.y.norm() < 1e-9);
  CHECK(m.R(0, 0) == doctest::Approx(0.01));  // lateral
  CHECK(m.R(1, 1) == doctest::Approx(0.09));  // vertical
  CHECK(m.R(0, 1) == 0.0);
  const auto full = vehicle_velocity(f, kCvb, Vec3::Zero(), earth_b);
  CHECK(full.y(0) == doctest::Approx(-12.0));  // the forward row, which the constraint leaves out
  CHECK((m.H.row(0) - full.H.row(1)).norm() == 0.0);
  CHECK((m.H.row(1) - full.H.row(2)).norm() == 0.0);
}

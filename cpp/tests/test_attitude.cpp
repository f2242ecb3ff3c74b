#include <doctest/doctest.h>

#include <cmath>
#include <random>

#include "gpsins/attitude.hpp"
#include "gpsins/earth.hpp"

using namespace gpsins;

namespace {
constexpr double kDeg = M_PI / 180.0;

double rot_distance(const Mat3& a, const Mat3& b) { return (a - b).norm(); }

Vec3 random_unit(std::mt19937_64& rng) {
  std::normal_distribution<double> n(0.0, 1.0);
  return Vec3(n(rng), n(rng), n(rng)).normalized();
}
}  // namespace

TEST_CASE("quaternion exp map against Rodrigues' formula") {
  std::mt19937_64 rng(3);
  std::uniform_real_distribution<double> ang(0.0, M_PI);
  for (int i = 0; i < 1000; ++i) {
    const Vec3 axis = random_unit(rng);
    const double a = ang(rng);
    // Rodrigues: R = I + sin(a) K + (1 - cos(a)) K^2
    const Mat3 k = skew(axis);
    const Mat3 rod = Mat3::Identity() + std::sin(a) * k + (1.0 - std::cos(a)) * k * k;
    CHECK(rot_distance(dcm_from_rotvec(a * axis), rod) < 1e-14);
  }
  // Quarter turn about z takes x to y (passive body-to-world: v_w = C v_b).
  const Vec3 y = dcm_from_rotvec(Vec3(0, 0, M_PI / 2)) * Vec3::UnitX();
  CHECK((y - Vec3::UnitY()).norm() < 1e-15);
}

TEST_CASE("rotation vector round trip, tiny to nearly pi") {
  std::mt19937_64 rng(5);
  for (double a : {0.0, 1e-300, 1e-20, 1e-12, 1e-8, 1e-5, 1e-4, 0.1, 1.0, 3.0, M_PI - 1e-6}) {
    for (int i = 0; i < 50; ++i) {
      const Vec3 v = a * random_unit(rng);
      const Vec3 back = rotvec_from_quat(quat_from_rotvec(v));
      CHECK((back - v).norm() <= 1e-15 + 1e-13 * a);
    }
  }
  // Small-angle quaternion is first-order exact: q = (1, v/2).
  const Quat q = quat_from_rotvec(Vec3(2e-9, -4e-9, 6e-9));
  CHECK(q.x() == doctest::Approx(1e-9).epsilon(1e-12));
  CHECK(std::abs(q.norm() - 1.0) < 1e-16);
}

TEST_CASE("quaternion and matrix agree, Shepperd is stable everywhere") {
  std::mt19937_64 rng(11);
  std::uniform_real_distribution<double> ang(0.0, M_PI);
  for (int i = 0; i < 5000; ++i) {
    const Vec3 v = ang(rng) * random_unit(rng);
    const Mat3 c = dcm_from_rotvec(v);
    const Quat q = quat_from_dcm(c);
    CHECK(rot_distance(dcm_from_quat(q), c) < 1e-14);
  }
  // Half-turns, where a trace-only formula divides by zero.
  for (const Vec3& axis : {Vec3(1, 0, 0), Vec3(0, 1, 0), Vec3(0, 0, 1), Vec3(1, 1, 0).normalized()}) {
    const Mat3 c = dcm_from_rotvec(M_PI * axis);
    CHECK(rot_distance(dcm_from_quat(quat_from_dcm(c)), c) < 1e-14);
  }
}

TEST_CASE("quaternion product composes rotations like matrices (Hamilton)") {
  std::mt19937_64 rng(13);
  for (int i = 0; i < 200; ++i) {
    const Quat a = quat_from_rotvec(2.0 * random_unit(rng));
    const Quat b = quat_from_rotvec(1.0 * random_unit(rng));
    CHECK(rot_distance(dcm_from_quat(a * b), dcm_from_quat(a) * dcm_from_quat(b)) < 1e-14);
  }
  // Hamilton: i * j = k.
  const Quat k = Quat(0, 1, 0, 0) * Quat(0, 0, 1, 0);
  CHECK(k.z() == 1.0);
}

TEST_CASE("Euler yaw-pitch-roll is intrinsic z-y-x") {
  const Euler e{30 * kDeg, 20 * kDeg, -10 * kDeg};
  const Mat3 expected = (Eigen::AngleAxisd(e.yaw_rad, Vec3::UnitZ()) * Eigen::AngleAxisd(e.pitch_rad, Vec3::UnitY()) *
                         Eigen::AngleAxisd(e.roll_rad, Vec3::UnitX()))
                            .toRotationMatrix();
  CHECK(rot_distance(dcm_from_euler(e), expected) < 1e-15);
  CHECK(rot_distance(dcm_from_quat(quat_from_euler(e)), expected) < 1e-15);
  // Nose up by 20 deg: the body x axis has a negative down component.
  CHECK(dcm_from_euler(e)(2, 0) == doctest::Approx(-std::sin(20 * kDeg)));
}

TEST_CASE("Euler round trip including the gimbal-lock neighbourhood") {
  std::mt19937_64 rng(17);
  std::uniform_real_distribution<double> yaw(-M_PI, M_PI), pitch(-M_PI / 2, M_PI / 2), roll(-M_PI, M_PI);
  for (int i = 0; i < 5000; ++i) {
    const Euler e{yaw(rng), pitch(rng), roll(rng)};
    const Euler back = euler_from_dcm(dcm_from_euler(e));
    CHECK(std::abs(std::remainder(back.yaw_rad - e.yaw_rad, 2 * M_PI)) < 1e-9);
    CHECK(std::abs(back.pitch_rad - e.pitch_rad) < 1e-12);
    CHECK(std::abs(std::remainder(back.roll_rad - e.roll_rad, 2 * M_PI)) < 1e-9);
  }
  // Near and at +-90 deg pitch the angles are not unique, the rotation is.
  for (double p : {M_PI / 2, M_PI / 2 - 1e-7, M_PI / 2 - 1e-12, -M_PI / 2, -M_PI / 2 + 1e-9}) {
    const Euler e{0.7, p, -0.4};
    const Mat3 c = dcm_from_euler(e);
    const Euler back = euler_from_dcm(c);
    CHECK(rot_distance(dcm_from_euler(back), c) < 1e-12);
    CHECK(std::abs(back.pitch_rad - p) < 1e-7);
  }
}

TEST_CASE("body to ECEF attitude from Euler angles and back") {
  const double lat = 59.37 * kDeg, lon = 17.95 * kDeg;
  const Euler e{-120 * kDeg, 3 * kDeg, 1.5 * kDeg};
  const Quat q_eb = quat_body_to_ecef(e, lat, lon);
  const Euler back = euler_from_body_to_ecef(q_eb, lat, lon);
  CHECK(back.yaw_rad == doctest::Approx(e.yaw_rad).epsilon(1e-12));
  CHECK(back.pitch_rad == doctest::Approx(e.pitch_rad).epsilon(1e-12));
  CHECK(back.roll_rad == doctest::Approx(e.roll_rad).epsilon(1e-12));
  // Level and facing north: body x is local north, body z is local down.
  const Mat3 c = dcm_from_quat(quat_body_to_ecef(Euler{}, lat, lon));
  CHECK(rot_distance(c, rot_ned_to_ecef(lat, lon)) < 1e-14);
}

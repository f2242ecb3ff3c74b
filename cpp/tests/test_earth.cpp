#include <doctest/doctest.h>

#include <cmath>
#include <random>

#include "gpsins/earth.hpp"

using namespace gpsins;

namespace {
constexpr double kDeg = M_PI / 180.0;
}

TEST_CASE("geodetic to ECEF at textbook points") {
  const Vec3 eq = geodetic_to_ecef({0.0, 0.0, 0.0});
  CHECK(eq.x() == doctest::Approx(wgs84::a).epsilon(1e-15));
  CHECK(std::abs(eq.y()) < 1e-9);
  CHECK(std::abs(eq.z()) < 1e-9);
  const Vec3 pole = geodetic_to_ecef({90.0 * kDeg, 0.0, 100.0});
  CHECK(std::abs(pole.x()) < 1e-9);
  CHECK(pole.z() == doctest::Approx(wgs84::b + 100.0).epsilon(1e-15));
  // b is 6356752.314245 m for WGS-84 (published value).
  CHECK(wgs84::b == doctest::Approx(6356752.314245).epsilon(1e-12));
}

TEST_CASE("geodetic round trip everywhere, poles and -5 km .. +100 km included") {
  std::mt19937_64 rng(7);
  std::uniform_real_distribution<double> lat(-M_PI / 2, M_PI / 2), lon(-M_PI, M_PI), h(-5000.0, 100000.0);
  double worst_m = 0.0, worst_rad = 0.0;
  auto check = [&](Geodetic in) {
    const Geodetic out = ecef_to_geodetic(geodetic_to_ecef(in));
    worst_m = std::max(worst_m, std::abs(out.height_m - in.height_m));
    worst_rad = std::max(worst_rad, std::abs(out.lat_rad - in.lat_rad));
    if (std::abs(in.lat_rad) < M_PI / 2 - 1e-9) {
      worst_rad =
          std::max(worst_rad, std::abs(std::remainder(out.lon_rad - in.lon_rad, 2 * M_PI)) * std::cos(in.lat_rad));
    }
  };
  for (int i = 0; i < 200000; ++i) check({lat(rng), lon(rng), h(rng)});
  for (double hh : {-5000.0, 0.0, 100000.0}) {
    check({M_PI / 2, 0.3, hh});
    check({-M_PI / 2, -1.0, hh});
    check({M_PI / 2 - 1e-10, 2.0, hh});
  }
  CHECK(worst_m < 1e-8);
  CHECK(worst_rad < 1e-12);
}

TEST_CASE("local frames are orthonormal and point the right way") {
  const double lat = 59.37 * kDeg, lon = 17.95 * kDeg;
  const Mat3 c = rot_ned_to_ecef(lat, lon);
  CHECK((c.transpose() * c - Mat3::Identity()).norm() < 1e-15);
  CHECK(c.determinant() == doctest::Approx(1.0));
  // Down is minus the ellipsoid normal: a step down lowers the height by the step.
  const Geodetic ref{lat, lon, 50.0};
  const Geodetic below = ecef_to_geodetic(ned_to_ecef(Vec3(0, 0, 10.0), ref));
  CHECK(below.height_m == doctest::Approx(40.0).epsilon(1e-9));
  // A step north raises the latitude by dN / (M + h).
  const Geodetic north = ecef_to_geodetic(ned_to_ecef(Vec3(1.0, 0, 0), ref));
  CHECK((north.lat_rad - lat) == doctest::Approx(1.0 / (meridian_radius_m(lat) + 50.0)).epsilon(1e-6));
  const Vec3 enu = ecef_to_enu(ned_to_ecef(Vec3(3, 4, 5), ref), ref);
  CHECK(enu.x() == doctest::Approx(4.0));
  CHECK(enu.y() == doctest::Approx(3.0));
  CHECK(enu.z() == doctest::Approx(-5.0));
}

TEST_CASE("normal gravity matches WGS-84 published values") {
  CHECK(normal_gravity_mps2(0.0, 0.0) == doctest::Approx(9.7803253359).epsilon(1e-12));
  CHECK(normal_gravity_mps2(M_PI / 2, 0.0) == doctest::Approx(9.8321849378).epsilon(1e-12));
  // The report's value at 59 deg 21' N (its own formula is approximate).
  CHECK(std::abs(normal_gravity_mps2((59.0 + 21.0 / 60.0) * kDeg, 0.0) - 9.8185) < 1e-3);
  // Free-air gradient near the surface: about -3.086e-6 (m/s^2)/m at mid latitudes.
  const double grad = (normal_gravity_mps2(45 * kDeg, 100.0) - normal_gravity_mps2(45 * kDeg, 0.0)) / 100.0;
  CHECK(grad == doctest::Approx(-3.086e-6).epsilon(2e-3));
}

TEST_CASE("normal gravity vector holds the centrifugal part") {
  // Somigliana's gamma is gravitation + centrifugal. On the equator both act
  // along the radius, so |gravitation| = gamma + omega^2 a there.
  const Vec3 g = normal_gravity_ecef(Geodetic{0.0, 0.0, 0.0});
  CHECK(g.x() == doctest::Approx(-9.7803253359).epsilon(1e-12));
  const double gravitation = -g.x() + wgs84::omega_rad_per_s * wgs84::omega_rad_per_s * wgs84::a;
  CHECK(gravitation == doctest::Approx(9.8142).epsilon(1e-4));
  // At the pole there is no centrifugal term and the vector points along -z.
  const Vec3 gp = normal_gravity_ecef(geodetic_to_ecef({M_PI / 2, 0.0, 0.0}));
  CHECK(gp.z() == doctest::Approx(-9.8321849378).epsilon(1e-12));
}

TEST_CASE("skew matrix is the cross product") {
  const Vec3 a(1.0, -2.0, 3.5), b(-0.5, 4.0, 2.0);
  CHECK((skew(a) * b - a.cross(b)).norm() < 1e-15);
  CHECK((skew(a) + skew(a).transpose()).norm() == 0.0);
  CHECK(earth_rate_ecef().z() == 7.292115e-5);
}

#include "gpsins/earth.hpp"

#include <cmath>

namespace gpsins {

Vec3 geodetic_to_ecef(const Geodetic& llh) {
  const double sl = std::sin(llh.lat_rad), cl = std::cos(llh.lat_rad);
  const double n = prime_vertical_radius_m(llh.lat_rad);
  return Vec3((n + llh.height_m) * cl * std::cos(llh.lon_rad), (n + llh.height_m) * cl * std::sin(llh.lon_rad),
              (n * (1.0 - wgs84::e2) + llh.height_m) * sl);
}

Geodetic ecef_to_geodetic(const Vec3& r) {
  // Fixed-point iteration on the z-coordinate of the normal's intersection
  // with the polar axis; it contracts by about e^2 per pass, so eight passes
  // reach double precision from the spherical start, poles included.
  const double p2 = r.x() * r.x() + r.y() * r.y();
  double z = r.z();
  double n = wgs84::a;
  for (int i = 0; i < 12; ++i) {
    const double sin_lat = z / std::sqrt(p2 + z * z);
    n = wgs84::a / std::sqrt(1.0 - wgs84::e2 * sin_lat * sin_lat);
    const double z_next = r.z() + n * wgs84::e2 * sin_lat;
    const double step = std::abs(z_next - z);
    z = z_next;
    if (step < 1e-9) break;
  }
  Geodetic llh;
  const double p = std::sqrt(p2);
  llh.lat_rad = std::atan2(z, p);
  llh.lon_rad = p2 > 0.0 ? std::atan2(r.y(), r.x()) : 0.0;
  llh.height_m = std::sqrt(p2 + z * z) - n;
  return llh;
}

double meridian_radius_m(double lat_rad) {
  const double s = std::sin(lat_rad);
  const double w2 = 1.0 - wgs84::e2 * s * s;
  return wgs84::a * (1.0 - wgs84::e2) / (w2 * std::sqrt(w2));
}

double prime_vertical_radius_m(double lat_rad) {
  const double s = std::sin(lat_rad);
  return wgs84::a / std::sqrt(1.0 - wgs84::e2 * s * s);
}

Mat3 rot_ned_to_ecef(double lat_rad, double lon_rad) {
  const double sl = std::sin(lat_rad), cl = std::cos(lat_rad);
  const double so = std::sin(lon_rad), co = std::cos(lon_rad);
  Mat3 c;  // columns: north, east, down in ECEF
  c << -sl * co, -so, -cl * co, -sl * so, co, -cl * so, cl, 0.0, -sl;
  return c;
}

Mat3 rot_enu_to_ecef(double lat_rad, double lon_rad) {
  const Mat3 ned = rot_ned_to_ecef(lat_rad, lon_rad);
  Mat3 enu;
  enu.col(0) = ned.col(1);
  enu.col(1) = ned.col(0);
  enu.col(2) = -ned.col(2);
  return enu;
}

Vec3 ecef_to_ned(const Vec3& r_ecef, const Geodetic& ref) {
  return rot_ned_to_ecef(ref.lat_rad, ref.lon_rad).transpose() * (r_ecef - geodetic_to_ecef(ref));
}

Vec3 ned_to_ecef(const Vec3& ned, const Geodetic& ref) {
  return geodetic_to_ecef(ref) + rot_ned_to_ecef(ref.lat_rad, ref.lon_rad) * ned;
}

Vec3 ecef_to_enu(const Vec3& r_ecef, const Geodetic& ref) {
  return rot_enu_to_ecef(ref.lat_rad, ref.lon_rad).transpose() * (r_ecef - geodetic_to_ecef(ref));
}

Vec3 enu_to_ecef(const Vec3& enu, const Geodetic& ref) {
  return geodetic_to_ecef(ref) + rot_enu_to_ecef(ref.lat_rad, ref.lon_rad) * enu;
}

double normal_gravity_mps2(double lat_rad, double height_m) {
  using namespace wgs84;
  const double s2 = std::sin(lat_rad) * std::sin(lat_rad);
  const double gamma0 = gamma_equator * (1.0 + somigliana_k * s2) / std::sqrt(1.0 - e2 * s2);
  const double height_factor =
      1.0 - 2.0 / a * (1.0 + f + m - 2.0 * f * s2) * height_m + 3.0 / (a * a) * height_m * height_m;
  return gamma0 * height_factor;
}

Vec3 normal_gravity_ecef(const Geodetic& llh) {
  const double cl = std::cos(llh.lat_rad);
  const Vec3 down(-cl * std::cos(llh.lon_rad), -cl * std::sin(llh.lon_rad), -std::sin(llh.lat_rad));
  return normal_gravity_mps2(llh.lat_rad, llh.height_m) * down;
}

Vec3 normal_gravity_ecef(const Vec3& r_ecef) { return normal_gravity_ecef(ecef_to_geodetic(r_ecef)); }

}  // namespace gpsins

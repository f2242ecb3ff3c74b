// The Earth model: geodetic and local frames, normal gravity, Earth rotation.
//
// Conventions: ECEF is WGS-84; local frames are NED (north-east-down) and ENU;
// C_e_n denotes the rotation taking NED vectors to ECEF.
#pragma once

#include "gpsins/types.hpp"
#include "gpsins/wgs84.hpp"

namespace gpsins {

struct Geodetic {
  double lat_rad = 0.0;
  double lon_rad = 0.0;
  double height_m = 0.0;  // above the WGS-84 ellipsoid
};

Vec3 geodetic_to_ecef(const Geodetic& llh);
// Iterated to machine precision (at most a handful of passes); exact at the poles.
Geodetic ecef_to_geodetic(const Vec3& r_ecef);

// Radii of curvature: meridian (north-south) and prime vertical (east-west), m.
double meridian_radius_m(double lat_rad);
double prime_vertical_radius_m(double lat_rad);

Mat3 rot_ned_to_ecef(double lat_rad, double lon_rad);
Mat3 rot_enu_to_ecef(double lat_rad, double lon_rad);

// Position of r_ecef relative to the origin `ref`, in ref's local frame, and back.
Vec3 ecef_to_ned(const Vec3& r_ecef, const Geodetic& ref);
Vec3 ned_to_ecef(const Vec3& ned, const Geodetic& ref);
Vec3 ecef_to_enu(const Vec3& r_ecef, const Geodetic& ref);
Vec3 enu_to_ecef(const Vec3& enu, const Geodetic& ref);

// Magnitude of WGS-84 normal gravity (gravitation plus centrifugal), m/s^2:
// Somigliana on the ellipsoid with the second-order height terms.
double normal_gravity_mps2(double lat_rad, double height_m);

// Normal gravity as an ECEF vector, pointing down along the ellipsoid normal.
// It already contains the centrifugal acceleration, so navigation equations
// using it must not add -Omega x (Omega x r) again. At rest an accelerometer
// measures f = -gamma. (The small north component at height, below 1e-5 m/s^2
// under 1 km, is neglected.)
Vec3 normal_gravity_ecef(const Geodetic& llh);
Vec3 normal_gravity_ecef(const Vec3& r_ecef);

// Earth rotation rate vector in ECEF, rad/s.
inline Vec3 earth_rate_ecef() { return Vec3(0.0, 0.0, wgs84::omega_rad_per_s); }

// Skew-symmetric (cross-product) matrix: skew(a) * b == a.cross(b).
inline Mat3 skew(const Vec3& v) {
  Mat3 s;
  s << 0.0, -v.z(), v.y(), v.z(), 0.0, -v.x(), -v.y(), v.x(), 0.0;
  return s;
}

}  // namespace gpsins

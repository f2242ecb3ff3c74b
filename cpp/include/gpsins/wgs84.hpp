// WGS-84 defining and derived constants (NIMA TR8350.2, 3rd ed.).
#pragma once

namespace gpsins::wgs84 {

inline constexpr double a = 6378137.0;                  // semi-major axis, m
inline constexpr double f = 1.0 / 298.257223563;        // flattening
inline constexpr double b = a * (1.0 - f);              // semi-minor axis, m
inline constexpr double e2 = f * (2.0 - f);             // first eccentricity squared
inline constexpr double ep2 = e2 / (1.0 - e2);          // second eccentricity squared
inline constexpr double gm_m3_per_s2 = 3.986004418e14;  // Earth's gravitational constant
inline constexpr double omega_rad_per_s = 7.292115e-5;  // Earth rotation rate

// Normal gravity on the ellipsoid (Somigliana), equator and pole, m/s^2.
inline constexpr double gamma_equator = 9.7803253359;
inline constexpr double gamma_pole = 9.8321849378;
// Somigliana's k = (b gamma_p - a gamma_e) / (a gamma_e).
inline constexpr double somigliana_k = (b * gamma_pole - a * gamma_equator) / (a * gamma_equator);
// m = omega^2 a^2 b / GM, used by the height terms of normal gravity.
inline constexpr double m = omega_rad_per_s * omega_rad_per_s * a * a * b / gm_m3_per_s2;

}  // namespace gpsins::wgs84

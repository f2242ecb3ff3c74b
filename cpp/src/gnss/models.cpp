#include "gpsins/gnss/models.hpp"

#include <algorithm>
#include <cmath>

#include "gpsins/gnss/ephemeris.hpp"

namespace gpsins::gnss {

AzEl az_el(const Geodetic& llh, const Vec3& rx, const Vec3& sat) {
  const Vec3 los = (sat - rx).normalized();
  const Vec3 enu = rot_enu_to_ecef(llh.lat_rad, llh.lon_rad).transpose() * los;
  AzEl out;
  out.az_rad = std::atan2(enu.x(), enu.y());
  if (out.az_rad < 0.0) out.az_rad += 2.0 * M_PI;
  out.el_rad = std::asin(std::clamp(enu.z(), -1.0, 1.0));
  return out;
}

double sagnac_m(const Vec3& s, const Vec3& r) { return kOmegaEarth * (s.x() * r.y() - s.y() * r.x()) / kSpeedOfLight; }

double sagnac_rate_mps(const Vec3& s, const Vec3& vs, const Vec3& r, const Vec3& vr) {
  return kOmegaEarth * (vs.x() * r.y() + s.x() * vr.y() - vs.y() * r.x() - s.y() * vr.x()) / kSpeedOfLight;
}

double klobuchar_m(const Klobuchar& k, const Geodetic& llh, const AzEl& ae, double tow_s) {
  if (!k.valid || ae.el_rad <= 0.0) return 0.0;
  const double el = ae.el_rad / M_PI;  // semicircles
  const double psi = 0.0137 / (el + 0.11) - 0.022;
  double phi = llh.lat_rad / M_PI + psi * std::cos(ae.az_rad);
  phi = std::clamp(phi, -0.416, 0.416);
  const double lam = llh.lon_rad / M_PI + psi * std::sin(ae.az_rad) / std::cos(phi * M_PI);
  const double phi_m = phi + 0.064 * std::cos((lam - 1.617) * M_PI);
  double t = 43200.0 * lam + tow_s;
  t -= std::floor(t / 86400.0) * 86400.0;
  const double f = 1.0 + 16.0 * std::pow(0.53 - el, 3);
  double amp = 0.0, per = 0.0, p = 1.0;
  for (int i = 0; i < 4; ++i) {
    amp += k.alpha[static_cast<std::size_t>(i)] * p;
    per += k.beta[static_cast<std::size_t>(i)] * p;
    p *= phi_m;
  }
  amp = std::max(amp, 0.0);
  per = std::max(per, 72000.0);
  const double x = 2.0 * M_PI * (t - 50400.0) / per;
  const double delay = std::abs(x) < 1.57 ? f * (5e-9 + amp * (1.0 - x * x / 2.0 + x * x * x * x / 24.0)) : f * 5e-9;
  return kSpeedOfLight * delay;
}

double saastamoinen_m(const Geodetic& llh, double el_rad, double humidity) {
  if (llh.height_m < -100.0 || llh.height_m > 1e4 || el_rad <= 0.0) return 0.0;
  const double h = std::max(llh.height_m, 0.0);
  const double pressure_hpa = 1013.25 * std::pow(1.0 - 2.2557e-5 * h, 5.2568);
  const double temp_k = 15.0 - 6.5e-3 * h + 273.16;
  const double e = 6.108 * humidity * std::exp((17.15 * temp_k - 4684.0) / (temp_k - 38.45));
  const double cos_z = std::cos(M_PI / 2.0 - el_rad);
  const double dry =
      0.0022768 * pressure_hpa / (1.0 - 0.00266 * std::cos(2.0 * llh.lat_rad) - 0.00028 * h / 1e3) / cos_z;
  const double wet = 0.002277 * (1255.0 / temp_k + 0.05) * e / cos_z;
  return dry + wet;
}

double pseudorange_variance_m2(double el_rad, double ura, double iono_m) {
  const double s = std::sin(el_rad);
  const double code = 100.0 * 100.0 * (0.003 * 0.003 + 0.003 * 0.003 / s);
  const double trop = 0.3 / (s + 0.1);
  return code + ura * ura + 0.3 * 0.3 + (0.5 * iono_m) * (0.5 * iono_m) + trop * trop;
}

}  // namespace gpsins::gnss

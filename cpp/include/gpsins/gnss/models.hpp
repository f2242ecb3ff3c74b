// Signal models: geometry (azimuth, elevation, Sagnac), Klobuchar ionosphere,
// Saastamoinen troposphere, and the pseudorange variance model.
#pragma once

#include <array>

#include "gpsins/earth.hpp"
#include "gpsins/gnss/ephemeris.hpp"
#include "gpsins/types.hpp"

namespace gpsins::gnss {

struct AzEl {
  double az_rad = 0.0;  // clockwise from north, [0, 2 pi)
  double el_rad = 0.0;
};

AzEl az_el(const Geodetic& rx_llh, const Vec3& rx_ecef, const Vec3& sat_ecef);

// Earth rotation during the signal's travel: range correction w (xs yr - ys xr) / c, m.
double sagnac_m(const Vec3& sat_ecef, const Vec3& rx_ecef);
// Its rate, m/s, from both ends' ECEF velocities (a few cm/s: not negligible against a Doppler).
double sagnac_rate_mps(const Vec3& sat_ecef, const Vec3& sat_v_ecef, const Vec3& rx_ecef, const Vec3& rx_v_ecef);

// GPS L1 and Galileo E1 share one carrier: a Doppler (Hz, positive approaching) is -rate / wavelength.
inline constexpr double kL1WavelengthM = kSpeedOfLight / 1575.42e6;

struct Klobuchar {
  std::array<double, 4> alpha{};
  std::array<double, 4> beta{};
  bool valid = false;
};

// L1 ionospheric delay, m (IS-GPS-200 20.3.3.5.2.5); tow: receiver GPS seconds of week.
double klobuchar_m(const Klobuchar& k, const Geodetic& rx_llh, const AzEl& ae, double tow_s);

// Saastamoinen with a standard atmosphere at the receiver's height, relative humidity `humidity`.
double saastamoinen_m(const Geodetic& rx_llh, double el_rad, double humidity = 0.7);

// Pseudorange variance, m^2, elevation-dependent in the way of RTKLIB's single
// point positioning: code noise 100 x (0.003^2 + 0.003^2 / sin el), the
// ephemeris URA, a code bias term 0.3^2, half the ionosphere model and the
// troposphere's 0.3 / (sin el + 0.1).
double pseudorange_variance_m2(double el_rad, double ura_m, double iono_m);

}  // namespace gpsins::gnss

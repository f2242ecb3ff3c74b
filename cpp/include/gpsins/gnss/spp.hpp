// Single-point positioning: iterated weighted least squares for position and
// receiver clock from L1 pseudoranges, with Klobuchar, Saastamoinen, TGD, an
// elevation mask and the elevation-dependent variance model; a chi-square test
// on the weighted residuals and, when it fails and enough satellites remain,
// the exclusion of the one satellite that makes it pass (RAIM-style).
#pragma once

#include <array>

#include "gpsins/gnss/ephemeris.hpp"
#include "gpsins/gnss/models.hpp"

namespace gpsins::gnss {

inline constexpr int kMaxSats = 24;

struct PseudorangeObs {
  int prn = 0;
  double pr_m = 0.0;
};

struct SppOptions {
  double elevation_mask_rad = 15.0 * M_PI / 180.0;
  bool ionosphere = true;
  bool troposphere = true;
  bool tgd = true;
  bool raim = true;
  double chi2_probability = 0.999;
  double max_gdop = 30.0;
};

struct SatUse {
  int prn = 0;
  bool used = false;
  double el_rad = 0.0, az_rad = 0.0;
  double residual_m = 0.0;  // after the final iteration
  double sigma_m = 0.0;
};

struct SppResult {
  bool ok = false;
  Vec3 r_ecef_m = Vec3::Zero();
  double clock_m = 0.0;  // receiver clock bias times c
  double gdop = 0.0, pdop = 0.0, hdop = 0.0, vdop = 0.0;
  int n_used = 0;
  int excluded_prn = 0;
  double chi2 = 0.0;
  int iterations = 0;
  std::array<SatUse, kMaxSats> sats{};
  int n_sats = 0;
};

// t_rx_abs: receiver time of the observations, seconds since the GPS epoch.
SppResult spp(const EphemerisStore& store, const Klobuchar& iono, double t_rx_abs, const PseudorangeObs* obs, int n,
              const SppOptions& opt, const Vec3& r_guess = Vec3::Zero());

// Satellite position (rotated into the frame of reception: Sagnac applied separately by
// sagnac_m) and clock for a pseudorange received at t_rx: transmission time
// t_rx - pr / c - dts, two passes. Returns false without an ephemeris.
bool sat_at_transmission(const EphemerisStore& store, int prn, double t_rx_abs, double pr_m, SatState& out,
                         const Ephemeris** eph = nullptr);

}  // namespace gpsins::gnss

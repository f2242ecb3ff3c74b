// GPS broadcast ephemeris (IS-GPS-200): the subframe decoding of the Superstar
// II's ID 22, satellite position and clock at transmission time, and a store
// that picks the ephemeris for a time (nearest toe within its validity,
// healthy). Galileo's broadcast orbit (OS SIS ICD 5.1.1) has the same form
// with its own mu; its satellites share the id space: 33..68 are E01..E36.
// Fixed-size: no allocation.
#pragma once

#include <array>
#include <cstdint>

#include "gpsins/types.hpp"

namespace gpsins::gnss {

inline constexpr double kSpeedOfLight = 299792458.0;
inline constexpr double kGm = 3.986005e14;                // IS-GPS-200 value of mu, m^3/s^2
inline constexpr double kOmegaEarth = 7.2921151467e-5;    // IS-GPS-200 Earth rate, rad/s
inline constexpr double kGpsPi = 3.1415926535898;         // the semicircle of IS-GPS-200
inline constexpr double kRelativityF = -4.442807633e-10;  // s/sqrt(m)
inline constexpr double kSecondsPerWeek = 604800.0;
inline constexpr double kGmGalileo = 3.986004418e14;             // OS SIS ICD value of mu, m^3/s^2
inline constexpr double kRelativityFGalileo = -4.442807309e-10;  // -2 sqrt(mu) / c^2 with Galileo's mu

// Satellite ids: GPS PRN 1..32 as they are, Galileo E01..E36 as 33..68.
inline constexpr int kGalileoIdOffset = 32;
inline constexpr int kMaxSatId = kGalileoIdOffset + 36;
inline constexpr bool is_sat_id(int id) { return id >= 1 && id <= kMaxSatId; }
inline constexpr bool is_galileo(int id) { return id > kGalileoIdOffset && id <= kMaxSatId; }

struct Ephemeris {
  int prn = 0;                      // satellite id (is_sat_id): Galileo's are offset by kGalileoIdOffset
  int week = 0;                     // full GPS week of toe (Galileo: its GST week + 1024, GST keeping GPS seconds)
  double toe_s = 0.0, toc_s = 0.0;  // seconds of week
  double sqrt_a = 0.0, e = 0.0, i0 = 0.0, omega0 = 0.0, omega = 0.0, m0 = 0.0;  // m^1/2, -, rad
  double delta_n = 0.0, idot = 0.0, omega_dot = 0.0;                            // rad/s
  double cuc = 0.0, cus = 0.0, crc = 0.0, crs = 0.0, cic = 0.0, cis = 0.0;      // rad, m
  double af0 = 0.0, af1 = 0.0, af2 = 0.0, tgd_s = 0.0;  // Galileo: tgd_s is BGD(E1, E5b) of I/NAV
  int iode = 0, iodc = 0, health = 0, ura_index = 0;
  bool fit_interval_long = false;
  bool valid() const { return is_sat_id(prn) && sqrt_a > 0.0; }
  double toe_abs() const { return week * kSecondsPerWeek + toe_s; }  // seconds since the GPS epoch
};

// Subframes 1, 2, 3, words 3..10, each 24 bits (parity removed), MSB first.
// `week_hint` resolves the 10-bit week number (nearest to it).
bool decode_subframes(const std::array<std::array<std::uint32_t, 8>, 3>& words, int prn, int week_hint, Ephemeris& out);

struct SatState {
  Vec3 r_ecef_m = Vec3::Zero();  // ECEF at the transmission time (frame of that instant)
  double clock_s = 0.0;          // satellite clock offset incl. the relativistic term, excl. TGD
};

// t: GPS time (seconds since the GPS epoch) treated as the transmission time.
SatState sat_state(const Ephemeris& eph, double t_abs_s);

// The satellite's ECEF velocity and clock drift at t (what a Doppler measurement
// needs), as central differences of sat_state over +-0.5 s: the orbit's third
// derivative keeps their error below 1e-5 m/s, far inside any receiver's Doppler noise.
struct SatMotion {
  Vec3 v_ecef_mps = Vec3::Zero();
  double clock_drift = 0.0;  // s/s, incl. the relativistic term's rate
};
SatMotion sat_motion(const Ephemeris& eph, double t_abs_s);

// User range accuracy (m) of a URA index (IS-GPS-200 20.3.3.3.1.3), 6144 m when unknown.
double ura_m(int index);

// Ephemerides by PRN, a few per satellite, the newest replacing the oldest.
class EphemerisStore {
 public:
  static constexpr int kPerSat = 16;  // a day of 2-hourly sets
  // Add or replace (same toe and IODE: replaced). Returns false for an invalid one.
  bool add(const Ephemeris& e);
  // The healthy ephemeris with toe nearest t, within max_age_s; nullptr if none.
  const Ephemeris* select(int prn, double t_abs_s, double max_age_s = 7200.0 + 60.0) const;
  int count() const;

 private:
  std::array<std::array<Ephemeris, kPerSat>, kMaxSatId + 1> eph_{};
  std::array<int, kMaxSatId + 1> next_{};
};

}  // namespace gpsins::gnss

#include "gpsins/gnss/ephemeris.hpp"

#include <cmath>

namespace gpsins::gnss {

namespace {

// Bits [first, first + len) of a 24-bit word, bit 1 being the MSB (IS-GPS-200 numbering).
std::uint32_t bits(std::uint32_t word, int first, int len) {
  return (word >> (24 - (first - 1) - len)) & ((1u << len) - 1u);
}

double as_signed(std::uint32_t v, int len) {
  const std::int64_t x = static_cast<std::int64_t>(v);
  return static_cast<double>(x >= (std::int64_t{1} << (len - 1)) ? x - (std::int64_t{1} << len) : x);
}

// A 32-bit field split as 8 MSBs at the end of one word and 24 LSBs filling the next.
std::uint32_t join(std::uint32_t hi8, std::uint32_t lo24) { return (hi8 << 24) | (lo24 & 0xFFFFFFu); }

}  // namespace

bool decode_subframes(const std::array<std::array<std::uint32_t, 8>, 3>& w, int prn, int week_hint, Ephemeris& e) {
  const auto& s1 = w[0];
  const auto& s2 = w[1];
  const auto& s3 = w[2];
  e = Ephemeris{};
  e.prn = prn;
  const int wn10 = static_cast<int>(bits(s1[0], 1, 10));
  e.ura_index = static_cast<int>(bits(s1[0], 13, 4));
  e.health = static_cast<int>(bits(s1[0], 17, 6));
  const std::uint32_t iodc_hi = bits(s1[0], 23, 2);
  e.tgd_s = as_signed(bits(s1[4], 17, 8), 8) * std::ldexp(1.0, -31);
  e.iodc = static_cast<int>((iodc_hi << 8) | bits(s1[5], 1, 8));
  e.toc_s = bits(s1[5], 9, 16) * 16.0;
  e.af2 = as_signed(bits(s1[6], 1, 8), 8) * std::ldexp(1.0, -55);
  e.af1 = as_signed(bits(s1[6], 9, 16), 16) * std::ldexp(1.0, -43);
  e.af0 = as_signed(bits(s1[7], 1, 22), 22) * std::ldexp(1.0, -31);

  e.iode = static_cast<int>(bits(s2[0], 1, 8));
  e.crs = as_signed(bits(s2[0], 9, 16), 16) * std::ldexp(1.0, -5);
  e.delta_n = as_signed(bits(s2[1], 1, 16), 16) * std::ldexp(1.0, -43) * kGpsPi;
  e.m0 = as_signed(join(bits(s2[1], 17, 8), s2[2]), 32) * std::ldexp(1.0, -31) * kGpsPi;
  e.cuc = as_signed(bits(s2[3], 1, 16), 16) * std::ldexp(1.0, -29);
  e.e = static_cast<double>(join(bits(s2[3], 17, 8), s2[4])) * std::ldexp(1.0, -33);
  e.cus = as_signed(bits(s2[5], 1, 16), 16) * std::ldexp(1.0, -29);
  e.sqrt_a = static_cast<double>(join(bits(s2[5], 17, 8), s2[6])) * std::ldexp(1.0, -19);
  e.toe_s = bits(s2[7], 1, 16) * 16.0;
  e.fit_interval_long = bits(s2[7], 17, 1) != 0;

  e.cic = as_signed(bits(s3[0], 1, 16), 16) * std::ldexp(1.0, -29);
  e.omega0 = as_signed(join(bits(s3[0], 17, 8), s3[1]), 32) * std::ldexp(1.0, -31) * kGpsPi;
  e.cis = as_signed(bits(s3[2], 1, 16), 16) * std::ldexp(1.0, -29);
  e.i0 = as_signed(join(bits(s3[2], 17, 8), s3[3]), 32) * std::ldexp(1.0, -31) * kGpsPi;
  e.crc = as_signed(bits(s3[4], 1, 16), 16) * std::ldexp(1.0, -5);
  e.omega = as_signed(join(bits(s3[4], 17, 8), s3[5]), 32) * std::ldexp(1.0, -31) * kGpsPi;
  e.omega_dot = as_signed(s3[6] & 0xFFFFFFu, 24) * std::ldexp(1.0, -43) * kGpsPi;
  const int iode3 = static_cast<int>(bits(s3[7], 1, 8));
  e.idot = as_signed(bits(s3[7], 9, 14), 14) * std::ldexp(1.0, -43) * kGpsPi;

  // The full week nearest the hint with the same 10 bits.
  int week = week_hint - ((week_hint - wn10) % 1024 + 1024) % 1024;
  if (week_hint - week > 512) week += 1024;
  e.week = week;
  // IODE in subframes 2 and 3 and the IODC's low 8 bits agree for a consistent set.
  return iode3 == e.iode && (e.iodc & 0xFF) == e.iode && e.valid();
}

SatState sat_state(const Ephemeris& eph, double t_abs) {
  SatState s;
  const double a = eph.sqrt_a * eph.sqrt_a;
  double tk = t_abs - eph.toe_abs();
  const bool galileo = is_galileo(eph.prn);
  const double n = std::sqrt((galileo ? kGmGalileo : kGm) / (a * a * a)) + eph.delta_n;
  const double m = eph.m0 + n * tk;
  double ecc_anomaly = m;
  for (int i = 0; i < 30; ++i) {  // Newton on Kepler's equation
    const double step = (ecc_anomaly - eph.e * std::sin(ecc_anomaly) - m) / (1.0 - eph.e * std::cos(ecc_anomaly));
    ecc_anomaly -= step;
    if (std::abs(step) < 1e-14) break;
  }
  const double se = std::sin(ecc_anomaly), ce = std::cos(ecc_anomaly);
  const double nu = std::atan2(std::sqrt(1.0 - eph.e * eph.e) * se, ce - eph.e);
  const double phi = nu + eph.omega;
  const double s2 = std::sin(2.0 * phi), c2 = std::cos(2.0 * phi);
  const double u = phi + eph.cus * s2 + eph.cuc * c2;
  const double r = a * (1.0 - eph.e * ce) + eph.crs * s2 + eph.crc * c2;
  const double i = eph.i0 + eph.idot * tk + eph.cis * s2 + eph.cic * c2;
  const double xp = r * std::cos(u), yp = r * std::sin(u);
  const double om = eph.omega0 + (eph.omega_dot - kOmegaEarth) * tk - kOmegaEarth * eph.toe_s;
  const double so = std::sin(om), co = std::cos(om), ci = std::cos(i);
  s.r_ecef_m = Vec3(xp * co - yp * ci * so, xp * so + yp * ci * co, yp * std::sin(i));
  double dt = t_abs - (eph.week * kSecondsPerWeek + eph.toc_s);
  s.clock_s = eph.af0 + eph.af1 * dt + eph.af2 * dt * dt +
              (galileo ? kRelativityFGalileo : kRelativityF) * eph.e * eph.sqrt_a * se;
  return s;
}

SatMotion sat_motion(const Ephemeris& eph, double t_abs) {
  constexpr double h = 0.5;
  const SatState a = sat_state(eph, t_abs - h), b = sat_state(eph, t_abs + h);
  return SatMotion{(b.r_ecef_m - a.r_ecef_m) / (2.0 * h), (b.clock_s - a.clock_s) / (2.0 * h)};
}

double ura_m(int index) {
  static constexpr std::array<double, 15> table{2.4,  3.4,   4.85,  6.85,  9.65,   13.65,  24.0,  48.0,
                                                96.0, 192.0, 384.0, 768.0, 1536.0, 3072.0, 6144.0};
  return index >= 0 && index < 15 ? table[static_cast<std::size_t>(index)] : 6144.0;
}

bool EphemerisStore::add(const Ephemeris& e) {
  if (!e.valid()) return false;
  auto& slots = eph_[static_cast<std::size_t>(e.prn)];
  for (auto& s : slots) {
    if (s.valid() && s.toe_abs() == e.toe_abs() && s.iode == e.iode) {
      s = e;
      return true;
    }
  }
  auto& k = next_[static_cast<std::size_t>(e.prn)];
  slots[static_cast<std::size_t>(k)] = e;
  k = (k + 1) % kPerSat;
  return true;
}

const Ephemeris* EphemerisStore::select(int prn, double t_abs, double max_age_s) const {
  if (!is_sat_id(prn)) return nullptr;
  const Ephemeris* best = nullptr;
  double best_age = max_age_s;
  for (const auto& s : eph_[static_cast<std::size_t>(prn)]) {
    if (!s.valid() || s.health != 0) continue;
    const double age = std::abs(t_abs - s.toe_abs());
    if (age <= best_age) {
      best_age = age;
      best = &s;
    }
  }
  return best;
}

int EphemerisStore::count() const {
  int n = 0;
  for (const auto& slots : eph_)
    for (const auto& s : slots) n += s.valid();
  return n;
}

}  // namespace gpsins::gnss

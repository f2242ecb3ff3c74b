// InsFilter's tight coupling: an epoch's pseudoranges corrected and masked,
// their correlated errors' variance, GPS ranges against the clock states,
// Galileo as differences, and every system's Doppler as range rates.
#include <algorithm>
#include <cmath>
#include <limits>

#include <Eigen/Cholesky>

#include "gpsins/aiding/pseudorange.hpp"
#include "gpsins/aiding/range_rate.hpp"
#include "gpsins/aiding/time_offset.hpp"
#include "gpsins/gnss/spp.hpp"
#include "internal.hpp"

namespace gpsins {

namespace {

// The elevation's sine a correlated range error's growth at low elevation stops at (about 6 deg).
constexpr double kMinElevationSine = 0.1;

// (1 + a) / (1 - a), a = exp(-dt / tau): what a Gauss-Markov error's stationary
// variance is multiplied by when a satellite's updates dt apart are treated as
// independent. a = 0 (factor 1) without a previous update or for a white error.
double gm_update_factor(double dt, double tau) {
  if (!(dt > 0.0) || !(tau > 0.0)) return 1.0;        // dt NaN: none since acquisition
  const double one_minus_a = -std::expm1(-dt / tau);  // accurate for dt << tau
  return (2.0 - one_minus_a) / one_minus_a;
}

}  // namespace

// The variance a pseudorange's correlated errors add to this update: multipath
// (pseudorange_error_gm_*, growing as 1 / sin(elevation)) and signal in space
// (sigma sis_m, the same at any elevation; 0 when a state carries it), each
// sigma^2 (1 + a) / (1 - a) with its own tau, dt since the satellite's previous update.
template <int NB, int NC, int NT>
double InsFilter<NB, NC, NT>::correlated_variance(int prn, double t, double el_rad, double sis_m) const {
  const bool known = gnss::is_sat_id(prn);
  const double dt = known ? t - pr_used_t_[static_cast<std::size_t>(prn)] : std::numeric_limits<double>::quiet_NaN();
  double var = 0.0;
  if (cfg_.pseudorange_error_gm_sigma_m > 0.0 && known) {
    const double s = cfg_.pseudorange_error_gm_sigma_m / std::max(std::sin(el_rad), kMinElevationSine);
    var += s * s * gm_update_factor(dt, cfg_.pseudorange_error_gm_tau_s);
  }
  if (sis_m > 0.0) var += sis_m * sis_m * gm_update_factor(dt, cfg_.pseudorange_sis_tau_s);
  return var;
}

// One pseudorange as a measurement: geometry, clock, the IMU time offset's range
// rate and, when it has a slot, the satellite's signal-in-space error.
template <int NB, int NC, int NT>
Measurement<1, InsFilter<NB, NC, NT>::N> InsFilter<NB, NC, NT>::range_measurement(const PrUse& u,
                                                                                  const Vec3& v_a) const {
  if constexpr (Core::kHasClock) {
    auto m = pseudorange(core_, cfg_.lever_arm_body_m, u.sat, u.pr_corr, u.sagnac, u.var);
    add_time_offset(m, core_, es::pos, v_a, heading_known());  // the range rate the receiver's motion gives
    if constexpr (Core::kSisCount > 0) {
      if (u.sis_slot >= 0) {
        m.y(0) -= core_.sis(u.sis_slot);
        m.H(0, Core::kSis + u.sis_slot) = 1.0;
      }
    }
    return m;
  } else {
    (void)u, (void)v_a;
    return Measurement<1, N>{};
  }
}

template <int NB, int NC, int NT>
void InsFilter<NB, NC, NT>::process_pseudoranges(const PseudorangeEpoch& ep) {
  if constexpr (Core::kHasClock) {
    // A satellite settles for a while after (re)acquisition (see track_locks).
    std::array<bool, PseudorangeEpoch::kMaxSats> settled{};
    for (int i = 0; i < ep.n; ++i) {
      const int prn = ep.prn[static_cast<std::size_t>(i)];
      settled[static_cast<std::size_t>(i)] =
          gnss::is_sat_id(prn) && ep.t_s - locked_since_[static_cast<std::size_t>(prn)] >= cfg_.pseudorange_settle_s;
    }

    const double t_abs = ep.t_s + cfg_.gps_time_offset_s;
    const double tow = std::fmod(t_abs, gnss::kSecondsPerWeek);
    const Mat3 c = core_.nav.q_eb.toRotationMatrix();
    const Vec3 r_a = core_.nav.r_ecef_m + c * cfg_.lever_arm_body_m;
    const Geodetic llh = ecef_to_geodetic(r_a);
    std::array<PrUse, PseudorangeEpoch::kMaxSats> use{};
    int n = 0;
    for (int i = 0; i < ep.n; ++i) {
      const auto k = static_cast<std::size_t>(i);
      const bool doppler = cfg_.doppler_sigma_mps > 0.0 && std::isfinite(ep.doppler_hz[k]);
      if (!ep.ranges && !doppler) continue;
      gnss::SatState st;
      const gnss::Ephemeris* eph = nullptr;
      if (!gnss::sat_at_transmission(store_, ep.prn[k], t_abs, ep.pr_m[k], st, &eph)) {
        if (ep.ranges) ++counters_.pseudoranges_no_ephemeris;
        continue;
      }
      const gnss::AzEl ae = gnss::az_el(llh, r_a, st.r_ecef_m);
      if (ae.el_rad < cfg_.pseudorange_elevation_mask_rad || ep.cn0_dbhz[k] < cfg_.pseudorange_min_cn0_dbhz ||
          !settled[k]) {
        if (ep.ranges) ++counters_.pseudoranges_masked;
        continue;
      }
      PrUse& u = use[static_cast<std::size_t>(n++)];
      u = PrUse{st.r_ecef_m, 0.0, gnss::sagnac_m(st.r_ecef_m, r_a), 0.0, ep.prn[k]};
      if (ep.ranges) {
        const double iono = cfg_.pseudorange_ionosphere ? gnss::klobuchar_m(iono_, llh, ae, tow) : 0.0;
        const double trop = cfg_.pseudorange_troposphere ? gnss::saastamoinen_m(llh, ae.el_rad) : 0.0;
        // The white part without the broadcast URA: orbit and clock errors are slow (assign_sis).
        u.var = cfg_.pseudorange_sigma_m > 0.0 ? cfg_.pseudorange_sigma_m * cfg_.pseudorange_sigma_m
                                               : gnss::pseudorange_variance_m2(ae.el_rad, 0.0, iono);
        u.el_rad = ae.el_rad;
        u.eph = eph;
        // Everything but geometry and the receiver clock moved to the measurement side.
        u.pr_corr = ep.pr_m[k] + gnss::kSpeedOfLight * (st.clock_s - eph->tgd_s) - iono - trop;
      }
      if (doppler) {
        const gnss::SatMotion sm = gnss::sat_motion(*eph, t_abs - ep.pr_m[k] / gnss::kSpeedOfLight - st.clock_s);
        const double s_el = std::sin(ae.el_rad);
        u.sat_v = sm.v_ecef_mps;
        u.rate_corr = -gnss::kL1WavelengthM * ep.doppler_hz[k] + gnss::kSpeedOfLight * sm.clock_drift;
        u.rate_var = 0.5 * cfg_.doppler_sigma_mps * cfg_.doppler_sigma_mps * (1.0 + 1.0 / (s_el * s_el));
      }
    }
    if (n == 0) return;
    if (ep.ranges) assign_sis(use.data(), n, ep);
    // GPS first, Galileo after it (see update_galileo): the clock states are GPS's. In
    // each, the ranges to use before those only the Doppler is used of.
    const auto galileo_first =
        std::stable_partition(use.begin(), use.begin() + n, [](const PrUse& u) { return !gnss::is_galileo(u.prn); });
    const auto ranged = [](const PrUse& u) { return u.range; };
    const auto gps_end = std::stable_partition(use.begin(), galileo_first, ranged);
    const auto galileo_end = std::stable_partition(galileo_first, use.begin() + n, ranged);
    const int n_gps = ep.ranges ? static_cast<int>(gps_end - use.begin()) : 0;
    if (n_gps > 0) check_clock(use.data(), n_gps, ep.t_s);
    bool any = false;
    const Vec3 v_a = NT == 1 ? antenna_velocity_now() : Vec3::Zero();
    for (int i = 0; i < n_gps; ++i) {
      const auto& u = use[static_cast<std::size_t>(i)];
      const auto r = apply(range_measurement(u, v_a), 1);
      record(kPseudorange, r, 1, u.prn);
      ++(r.accepted ? counters_.pseudoranges_used : counters_.pseudoranges_rejected);
      if (r.accepted) pr_used_t_[static_cast<std::size_t>(u.prn)] = ep.t_s;
      any = any || r.accepted;
    }
    const int n_gal = ep.ranges ? static_cast<int>(galileo_end - galileo_first) : 0;
    if (n_gal >= 2) any = update_galileo(&*galileo_first, n_gal, v_a, ep.t_s) || any;
    // Every system's Doppler shares the one drift: the receiver's oscillator (GGTO's rate is nil).
    if (heading_known()) any = update_range_rates(use.data(), n) || any;
    note_gnss(any, ep.t_s);
  } else {
    (void)ep;
  }
}

// Galileo pseudoranges see the receiver clock plus the GPS-Galileo time offset
// and the receiver's own inter-system bias, neither known here. The epoch's
// differences from one Galileo satellite (the one with the smallest variance)
// carry neither: the unknown is eliminated, as a state with no prior and no
// memory would be, and Galileo adds geometry without touching the clock
// states. The differences share the reference satellite's noise, so they are
// whitened (R_d = L L^T, rows of L^-1 D) into independent scalar updates. Each
// row is formed again from the state the previous rows left (the innovations
// move with every injection; L does not depend on the state).
template <int NB, int NC, int NT>
bool InsFilter<NB, NC, NT>::update_galileo(const PrUse* use, int n, const Vec3& v_a, double t) {
  if constexpr (Core::kHasClock) {
    constexpr int kMax = PseudorangeEpoch::kMaxSats;
    using MatD = Eigen::Matrix<double, Eigen::Dynamic, Eigen::Dynamic, 0, kMax, kMax>;
    int ref = 0;
    for (int i = 1; i < n; ++i)
      if (use[i].var < use[ref].var) ref = i;
    std::array<int, kMax> other{};
    for (int i = 0, k = 0; i < n; ++i)
      if (i != ref) other[static_cast<std::size_t>(k++)] = i;
    const int nd = n - 1;
    MatD r_d = MatD::Constant(nd, nd, use[ref].var);
    for (int k = 0; k < nd; ++k) r_d(k, k) += use[other[static_cast<std::size_t>(k)]].var;
    const Eigen::LLT<MatD> llt(r_d);
    if (llt.info() != Eigen::Success) return false;
    const MatD l_inv = llt.matrixL().solve(MatD::Identity(nd, nd));
    bool any = false;
    for (int k = 0; k < nd; ++k) {
      const auto single = [&](int i) { return range_measurement(use[i], v_a); };
      const auto m_ref = single(ref);
      Measurement<1, N> m;
      for (int j = 0; j <= k; ++j) {  // L^-1 is lower triangular
        const auto m_j = single(other[static_cast<std::size_t>(j)]);
        m.y += l_inv(k, j) * (m_j.y - m_ref.y);
        m.H += l_inv(k, j) * (m_j.H - m_ref.H);
      }
      m.R(0, 0) = 1.0;
      const int prn = use[other[static_cast<std::size_t>(k)]].prn;
      const auto r = apply(m, 1);
      record(kPseudorange, r, 1, prn);
      ++(r.accepted ? counters_.pseudoranges_used : counters_.pseudoranges_rejected);
      if (r.accepted) {
        pr_used_t_[static_cast<std::size_t>(prn)] = t;
        pr_used_t_[static_cast<std::size_t>(use[ref].prn)] = t;
      }
      any = any || r.accepted;
    }
    return any;
  } else {
    (void)use, (void)n, (void)v_a, (void)t;
    return false;
  }
}

template <int NB, int NC, int NT>
bool InsFilter<NB, NC, NT>::update_range_rates(const PrUse* use, int n) {
  bool any = false;
  if constexpr (Core::kHasClock) {
    const Vec3 rate = gyro_rate_now();
    const Vec3 a_a = NT == 1 ? antenna_acceleration_now() : Vec3::Zero();
    for (int i = 0; i < n; ++i) {
      const PrUse& u = use[i];
      if (!std::isfinite(u.rate_corr)) continue;
      auto m = range_rate(core_, cfg_.lever_arm_body_m, rate, u.sat, u.sat_v, u.rate_corr, u.rate_var);
      add_time_offset(m, core_, es::vel, a_a);
      const auto r = apply(m, 1);
      record(kRangeRate, r, 1, u.prn);
      ++(r.accepted ? counters_.range_rates_used : counters_.range_rates_rejected);
      any = any || r.accepted;
    }
  } else {
    (void)use, (void)n;
  }
  return any;
}

#define GPSINS_INSTANTIATE(NB, NC, NT)                                                                                \
  template double InsFilter<NB, NC, NT>::correlated_variance(int, double, double, double) const;                      \
  template Measurement<1, InsFilter<NB, NC, NT>::N> InsFilter<NB, NC, NT>::range_measurement(                         \
      const InsFilter<NB, NC, NT>::PrUse&, const Vec3&) const;                                                        \
  template void InsFilter<NB, NC, NT>::process_pseudoranges(const PseudorangeEpoch&);                                 \
  template bool InsFilter<NB, NC, NT>::update_galileo(const InsFilter<NB, NC, NT>::PrUse*, int, const Vec3&, double); \
  template bool InsFilter<NB, NC, NT>::update_range_rates(const InsFilter<NB, NC, NT>::PrUse*, int);
GPSINS_FOR_EACH_FILTER(GPSINS_INSTANTIATE)
#undef GPSINS_INSTANTIATE

}  // namespace gpsins

// InsFilter's view of the receiver in tight coupling: lock tracking (a new
// track starts its errors afresh) and the clock states re-seeded from an
// epoch's median residual when they no longer describe the receiver's clock.
#include <algorithm>
#include <cmath>
#include <limits>

#include "internal.hpp"

namespace gpsins {

namespace {

// The squared normalised clock jump beyond which the clock is suspect when updates are not
// gated (5 sigma); four times it (10 sigma) re-seeds it at once.
constexpr double kUngatedClockBound = 25.0;
constexpr double kClockFarBeyond = 4.0;
constexpr double kMillisecond_s = 1e-3;  // a receiver's clock steers in whole milliseconds

}  // namespace

// The receiver's lock counter grows while a satellite stays locked (saturating);
// a drop, or a satellite missing from an epoch, means the lock was lost.
template <int NB, int NC, int NT>
void InsFilter<NB, NC, NT>::track_locks(const PseudorangeEpoch& ep) {
  std::array<bool, gnss::kMaxSatId + 1> seen{};
  for (int i = 0; i < ep.n; ++i) {
    const int prn = ep.prn[static_cast<std::size_t>(i)];
    if (!gnss::is_sat_id(prn)) continue;
    const auto p = static_cast<std::size_t>(prn);
    const int lock = ep.lock_count[static_cast<std::size_t>(i)];
    if (!tracked_[p] || lock < last_lock_[p]) {
      locked_since_[p] = ep.t_s;
      pr_used_t_[p] = std::numeric_limits<double>::quiet_NaN();  // a new track: its errors start afresh
    }
    last_lock_[p] = lock;
    seen[p] = true;
  }
  tracked_ = seen;
}

// The clock states describe the receiver's clock only while the epoch's
// median residual (pseudorange minus range: the clock seen through all
// satellites at once) agrees with them. It cannot on the first epoch; it does
// not after a clock jump (receivers that steer their clock step it by whole
// milliseconds) or when the oscillator drifts far beyond the drift's prior
// (1.4 us/s, 12.5 km between 30 s epochs, on a geodetic receiver): every
// pseudorange would then be gated out. So the bias is re-seeded from the
// median when it lies beyond the gate on two epochs in a row (one is a tail
// event) or far beyond it once; the drift too, from the last two medians,
// unless the step is a whole number of milliseconds.
template <int NB, int NC, int NT>
void InsFilter<NB, NC, NT>::check_clock(const PrUse* use, int n, double t) {
  if constexpr (Core::kHasClock) {
    std::array<double, PseudorangeEpoch::kMaxSats> res{}, var{};
    const Vec3 r_a = core_.nav.r_ecef_m + core_.nav.q_eb * cfg_.lever_arm_body_m;
    for (int i = 0; i < n; ++i) {
      const auto k = static_cast<std::size_t>(i);
      res[k] = use[k].pr_corr - ((use[k].sat - r_a).norm() + use[k].sagnac);
      var[k] = use[k].var;
    }
    std::nth_element(res.begin(), res.begin() + n / 2, res.begin() + n);
    std::nth_element(var.begin(), var.begin() + n / 2, var.begin() + n);
    const double median = res[static_cast<std::size_t>(n / 2)];
    const double d = median - core_.clock(0);
    const double var_d = core_.P(Core::kClock, Core::kClock) + var[static_cast<std::size_t>(n / 2)] +
                         core_.P.template block<3, 3>(es::pos, es::pos).trace() / filter_detail::kAxes;
    const double bound = gate(1) > 0.0 ? gate(1) : kUngatedClockBound;
    const double z2 = d * d / var_d;
    const bool beyond = z2 > bound;
    const bool reseed = !clock_set_ || (beyond && (clock_suspect_ || z2 > kClockFarBeyond * bound));
    clock_suspect_ = clock_set_ && beyond && !reseed;
    if (reseed) {
      const double ms_m = kMillisecond_s * gnss::kSpeedOfLight;
      const double whole_ms = std::round(d / ms_m);
      const double rest = d - whole_ms * ms_m;
      const bool ms_jump = clock_set_ && whole_ms != 0.0 && rest * rest <= bound * var_d;
      const double dt = t - last_clock_t_;
      const bool drift_from_medians = clock_set_ && !ms_jump && dt > 0.0 && dt <= cfg_.clock_reseed_window_s;
      core_.clock(0) = median;
      core_.P.row(Core::kClock).setZero();
      core_.P.col(Core::kClock).setZero();
      core_.P(Core::kClock, Core::kClock) = cfg_.clock_bias_sigma_m * cfg_.clock_bias_sigma_m;
      if (drift_from_medians) {  // centred on the two epochs' rate, within the drift's prior
        core_.clock(1) = (median - last_clock_median_m_) / dt;
        core_.P.row(Core::kClock + 1).setZero();
        core_.P.col(Core::kClock + 1).setZero();
        core_.P(Core::kClock + 1, Core::kClock + 1) = cfg_.clock_drift_sigma_mps * cfg_.clock_drift_sigma_mps;
      }
      core_.note_restart(Core::kClock, drift_from_medians ? 2 : 1);
      if (clock_set_) {
        ++counters_.clock_reseeds;
        event(kClockReseed, d);
      }
      clock_set_ = true;
    }
    last_clock_median_m_ = median;
    last_clock_t_ = t;
  } else {
    (void)use, (void)n, (void)t;
  }
}

#define GPSINS_INSTANTIATE(NB, NC, NT)                                       \
  template void InsFilter<NB, NC, NT>::track_locks(const PseudorangeEpoch&); \
  template void InsFilter<NB, NC, NT>::check_clock(const InsFilter<NB, NC, NT>::PrUse*, int, double);
GPSINS_FOR_EACH_FILTER(GPSINS_INSTANTIATE)
#undef GPSINS_INSTANTIATE

}  // namespace gpsins

// InsFilter's signal-in-space slots (pseudorange_sis_states): an epoch's ranges
// given slots (SisSlots: which satellite's broadcast orbit and clock error each of
// the tight filter's kSisSlots states carries), the highest satellites first, and
// a slot's state restarted.
#include <algorithm>
#include <limits>
#include <numeric>

#include "internal.hpp"

namespace gpsins {

// The slot holding this satellite's signal-in-space error (SisSlots), its state
// restarted when the slot is new to it or its ephemeris issue changed.
template <int NB, int NC, int NT>
int InsFilter<NB, NC, NT>::sis_slot(int prn, int iode, double t, double var_m2) {
  if constexpr (Core::kSisCount > 0) {
    using Outcome = SisSlots<kSisSlots>::Outcome;
    const auto a = sis_slots_.assign(prn, iode, t);
    switch (a.outcome) {
      case Outcome::Kept:
        break;
      case Outcome::Restarted:
        restart_sis_slot(a.slot, var_m2);
        ++counters_.sis_slots_restarted;
        break;
      case Outcome::Taken:
        restart_sis_slot(a.slot, var_m2);
        ++counters_.sis_slots_taken;
        break;
      case Outcome::None:
        ++counters_.pseudoranges_without_sis_slot;
        break;
    }
    return a.slot;
  } else {
    (void)prn, (void)iode, (void)t, (void)var_m2;
    return -1;
  }
}

// With more satellites than slots the highest keep them: they are ranged first, so
// they take what is free. A range without a slot carries its signal-in-space error in
// its variance when that error is Gauss-Markov; a constant one (tau <= 0) would average
// into the position as if white, so that range is not used (its Doppler is).
template <int NB, int NC, int NT>
void InsFilter<NB, NC, NT>::assign_sis(PrUse* use, int n, const PseudorangeEpoch& ep) {
  sis_slots_.begin_epoch(ep.t_s);
  std::array<int, PseudorangeEpoch::kMaxSats> order{};
  std::iota(order.begin(), order.begin() + n, 0);
  std::stable_sort(order.begin(), order.begin() + n, [&](int a, int b) { return use[a].el_rad > use[b].el_rad; });
  for (int j = 0; j < n; ++j) {
    PrUse& u = use[order[static_cast<std::size_t>(j)]];
    const double sis = cfg_.pseudorange_sis_use_ura ? gnss::ura_m(u.eph->ura_index) : cfg_.pseudorange_sis_sigma_m;
    if (cfg_.pseudorange_sis_states && sis > 0.0) {
      u.sis_slot = sis_slot(u.prn, u.eph->iode, ep.t_s, sis * sis);
      u.range = u.sis_slot >= 0 || cfg_.pseudorange_sis_tau_s > 0.0;
    }
    u.var += correlated_variance(u.prn, ep.t_s, u.el_rad, u.sis_slot >= 0 ? 0.0 : sis);
  }
}

// A slot's error restarts unknown within its stationary spread, uncorrelated.
template <int NB, int NC, int NT>
void InsFilter<NB, NC, NT>::restart_sis_slot(int slot, double var_m2) {
  if constexpr (Core::kSisCount > 0) {
    const int i = Core::kSis + slot;
    core_.P.row(i).setZero();
    core_.P.col(i).setZero();
    core_.P(i, i) = var_m2;
    core_.noise.sis_var(slot) = var_m2;
    core_.sis(slot) = 0.0;
    core_.note_restart(i, 1);
  } else {
    (void)slot, (void)var_m2;
  }
}

#define GPSINS_INSTANTIATE(NB, NC, NT)                                                                          \
  template int InsFilter<NB, NC, NT>::sis_slot(int, int, double, double);                                       \
  template void InsFilter<NB, NC, NT>::assign_sis(InsFilter<NB, NC, NT>::PrUse*, int, const PseudorangeEpoch&); \
  template void InsFilter<NB, NC, NT>::restart_sis_slot(int, double);
GPSINS_FOR_EACH_FILTER(GPSINS_INSTANTIATE)
#undef GPSINS_INSTANTIATE

}  // namespace gpsins

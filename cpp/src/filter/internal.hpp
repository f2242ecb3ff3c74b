// What the files of InsFilter's member definitions share (cpp/src/filter/, one
// file per concern): small helpers and the member templates every update goes through (apply, record),
// which each file instantiates for the measurements it makes.
//
// Each file defines its members and explicitly instantiates them for every
// variant (GPSINS_FOR_EACH_FILTER, filter_variants.hpp), so the twelve variants' code is compiled
// once, spread over translation units that build in parallel; ins_filter.hpp's
// extern declarations keep every other file from instantiating them again.
#pragma once

#include <cstddef>
#include <limits>

#include "gpsins/filter_variants.hpp"
#include "gpsins/ins_filter.hpp"

namespace gpsins {
namespace filter_detail {

inline Vec3 square(const Vec3& v) { return v.cwiseProduct(v); }

// Two fixes at most this far apart give a velocity by their difference (s).
inline constexpr double kMaxFixDifferenceSpan_s = 2.0;
// Per-axis means of 3-axis sums (a covariance block's trace, a squared norm).
inline constexpr double kAxes = 3.0;

}  // namespace filter_detail

// Every update's bookkeeping: its record (the update log, last_update), the counters, and
// while the heading is unknown the yaw kept out of what the update taught the other states.
template <int NB, int NC, int NT>
template <int M>
void InsFilter<NB, NC, NT>::record(int kind, const UpdateResult<M>& r, int dof, int id) {
  UpdateRecord u;
  u.t_s = core_.nav.t_s;
  u.kind = kind;
  u.id = id;
  u.dof = dof;
  u.nis = r.nis;
  u.gate = gate(dof);
  u.log_det_s = r.log_det_s;
  u.r_scale = r.r_scale;
  u.accepted = r.accepted;
  u.guarded = r.guarded;
  u.innovation.fill(std::numeric_limits<double>::quiet_NaN());
  u.innovation_sigma.fill(std::numeric_limits<double>::quiet_NaN());
  for (int i = 0; i < M && i < 3; ++i) {
    u.innovation[static_cast<std::size_t>(i)] = r.innovation(i);
    u.innovation_sigma[static_cast<std::size_t>(i)] = r.innovation_sigma(i);
  }
  if (yaw_decoupled()) decouple_yaw();
  if (!r.accepted) ++counters_.updates_rejected;
  if (r.guarded) ++counters_.updates_guarded;
  if (r.attitude_refused) ++counters_.updates_attitude_refused;
  last_update_ = u;
  if (log_) log_->push_back(u);
}

// The core's gated update; with robust_after_rejections, a run of rejections of one kind
// lets the next be used down-weighted.
template <int NB, int NC, int NT>
template <int M, int K>
UpdateResult<M> InsFilter<NB, NC, NT>::apply(const Measurement<M, K>& m, int dof, int robust_kind, bool standstill) {
  const double g = cfg_.gate_standstill_only && !standstill ? 0.0 : gate(dof);
  const auto r = core_.update(m.y, m.H, m.R, g, attitude_limit());
  if (robust_kind <= 0 || cfg_.robust_after_rejections <= 0 || !(g > 0.0)) return r;
  int& in_row = rejections_in_row_[static_cast<std::size_t>(robust_kind)];
  const bool beyond_gate = !r.accepted && !r.guarded && !r.attitude_refused;
  if (!beyond_gate) {
    if (r.accepted) in_row = 0;
    return r;
  }
  if (++in_row <= cfg_.robust_after_rejections) return r;
  // A run of rejections says the filter, not this measurement, is off: use it with R
  // scaled so that its NIS would sit at the gate were the prediction exact.
  const double scale = r.nis / g;
  auto used = core_.update(m.y, m.H, (m.R * scale).eval(), 0.0, attitude_limit());
  used.nis = r.nis;  // the measurement's consistency, as the unscaled model saw it
  used.log_det_s = r.log_det_s;
  used.r_scale = scale;
  if (used.accepted) ++counters_.updates_downweighted;
  return used;
}

}  // namespace gpsins

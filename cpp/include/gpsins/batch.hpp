// Batch runs: the loop that feeds tables of inputs (rows of doubles, as NumPy
// hands them over) through a filter in time order, and what it gives back: the
// state rows, covariances, update log, events, and the first input the filter
// refused. The bindings only convert NumPy arrays to tables and the result to
// Python objects; the filter variants (AnyFilter) are chosen here from the
// configuration.
#pragma once

#include <cstddef>
#include <cstdint>
#include <memory>
#include <string>
#include <variant>
#include <vector>

#include "gpsins/ins_filter.hpp"

namespace gpsins {

// Any of the filters the core builds (filter_variants.hpp): make_filter picks the one a
// configuration needs.
#define GPSINS_FILTER_TYPE(NB, NC, NT) InsFilter<NB, NC, NT>
using AnyFilter = std::variant<GPSINS_FILTER_LIST(GPSINS_FILTER_TYPE, GPSINS_COMMA_SEPARATOR)>;
#undef GPSINS_FILTER_TYPE
AnyFilter make_filter(const InsConfig& cfg, bool tight);

// The tables' columns.
namespace batch_cols {
inline constexpr int kImu = 7;                 // t, dtheta xyz, dv xyz
inline constexpr int kFix = 10;                // t, r xyz, v xyz, hdop, vdop, mode
inline constexpr int kFixSigma = 16;           // then sigma n, e, d (m) and sigma vn, ve, vd (m/s): NaN or <= 0 none
inline constexpr int kPseudorange = 5;         // t, prn, pseudorange, C/N0, lock count
inline constexpr int kPseudorangeDoppler = 6;  // then Doppler (Hz, positive approaching; NaN: none)
inline constexpr int kAttitude = 5;            // t, yaw, pitch (NaN: none), sigma yaw, sigma pitch (rad)
}  // namespace batch_cols

// A row of the fix table (kFix or kFixSigma columns); a mode that is not finite is no solution.
FixInput fix_of_row(const double* p, int cols);
// Rows [start, end) of a pseudorange table with the same time, as one epoch.
PseudorangeEpoch pseudorange_epoch_of_rows(const double* p, std::ptrdiff_t start, std::ptrdiff_t end, int cols);

// CPU time of the calling thread (s): on a shared machine the figure to compare,
// where wall time counts the waits for a core and process time other threads' work.
double thread_cpu_s();

// A row-major table of doubles.
struct BatchTable {
  const double* data = nullptr;
  std::ptrdiff_t rows = 0;
  int cols = 0;
};

struct BatchInputs {
  BatchTable imu, fixes, pseudoranges, attitude;
};

// Input rows of this call within the whole run, for output decimation and messages.
struct RowOffsets {
  std::ptrdiff_t imu = 0, fixes = 0, prs = 0, att = 0;
};

struct BatchOptions {
  int output_every = 1;
  bool covariance = false;
  // With covariance: only the navigation block (attitude, velocity, position errors, and the IMU
  // time offset last when it is a state), 9 or 10 states instead of up to 50: what a replay's
  // sigmas and NEES take, at a small part of the copying.
  bool covariance_navigation = false;
  bool record = false;  // keep (or go on keeping) the smoother's record of the forward pass
  double smooth_chunk_mb = 256.0;
};

// The navigation block of a covariance (BatchOptions::covariance_navigation): attitude,
// velocity and position, then the IMU time offset (the last state) when NT = 1, written
// row-major at out.
template <int NT>
inline constexpr int kNavigationDim = es::kNavStates + NT;
// The navigation block's states (write_navigation_block's) as a mask, bit i for state i of N.
template <int N, int NT>
inline constexpr std::uint64_t kNavigationStates = ((std::uint64_t(1) << es::kNavStates) - 1) |
                                                   (NT == 1 ? std::uint64_t(1) << (N - 1) : 0);
template <int NT, int N>
void write_navigation_block(const Eigen::Matrix<double, N, N>& P, double* out) {
  constexpr int kNav = kNavigationDim<NT>, k9 = es::kNavStates;
  Eigen::Map<Eigen::Matrix<double, kNav, kNav, Eigen::RowMajor>> c(out);
  c.template topLeftCorner<k9, k9>() = P.template topLeftCorner<k9, k9>();
  if constexpr (NT == 1) {
    c.template topRightCorner<k9, 1>() = P.template topRightCorner<k9, 1>();
    c.template bottomLeftCorner<1, k9>() = P.template bottomLeftCorner<1, k9>();
    c(kNav - 1, kNav - 1) = P(N - 1, N - 1);
  }
}

// What a filter carries from one batch call to the next: the smoother's record
// of the forward pass (its type follows the filter's, so it is kept type-erased)
// and the forward wall time so far.
struct BatchCarry {
  std::shared_ptr<void> recorder;
  double forward_s = 0.0;
  double forward_cpu_s = 0.0;  // thread CPU time (thread_cpu_s)
};

struct BatchResult {
  // Row layout of the state output: t, r, v, q, bg, ba, [sg, sa], the NC augmented
  // states (tight: the signal-in-space slots, clock bias and drift; loose: the fix
  // error), [the time offset], sigmas, flags (1: standstill, 2: heading known).
  std::vector<double> state;
  int state_cols = 0;
  std::vector<double> covariance;  // covariance_dim^2 per state row, row-major (BatchOptions::covariance)
  int covariance_dim = 0;          // n_states, or the navigation block's 9 or 10
  int n_states = 0;
  std::vector<UpdateRecord> updates;
  std::vector<FilterEvent> events;
  Counters counters;
  std::ptrdiff_t fixes_after_end = 0;
  // The first input the filter refused (status Ok: none): its table, its row within the whole run, its time.
  InputStatus bad = InputStatus::Ok;
  const char* bad_what = nullptr;
  std::ptrdiff_t bad_row = -1;
  double bad_t = 0.0;
};

// One batch call: every sample, fix, pseudorange epoch and attitude of the tables
// in time order. A run may be split into consecutive calls (the fixes and
// pseudoranges of each call those up to its last IMU time); the result is then
// the same as one call over the whole tables. It stops at the first input the
// filter refuses (BatchResult::bad). Touches no Python object: the bindings run
// it without the GIL.
template <int NB, int NC, int NT>
BatchResult run_batch(InsFilter<NB, NC, NT>& f, const BatchInputs& in, const BatchOptions& opt, BatchCarry& carry,
                      const RowOffsets& offset);

#define GPSINS_RUN_BATCH_EXTERN(NB, NC, NT)                                                                           \
  extern template BatchResult run_batch(InsFilter<NB, NC, NT>&, const BatchInputs&, const BatchOptions&, BatchCarry&, \
                                        const RowOffsets&);
GPSINS_FOR_EACH_FILTER(GPSINS_RUN_BATCH_EXTERN)
#undef GPSINS_RUN_BATCH_EXTERN

}  // namespace gpsins

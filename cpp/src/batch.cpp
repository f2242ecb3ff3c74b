// Batch runs (batch.hpp): the filter chosen from the configuration, the tables'
// rows as the filter's inputs, and the loop that feeds them through it in time
// order, for each of the twelve filters.
#include "gpsins/batch.hpp"

#include <chrono>
#include <cmath>
#include <ctime>
#if defined(__unix__) || defined(__APPLE__)
#include <time.h>
#endif

#include "filter/internal.hpp"
#include "gpsins/rts.hpp"

namespace gpsins {

namespace {

template <int NT>
AnyFilter make_filter_nt(const InsConfig& cfg, bool tight) {
  if (tight) {
    if (cfg.scale_factor_states) return InsFilter<7, kTightAugmented, NT>(cfg);
    return InsFilter<5, kTightAugmented, NT>(cfg);
  }
  if ((cfg.fix_error_gm_sigma_m.array() > 0.0).any()) {
    if (cfg.scale_factor_states) return InsFilter<7, 3, NT>(cfg);
    return InsFilter<5, 3, NT>(cfg);
  }
  if (cfg.scale_factor_states) return InsFilter<7, 0, NT>(cfg);
  return InsFilter<5, 0, NT>(cfg);
}

// The state output's row (BatchResult::state).
template <int NB, int NC, int NT>
struct StateRow {
  static constexpr int N = 3 * NB + NC + NT;
  static constexpr int kCols = 1 + 3 + 3 + 4 + 3 + 3 + (NB == 7 ? 6 : 0) + NC + NT + N + 1;
  static void write(const InsFilter<NB, NC, NT>& f, double* o) {
    const auto& e = f.core();
    int k = 0;
    o[k++] = e.nav.t_s;
    for (int i = 0; i < 3; ++i) o[k++] = e.nav.r_ecef_m(i);
    for (int i = 0; i < 3; ++i) o[k++] = e.nav.v_ecef_mps(i);
    o[k++] = e.nav.q_eb.w();
    o[k++] = e.nav.q_eb.x();
    o[k++] = e.nav.q_eb.y();
    o[k++] = e.nav.q_eb.z();
    for (int i = 0; i < 3; ++i) o[k++] = e.imu.gyro_bias_rad_per_s(i);
    for (int i = 0; i < 3; ++i) o[k++] = e.imu.accel_bias_mps2(i);
    if constexpr (NB == 7) {
      for (int i = 0; i < 3; ++i) o[k++] = e.imu.gyro_scale_factor(i);
      for (int i = 0; i < 3; ++i) o[k++] = e.imu.accel_scale_factor(i);
    }
    if constexpr (Eskf<NB, NC, NT>::kSisCount > 0)
      for (int i = 0; i < Eskf<NB, NC, NT>::kSisCount; ++i) o[k++] = e.sis(i);
    if constexpr (Eskf<NB, NC, NT>::kHasClock) {
      o[k++] = e.clock(0);
      o[k++] = e.clock(1);
    }
    if constexpr (NC == 3)
      for (int i = 0; i < 3; ++i) o[k++] = e.fix_error(i);
    if constexpr (NT == 1) o[k++] = e.time_offset_s;
    const auto s = e.sigma();
    for (int i = 0; i < N; ++i) o[k++] = s(i);
    o[k++] = (f.standstill() ? kRowFlagStandstill : 0) + (f.heading_known() ? kRowFlagHeadingKnown : 0);  // flags
  }
};

constexpr double kBytesPerMb = 1048576.0;

}  // namespace

AnyFilter make_filter(const InsConfig& cfg, bool tight) {
  return cfg.estimate_time_offset ? make_filter_nt<1>(cfg, tight) : make_filter_nt<0>(cfg, tight);
}

FixInput fix_of_row(const double* p, int cols) {
  FixInput f;
  f.t_s = p[0];
  f.r_ecef_m = Vec3(p[1], p[2], p[3]);
  f.v_ecef_mps = Vec3(p[4], p[5], p[6]);
  f.hdop = p[7];
  f.vdop = p[8];
  f.mode = std::isfinite(p[9]) ? static_cast<int>(p[9]) : kFixModeNone;
  if (cols == batch_cols::kFixSigma) {
    f.sigma_ned_m = Vec3(p[10], p[11], p[12]);
    f.sigma_v_ned_mps = Vec3(p[13], p[14], p[15]);
  }
  return f;
}

PseudorangeEpoch pseudorange_epoch_of_rows(const double* p, std::ptrdiff_t start, std::ptrdiff_t end, int cols) {
  PseudorangeEpoch ep;
  ep.t_s = p[start * cols];
  for (std::ptrdiff_t r = start; r < end && ep.n < PseudorangeEpoch::kMaxSats; ++r) {
    const double* row = p + r * cols;
    const auto k = static_cast<std::size_t>(ep.n++);
    ep.prn[k] = static_cast<int>(row[1]);
    ep.pr_m[k] = row[2];
    ep.cn0_dbhz[k] = row[3];
    ep.lock_count[k] = static_cast<int>(row[4]);
    if (cols == batch_cols::kPseudorangeDoppler) ep.doppler_hz[k] = row[5];
  }
  return ep;
}

double thread_cpu_s() {
#if defined(CLOCK_THREAD_CPUTIME_ID)
  timespec ts{};
  clock_gettime(CLOCK_THREAD_CPUTIME_ID, &ts);
  return static_cast<double>(ts.tv_sec) + 1e-9 * static_cast<double>(ts.tv_nsec);
#else
  return static_cast<double>(std::clock()) / CLOCKS_PER_SEC;
#endif
}

template <int NB, int NC, int NT>
BatchResult run_batch(InsFilter<NB, NC, NT>& f, const BatchInputs& in, const BatchOptions& opt, BatchCarry& carry,
                      const RowOffsets& offset) {
  using Row = StateRow<NB, NC, NT>;
  constexpr int N = Row::N;
  BatchResult out;
  out.state_cols = Row::kCols;
  out.n_states = N;
  const std::ptrdiff_t n = in.imu.rows, m = in.fixes.rows;
  const int fc = in.fixes.cols;
  const int output_every = opt.output_every;
  std::vector<double>& rows = out.state;
  rows.reserve(static_cast<std::size_t>((n / output_every + 1) * Row::kCols));
  std::vector<double>& covs = out.covariance;
  // The navigation block: attitude, velocity and position (the first nine error states), then
  // the time offset (the last state) when NT = 1.
  constexpr int kNav = kNavigationDim<NT>;
  const int cov_dim = opt.covariance_navigation ? kNav : N;
  out.covariance_dim = opt.covariance ? cov_dim : 0;
  if (opt.covariance) covs.reserve(static_cast<std::size_t>((n / output_every + 1) * cov_dim * cov_dim));
  out.updates.reserve(static_cast<std::size_t>(m * 2 + n / 8 + 16));
  f.set_update_log(&out.updates);
  f.set_event_log(&out.events);
  const double* pi = in.imu.data;
  const double* pf = in.fixes.data;
  const double* pp = in.pseudoranges.data;
  const std::ptrdiff_t np_rows = in.pseudoranges.rows;
  const int pc = in.pseudoranges.cols;
  const double* pa = in.attitude.data;
  const std::ptrdiff_t na_rows = in.attitude.rows;
  std::ptrdiff_t j = 0, q = 0, g = 0;
  using Recorder = EskfRecorder<NB, NC, NT>;
  if (opt.record && !carry.recorder)
    carry.recorder = std::make_shared<Recorder>(static_cast<std::size_t>(opt.smooth_chunk_mb * kBytesPerMb));
  // The filter's type never changes, so the recorder is the one made above for it.
  Recorder* rec = opt.record ? static_cast<Recorder*>(carry.recorder.get()) : nullptr;
  if (rec) f.set_observer(rec);
  auto refuse = [&](InputStatus s, const char* what, std::ptrdiff_t row, double t) {
    out.bad = s;
    out.bad_what = what;
    out.bad_row = row;
    out.bad_t = t;
  };
  const auto t_forward = std::chrono::steady_clock::now();
  const double c_forward = thread_cpu_s();
  for (std::ptrdiff_t k = 0; k < n && out.bad == InputStatus::Ok; ++k) {
    const double* r = pi + k * batch_cols::kImu;
    // Fixes up to this sample's time go first: the filter holds them until the
    // increment that spans their time arrives, and splits it there.
    while (j < m && pf[j * fc] <= r[0]) {
      const InputStatus s = f.push_fix(fix_of_row(pf + j * fc, fc));
      if (s != InputStatus::Ok) {
        refuse(s, "fixes", offset.fixes + j, pf[j * fc]);
        break;
      }
      ++j;
    }
    if (out.bad != InputStatus::Ok) break;
    while (q < np_rows && pp[q * pc] <= r[0]) {
      std::ptrdiff_t e = q + 1;
      while (e < np_rows && pp[e * pc] == pp[q * pc]) ++e;
      const InputStatus s = f.push_pseudoranges(pseudorange_epoch_of_rows(pp, q, e, pc));
      if (s != InputStatus::Ok) {
        refuse(s, "pseudoranges", offset.prs + q, pp[q * pc]);
        break;
      }
      q = e;
    }
    if (out.bad != InputStatus::Ok) break;
    while (g < na_rows && pa[g * batch_cols::kAttitude] <= r[0]) {
      const double* a = pa + g * batch_cols::kAttitude;
      const InputStatus s = f.push_attitude(AttitudeInput{a[0], a[1], a[2], a[3], a[4]});
      if (s != InputStatus::Ok) {
        refuse(s, "attitude", offset.att + g, a[0]);
        break;
      }
      ++g;
    }
    if (out.bad != InputStatus::Ok) break;
    const InputStatus s = f.push_imu(r[0], Vec3(r[1], r[2], r[3]), Vec3(r[4], r[5], r[6]));
    if (s != InputStatus::Ok) {
      refuse(s, "imu", offset.imu + k, r[0]);
      break;
    }
    if (f.initialised() && (offset.imu + k) % output_every == 0) {
      // A smoother's record needs the covariance of the epoch itself; otherwise an epoch between two
      // covariance steps (covariance_interval_s) reports the last step's, at most that interval old.
      if (rec) f.flush_covariance();
      const std::size_t at = rows.size();
      rows.resize(at + Row::kCols);
      Row::write(f, rows.data() + at);
      if (opt.covariance) {
        const std::size_t c0 = covs.size();
        const auto& P = f.core().P;
        if (opt.covariance_navigation) {
          covs.resize(c0 + kNav * kNav);
          write_navigation_block<NT>(P, covs.data() + c0);
        } else {
          covs.resize(c0 + N * N);
          Eigen::Map<Eigen::Matrix<double, N, N, Eigen::RowMajor>>(covs.data() + c0) = P;
        }
      }
      if (rec) rec->output(f.core(), rows[rows.size() - 1]);
    }
  }
  f.set_observer(nullptr);
  carry.forward_s += std::chrono::duration<double>(std::chrono::steady_clock::now() - t_forward).count();
  carry.forward_cpu_s += thread_cpu_s() - c_forward;
  f.set_update_log(nullptr);
  f.set_event_log(nullptr);
  out.counters = f.counters();
  out.fixes_after_end = m - j;
  return out;
}

#define GPSINS_INSTANTIATE(NB, NC, NT)                                                                         \
  template BatchResult run_batch(InsFilter<NB, NC, NT>&, const BatchInputs&, const BatchOptions&, BatchCarry&, \
                                 const RowOffsets&);
GPSINS_FOR_EACH_FILTER(GPSINS_INSTANTIATE)
#undef GPSINS_INSTANTIATE

}  // namespace gpsins

// pybind11 face of the integrated filter: InsConfig, a streaming InsFilter and
// a batch run() that loops in C++ over NumPy arrays. Input errors raise
// ValueError naming the array, the row and the reason.
#include <pybind11/eigen.h>
#include <pybind11/numpy.h>
#include <pybind11/pybind11.h>
#include <pybind11/stl.h>

#include <chrono>
#include <ctime>
#if defined(__unix__) || defined(__APPLE__)
#include <time.h>
#endif
#include <limits>
#include <memory>
#include <string>
#include <variant>
#include <vector>

#include "gpsins/gnss/ephemeris.hpp"
#include "gpsins/ins_filter.hpp"
#include "gpsins/rts.hpp"

namespace py = pybind11;

// CPU time of the calling thread (s): on a shared machine the figure to compare,
// where wall time counts the waits for a core and process time other threads' work.
static double thread_cpu_s() {
#if defined(CLOCK_THREAD_CPUTIME_ID)
  timespec ts{};
  clock_gettime(CLOCK_THREAD_CPUTIME_ID, &ts);
  return static_cast<double>(ts.tv_sec) + 1e-9 * static_cast<double>(ts.tv_nsec);
#else
  return static_cast<double>(std::clock()) / CLOCKS_PER_SEC;
#endif
}
using namespace gpsins;

namespace {

using Array = py::array_t<double, py::array::c_style | py::array::forcecast>;
constexpr int kTight = kTightAugmented;
using AnyFilter =
    std::variant<InsFilter<5, 0>, InsFilter<7, 0>, InsFilter<5, kTight>, InsFilter<7, kTight>, InsFilter<5, 3>,
                 InsFilter<7, 3>, InsFilter<5, 0, 1>, InsFilter<7, 0, 1>, InsFilter<5, kTight, 1>,
                 InsFilter<7, kTight, 1>, InsFilter<5, 3, 1>, InsFilter<7, 3, 1>>;

// Tight: signal-in-space slots and clock states (NC = kTightAugmented). Loose: fix-error
// states (NC = 3) when configured.
// NT = 1: the IMU time offset state.
template <int NT>
AnyFilter make_filter_nt(const InsConfig& cfg, bool tight) {
  if (tight) {
    if (cfg.scale_factor_states) return InsFilter<7, kTight, NT>(cfg);
    return InsFilter<5, kTight, NT>(cfg);
  }
  if ((cfg.fix_error_gm_sigma_m.array() > 0.0).any()) {
    if (cfg.scale_factor_states) return InsFilter<7, 3, NT>(cfg);
    return InsFilter<5, 3, NT>(cfg);
  }
  if (cfg.scale_factor_states) return InsFilter<7, 0, NT>(cfg);
  return InsFilter<5, 0, NT>(cfg);
}
AnyFilter make_filter(const InsConfig& cfg, bool tight) {
  return cfg.estimate_time_offset ? make_filter_nt<1>(cfg, tight) : make_filter_nt<0>(cfg, tight);
}

constexpr int kImuCols = 7;        // t, dtheta xyz, dv xyz
constexpr int kFixCols = 10;       // t, r xyz, v xyz, hdop, vdop, mode
constexpr int kFixColsSigma = 16;  // then sigma n, e, d (m) and sigma vn, ve, vd (m/s): NaN or <= 0 none
constexpr int kPrCols = 5;         // t, prn, pseudorange, C/N0, lock count
constexpr int kPrColsDoppler = 6;  // then Doppler (Hz, positive approaching; NaN: none)
constexpr int kAttCols = 5;        // t, yaw, pitch (NaN: none), sigma yaw, sigma pitch (rad)

FixInput fix_of(const double* p, int cols) {
  FixInput f;
  f.t_s = p[0];
  f.r_ecef_m = Vec3(p[1], p[2], p[3]);
  f.v_ecef_mps = Vec3(p[4], p[5], p[6]);
  f.hdop = p[7];
  f.vdop = p[8];
  f.mode = std::isfinite(p[9]) ? static_cast<int>(p[9]) : kFixModeNone;
  if (cols == kFixColsSigma) {
    f.sigma_ned_m = Vec3(p[10], p[11], p[12]);
    f.sigma_v_ned_mps = Vec3(p[13], p[14], p[15]);
  }
  return f;
}

[[noreturn]] void input_error(const char* what, py::ssize_t row, double t, InputStatus s) {
  throw py::value_error(std::string(what) + " row " + std::to_string(row) + " (t = " + std::to_string(t) +
                        " s): " + input_status_text(s));
}

Array table(py::handle obj, int cols, const char* name, int alt_cols = -1) {
  Array a = Array::ensure(obj);
  if (!a) throw py::type_error(std::string(name) + ": not convertible to a float array");
  if (a.ndim() == 2 && alt_cols > 0 && a.shape(1) == alt_cols) return a;
  if (a.ndim() != 2 || a.shape(1) != cols)
    throw py::value_error(std::string(name) + ": expected shape (n, " + std::to_string(cols) +
                          (alt_cols > 0 ? ") or (n, " + std::to_string(alt_cols) : std::string()) + "), got ndim " +
                          std::to_string(a.ndim()) +
                          (a.ndim() == 2 ? ", " + std::to_string(a.shape(1)) + " columns" : ""));
  return a;
}

py::dict counters_dict(const Counters& c) {
  py::dict d;
#define GPSINS_COUNTER_ITEM(name) d[#name] = c.name;
  GPSINS_COUNTERS(GPSINS_COUNTER_ITEM)
#undef GPSINS_COUNTER_ITEM
  d["diverged"] = c.diverged;
  return d;
}

py::dict update_dict(const UpdateRecord& u) {
  py::dict d;
  d["t"] = u.t_s;
  d["kind"] = u.kind;
  d["id"] = u.id;
  d["dof"] = u.dof;
  d["nis"] = u.nis;
  d["gate"] = u.gate;
  d["log_det_s"] = u.log_det_s;
  d["r_scale"] = u.r_scale;
  d["accepted"] = u.accepted;
  d["guarded"] = u.guarded;
  d["innovation"] = py::make_tuple(u.innovation[0], u.innovation[1], u.innovation[2]);
  d["innovation_sigma"] = py::make_tuple(u.innovation_sigma[0], u.innovation_sigma[1], u.innovation_sigma[2]);
  return d;
}

// Row layout of a batch's state output: t, r, v, q, bg, ba, [sg, sa], the NC
// augmented states (tight: the signal-in-space slots, clock bias and drift; loose: the fix error),
// [the time offset], sigmas, flags.
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

Array from_rows(const std::vector<double>& v, py::ssize_t cols) {
  const py::ssize_t n = static_cast<py::ssize_t>(v.size()) / cols;
  Array a({n, cols});
  std::copy(v.begin(), v.end(), a.mutable_data());
  return a;
}

// Rows [start, end) of a pseudorange table with the same time, as one epoch.
PseudorangeEpoch pr_epoch(const double* p, py::ssize_t start, py::ssize_t end, int cols) {
  PseudorangeEpoch ep;
  ep.t_s = p[start * cols];
  for (py::ssize_t r = start; r < end && ep.n < PseudorangeEpoch::kMaxSats; ++r) {
    const double* row = p + r * cols;
    const auto k = static_cast<std::size_t>(ep.n++);
    ep.prn[k] = static_cast<int>(row[1]);
    ep.pr_m[k] = row[2];
    ep.cn0_dbhz[k] = row[3];
    ep.lock_count[k] = static_cast<int>(row[4]);
    if (cols == kPrColsDoppler) ep.doppler_hz[k] = row[5];
  }
  return ep;
}

// Backward pass over a recorded run. Rows come newest first; they are gathered
// into blocks of block_rows, each in time order, and a block is handed to
// sink(dict(state=..., covariance=..., first=index of its first row)) as soon
// as it is complete, so the caller can write it out. With no sink the whole
// smoothed run is returned as smooth_state / smooth_covariance.
template <int NB, int NC, int NT>
py::dict smooth_recorded(EskfRecorder<NB, NC, NT>& rec, bool with_cov, py::object sink, long block_rows) {
  using Rec = EskfRecorder<NB, NC, NT>;
  constexpr int N = Rec::N, kNom = Rec::kNominal;
  constexpr int kCols = kNom + N;  // nominal without flags, sigma, flags
  const long n = rec.outputs();
  const bool streaming = !sink.is_none();
  const long rows = streaming ? std::max(1L, std::min(block_rows, n)) : n;
  auto new_block = [&](long len) {
    return std::make_pair(Array({static_cast<py::ssize_t>(len), py::ssize_t(kCols)}),
                          Array(with_cov ? std::vector<py::ssize_t>{len, N, N} : std::vector<py::ssize_t>{0, N, N}));
  };
  long lo = std::max(0L, n - rows);  // rows [lo, hi) are being filled
  auto block = new_block(n - lo);
  const auto t0 = std::chrono::steady_clock::now();
  const double c0 = thread_cpu_s();
  double sink_s = 0.0, sink_cpu_s = 0.0;  // the caller's work on the blocks, not the smoother's
  {
    py::gil_scoped_release release;
    rec.smooth([&](long k, const double* row, const Eigen::Matrix<double, N, N>& p) {
      double* o = block.first.mutable_data() + (k - lo) * kCols;
      std::copy(row, row + kNom - 1, o);
      for (int i = 0; i < N; ++i) o[kNom - 1 + i] = std::sqrt(std::max(p(i, i), 0.0));
      o[kCols - 1] = row[kNom - 1];
      if (with_cov)
        Eigen::Map<Eigen::Matrix<double, N, N, Eigen::RowMajor>>(block.second.mutable_data() + (k - lo) * N * N) = p;
      if (streaming && k == lo) {
        py::gil_scoped_acquire acquire;
        py::dict b;
        b["state"] = block.first;
        if (with_cov) b["covariance"] = block.second;
        b["first"] = lo;
        const auto s0 = std::chrono::steady_clock::now();
        const double sc0 = thread_cpu_s();
        sink(b);
        sink_cpu_s += thread_cpu_s() - sc0;
        sink_s += std::chrono::duration<double>(std::chrono::steady_clock::now() - s0).count();
        const long next_lo = std::max(0L, lo - rows);
        if (lo > 0) block = new_block(lo - next_lo);
        lo = next_lo;
      }
    });
  }
  const double backward_s = std::chrono::duration<double>(std::chrono::steady_clock::now() - t0).count() - sink_s;
  const double backward_cpu_s = thread_cpu_s() - c0 - sink_cpu_s;
  py::dict out;
  if (!streaming) {
    out["smooth_state"] = block.first;
    if (with_cov) out["smooth_covariance"] = block.second;
  }
  py::dict info;
  info["tape_bytes"] = rec.tape().bytes();
  info["spilled_bytes"] = rec.tape().spilled_bytes();
  info["chunks_spilled"] = rec.tape().chunks_spilled();
  info["outputs"] = n;
  info["backward_s"] = backward_s;
  info["backward_cpu_s"] = backward_cpu_s;
  info["sink_s"] = sink_s;  // wall time in sink, left out of backward_s
  out["smooth_info"] = info;
  return out;
}

// What a filter carries from one batch call to the next: the smoother's record
// of the forward pass (its type follows the filter's, so it is kept type-erased)
// and the forward wall time so far.
struct BatchCarry {
  std::shared_ptr<void> recorder;
  double forward_s = 0.0;
  double forward_cpu_s = 0.0;  // thread CPU time (thread_cpu_s)
};

// The recorder run_batch made for this filter type.
template <int NB, int NC, int NT>
EskfRecorder<NB, NC, NT>* recorder_of(const InsFilter<NB, NC, NT>&, void* p) {
  return static_cast<EskfRecorder<NB, NC, NT>*>(p);
}

// Input rows of this call within the whole run, for output decimation and messages.
struct RowOffsets {
  py::ssize_t imu = 0, fixes = 0, prs = 0, att = 0;
};

// One batch call: every sample, fix and pseudorange epoch of the arrays in time
// order. A run may be split into consecutive calls (the fixes and pseudoranges
// of each call those up to its last IMU time); the result is then the same as
// one call over the whole arrays. record: keep (or go on keeping) the
// smoother's record of the forward pass in carry.
template <int NB, int NC, int NT>
py::dict run_batch(InsFilter<NB, NC, NT>& f, const Array& imu, const Array& fixes, const Array& prs, const Array& att,
                   int output_every, bool with_cov, bool record, double smooth_chunk_mb, BatchCarry& carry,
                   const RowOffsets& offset) {
  using Row = StateRow<NB, NC, NT>;
  const py::ssize_t n = imu.shape(0), m = fixes.shape(0);
  const int fc = static_cast<int>(fixes.shape(1));
  std::vector<double> rows;
  rows.reserve(static_cast<std::size_t>((n / output_every + 1) * Row::kCols));
  constexpr int N = Row::N;
  std::vector<double> covs;
  if (with_cov) covs.reserve(static_cast<std::size_t>((n / output_every + 1) * N * N));
  std::vector<UpdateRecord> log;
  log.reserve(static_cast<std::size_t>(m * 2 + n / 8 + 16));
  f.set_update_log(&log);
  std::vector<FilterEvent> events;
  f.set_event_log(&events);
  const double* pi = imu.data();
  const double* pf = fixes.data();
  const double* pp = prs.data();
  const py::ssize_t np_rows = prs.shape(0);
  const int pc = static_cast<int>(prs.shape(1));
  const double* pa = att.data();
  const py::ssize_t na_rows = att.shape(0);
  py::ssize_t j = 0, q = 0, g = 0, bad_row = -1;
  const char* bad_what = nullptr;
  double bad_t = 0.0;
  InputStatus bad = InputStatus::Ok;
  using Recorder = EskfRecorder<NB, NC, NT>;
  if (record && !carry.recorder)
    carry.recorder = std::make_shared<Recorder>(static_cast<std::size_t>(smooth_chunk_mb * 1048576.0));
  // The filter's type never changes, so the recorder is the one made above for it.
  Recorder* rec = record ? static_cast<Recorder*>(carry.recorder.get()) : nullptr;
  if (rec) f.set_observer(rec);
  const auto t_forward = std::chrono::steady_clock::now();
  const double c_forward = thread_cpu_s();
  {
    py::gil_scoped_release release;
    for (py::ssize_t k = 0; k < n && bad == InputStatus::Ok; ++k) {
      const double* r = pi + k * kImuCols;
      // Fixes up to this sample's time go first: the filter holds them until the
      // increment that spans their time arrives, and splits it there.
      while (j < m && pf[j * fc] <= r[0]) {
        const InputStatus s = f.push_fix(fix_of(pf + j * fc, fc));
        if (s != InputStatus::Ok) {
          bad = s;
          bad_row = offset.fixes + j;
          bad_what = "fixes";
          bad_t = pf[j * fc];
          break;
        }
        ++j;
      }
      if (bad != InputStatus::Ok) break;
      while (q < np_rows && pp[q * pc] <= r[0]) {
        py::ssize_t e = q + 1;
        while (e < np_rows && pp[e * pc] == pp[q * pc]) ++e;
        const InputStatus s = f.push_pseudoranges(pr_epoch(pp, q, e, pc));
        if (s != InputStatus::Ok) {
          bad = s;
          bad_row = offset.prs + q;
          bad_what = "pseudoranges";
          bad_t = pp[q * pc];
          break;
        }
        q = e;
      }
      if (bad != InputStatus::Ok) break;
      while (g < na_rows && pa[g * kAttCols] <= r[0]) {
        const double* a = pa + g * kAttCols;
        const InputStatus s = f.push_attitude(AttitudeInput{a[0], a[1], a[2], a[3], a[4]});
        if (s != InputStatus::Ok) {
          bad = s;
          bad_row = offset.att + g;
          bad_what = "attitude";
          bad_t = a[0];
          break;
        }
        ++g;
      }
      if (bad != InputStatus::Ok) break;
      const InputStatus s = f.push_imu(r[0], Vec3(r[1], r[2], r[3]), Vec3(r[4], r[5], r[6]));
      if (s != InputStatus::Ok) {
        bad = s;
        bad_row = offset.imu + k;
        bad_what = "imu";
        bad_t = r[0];
        break;
      }
      if (f.initialised() && (offset.imu + k) % output_every == 0) {
        const std::size_t at = rows.size();
        rows.resize(at + Row::kCols);
        Row::write(f, rows.data() + at);
        if (with_cov) {
          const std::size_t c0 = covs.size();
          covs.resize(c0 + N * N);
          Eigen::Map<Eigen::Matrix<double, N, N, Eigen::RowMajor>>(covs.data() + c0) = f.core().P;
        }
        if (rec) rec->output(f.core(), rows[rows.size() - 1]);
      }
    }
  }
  f.set_observer(nullptr);
  carry.forward_s += std::chrono::duration<double>(std::chrono::steady_clock::now() - t_forward).count();
  carry.forward_cpu_s += thread_cpu_s() - c_forward;
  f.set_update_log(nullptr);
  f.set_event_log(nullptr);
  if (bad != InputStatus::Ok) input_error(bad_what, bad_row, bad_t, bad);

  py::dict out;
  out["state"] = from_rows(rows, Row::kCols);
  if (with_cov) {
    Array cov({static_cast<py::ssize_t>(covs.size() / (N * N)), py::ssize_t(N), py::ssize_t(N)});
    std::copy(covs.begin(), covs.end(), cov.mutable_data());
    out["covariance"] = cov;
  }
  const auto nu = static_cast<py::ssize_t>(log.size());
  Array ut({nu}), nis({nu}), gate({nu}), logdet({nu}), rscale({nu}), innov({nu, py::ssize_t(3)}),
      isig({nu, py::ssize_t(3)});
  py::array_t<int> kind({nu}), id({nu}), dof({nu});
  py::array_t<bool> acc({nu}), guarded({nu});
  for (py::ssize_t i = 0; i < nu; ++i) {
    const auto& u = log[static_cast<std::size_t>(i)];
    ut.mutable_at(i) = u.t_s;
    nis.mutable_at(i) = u.nis;
    gate.mutable_at(i) = u.gate;
    logdet.mutable_at(i) = u.log_det_s;
    rscale.mutable_at(i) = u.r_scale;
    kind.mutable_at(i) = u.kind;
    id.mutable_at(i) = u.id;
    dof.mutable_at(i) = u.dof;
    acc.mutable_at(i) = u.accepted;
    guarded.mutable_at(i) = u.guarded;
    for (py::ssize_t c = 0; c < 3; ++c) {
      innov.mutable_at(i, c) = u.innovation[static_cast<std::size_t>(c)];
      isig.mutable_at(i, c) = u.innovation_sigma[static_cast<std::size_t>(c)];
    }
  }
  py::dict upd;
  upd["t"] = ut;
  upd["kind"] = kind;
  upd["id"] = id;
  upd["dof"] = dof;
  upd["nis"] = nis;
  upd["gate"] = gate;
  upd["log_det_s"] = logdet;
  upd["r_scale"] = rscale;
  upd["accepted"] = acc;
  upd["guarded"] = guarded;
  upd["innovation"] = innov;
  upd["innovation_sigma"] = isig;
  out["updates"] = upd;
  const auto ne = static_cast<py::ssize_t>(events.size());
  Array et({ne}), ev({ne});
  py::array_t<int> ek({ne});
  for (py::ssize_t i = 0; i < ne; ++i) {
    const auto& e = events[static_cast<std::size_t>(i)];
    et.mutable_at(i) = e.t_s;
    ek.mutable_at(i) = e.kind;
    ev.mutable_at(i) = e.value;
  }
  py::dict evd;
  evd["t"] = et;
  evd["kind"] = ek;
  evd["value"] = ev;
  out["events"] = evd;
  out["counters"] = counters_dict(f.counters());
  out["fixes_after_end"] = m - j;
  out["n_states"] = NB * 3 + NC + NT;
  return out;
}

class PyFilter {
 public:
  PyFilter(const InsConfig& cfg, const std::string& mode)
      : f_(make_filter(cfg, parse_mode(mode))), tight_(parse_mode(mode)) {}

  static bool parse_mode(const std::string& mode) {
    if (mode == "loose") return false;
    if (mode == "tight") return true;
    throw py::value_error("mode must be 'loose' or 'tight', got '" + mode + "'");
  }

  void push_imu(double t, const Vec3& dtheta, const Vec3& dv) {
    const InputStatus s = std::visit([&](auto& f) { return f.push_imu(t, dtheta, dv); }, f_);
    if (s != InputStatus::Ok) input_error("imu", imu_count_, t, s);
    ++imu_count_;
  }
  void push_fix(double t, const Vec3& r, const Vec3& v, double hdop, double vdop, int mode, const Vec3& sigma_ned,
                const Vec3& sigma_v_ned) {
    FixInput fix;
    fix.sigma_ned_m = sigma_ned;
    fix.sigma_v_ned_mps = sigma_v_ned;
    fix.t_s = t;
    fix.r_ecef_m = r;
    fix.v_ecef_mps = v;
    fix.hdop = hdop;
    fix.vdop = vdop;
    fix.mode = mode;
    const InputStatus s = std::visit([&](auto& f) { return f.push_fix(fix); }, f_);
    if (s != InputStatus::Ok) input_error("fix", fix_count_, t, s);
    ++fix_count_;
  }
  py::dict run(py::handle imu, py::handle fixes, py::handle prs, int output_every, bool with_cov, bool smooth,
               double smooth_chunk_mb, bool record, py::ssize_t imu_row0, py::ssize_t fix_row0, py::ssize_t pr_row0,
               py::handle attitude, py::ssize_t att_row0) {
    if ((smooth || record) && !(smooth_chunk_mb > 0.0)) throw py::value_error("smooth_chunk_mb must be > 0");
    if (output_every < 1) throw py::value_error("output_every must be >= 1");
    if (imu_row0 < 0 || fix_row0 < 0 || pr_row0 < 0 || att_row0 < 0) throw py::value_error("row offsets must be >= 0");
    const Array a = table(imu, kImuCols, "imu"), b = table(fixes, kFixCols, "fixes", kFixColsSigma);
    const Array c = table(prs.is_none() ? py::handle(Array(std::vector<py::ssize_t>{0, kPrCols})) : prs, kPrCols,
                          "pseudoranges", kPrColsDoppler);
    if (c.shape(0) > 0 && !tight_)
      throw py::value_error("pseudoranges given to a loosely coupled filter (mode = 'tight' uses them)");
    const Array d = table(attitude.is_none() ? py::handle(Array(std::vector<py::ssize_t>{0, kAttCols})) : attitude,
                          kAttCols, "attitude");
    const RowOffsets at{imu_row0, fix_row0, pr_row0, att_row0};
    py::dict out = std::visit(
        [&](auto& f) {
          return run_batch(f, a, b, c, d, output_every, with_cov, smooth || record, smooth_chunk_mb, carry_, at);
        },
        f_);
    if (smooth) {
      py::dict sm = smooth_run(with_cov, py::none(), 0);
      for (auto item : sm) out[item.first] = item.second;
    }
    return out;
  }
  // The backward pass over what run(..., record=True) calls recorded (see smooth_recorded).
  py::dict smooth_run(bool with_cov, py::object sink, long block_rows) {
    if (!carry_.recorder) throw py::value_error("smooth: nothing recorded (run with record=True first)");
    if (!sink.is_none() && block_rows < 1) throw py::value_error("smooth: block_rows must be >= 1");
    py::dict out = std::visit(
        [&](auto& f) { return smooth_recorded(*recorder_of(f, carry_.recorder.get()), with_cov, sink, block_rows); },
        f_);
    py::dict info = out["smooth_info"];
    info["forward_s"] = carry_.forward_s;
    info["forward_cpu_s"] = carry_.forward_cpu_s;
    carry_.recorder.reset();
    return out;
  }
  void push_pseudoranges(double t, const std::vector<int>& prn, const std::vector<double>& pr,
                         const std::vector<double>& cn0, const std::vector<int>& lock,
                         const std::vector<double>& doppler) {
    if (!tight_) throw py::value_error("pseudoranges need mode = 'tight'");
    if (prn.size() != pr.size() || cn0.size() != pr.size() || lock.size() != pr.size() ||
        !(doppler.empty() || doppler.size() == pr.size()))
      throw py::value_error("push_pseudoranges: prn, pr, cn0, lock (and doppler if given) must have equal lengths");
    PseudorangeEpoch ep;
    ep.t_s = t;
    for (std::size_t i = 0; i < pr.size() && ep.n < PseudorangeEpoch::kMaxSats; ++i) {
      const auto k = static_cast<std::size_t>(ep.n++);
      ep.prn[k] = prn[i];
      ep.pr_m[k] = pr[i];
      ep.cn0_dbhz[k] = cn0[i];
      ep.lock_count[k] = lock[i];
      if (!doppler.empty()) ep.doppler_hz[k] = doppler[i];
    }
    const InputStatus s = std::visit([&](auto& f) { return f.push_pseudoranges(ep); }, f_);
    if (s != InputStatus::Ok) input_error("pseudorange epoch", pr_count_, t, s);
    ++pr_count_;
  }
  void push_attitude(double t, double yaw, double pitch, double sigma_yaw, double sigma_pitch) {
    const InputStatus s = std::visit(
        [&](auto& f) {
          return f.push_attitude(AttitudeInput{t, yaw, pitch, sigma_yaw, sigma_pitch});
        },
        f_);
    if (s != InputStatus::Ok) input_error("attitude", att_count_, t, s);
    ++att_count_;
  }
  bool add_ephemeris(const gnss::Ephemeris& e) {
    return std::visit([&](auto& f) { return f.add_ephemeris(e); }, f_);
  }
  void set_klobuchar(const std::vector<double>& alpha, const std::vector<double>& beta) {
    if (alpha.size() != 4 || beta.size() != 4) throw py::value_error("set_klobuchar: 4 alpha and 4 beta values");
    gnss::Klobuchar k;
    for (std::size_t i = 0; i < 4; ++i) {
      k.alpha[i] = alpha[i];
      k.beta[i] = beta[i];
    }
    k.valid = true;
    std::visit([&](auto& f) { f.set_klobuchar(k); }, f_);
  }

  template <class G>
  auto with(G&& g) const {
    return std::visit([&](const auto& f) { return g(f); }, f_);
  }

 private:
  AnyFilter f_;
  BatchCarry carry_;
  bool tight_ = false;
  py::ssize_t imu_count_ = 0, fix_count_ = 0, pr_count_ = 0, att_count_ = 0;
};

}  // namespace

void bind_filter(py::module_& m) {
  // The tight filter's signal-in-space slots: its output rows carry them before the clock.
  m.attr("SIS_SLOTS") = kSisSlots;
  // The shared names (filter_names.hpp): update and event kinds by value, the counters in order.
  py::dict update_kinds, event_kinds;
#define GPSINS_KIND_ITEM(dict_, enumerator, value, name) dict_[py::int_(value)] = name;
#define GPSINS_UPDATE_ITEM(enumerator, value, name) GPSINS_KIND_ITEM(update_kinds, enumerator, value, name)
#define GPSINS_EVENT_ITEM(enumerator, value, name) GPSINS_KIND_ITEM(event_kinds, enumerator, value, name)
  GPSINS_UPDATE_KINDS(GPSINS_UPDATE_ITEM)
  GPSINS_EVENT_KINDS(GPSINS_EVENT_ITEM)
#undef GPSINS_EVENT_ITEM
#undef GPSINS_UPDATE_ITEM
#undef GPSINS_KIND_ITEM
  m.attr("UPDATE_KINDS") = update_kinds;
  m.attr("EVENT_KINDS") = event_kinds;
  py::list counter_names;
#define GPSINS_COUNTER_NAME(name) counter_names.append(#name);
  GPSINS_COUNTERS(GPSINS_COUNTER_NAME)
#undef GPSINS_COUNTER_NAME
  m.attr("COUNTER_NAMES") = py::tuple(counter_names);
  py::enum_<BiasModel>(m, "BiasModel")
      .value("random_walk", BiasModel::RandomWalk)
      .value("gauss_markov", BiasModel::GaussMarkov)
      .value("constant", BiasModel::Constant);

  py::enum_<UpdateCheck>(m, "UpdateCheck")
      .value("chi_square", UpdateCheck::ChiSquare)
      .value("attitude_correction", UpdateCheck::AttitudeCorrection)
      .value("both", UpdateCheck::Both)
      .value("none", UpdateCheck::None);

  py::class_<BiasConfig>(m, "BiasConfig")
      .def(py::init<>())
      .def_readwrite("model", &BiasConfig::model)
      .def_readwrite("random_walk_per_sqrt_s", &BiasConfig::random_walk_per_sqrt_s)
      .def_readwrite("gm_sigma", &BiasConfig::gm_sigma)
      .def_readwrite("gm_tau_s", &BiasConfig::gm_tau_s);

  py::class_<InsConfig> c(m, "InsConfig", "Filter configuration (see gpsins.filter for the TOML names).");
  c.def(py::init<>());
#define GPSINS_FIELD(name) c.def_readwrite(#name, &InsConfig::name)
  GPSINS_FIELD(imu_rate_hz);
  GPSINS_FIELD(max_gap_s);
  GPSINS_FIELD(imu_increments_cover_gaps);
  GPSINS_FIELD(gap_accel_sigma_mps2);
  GPSINS_FIELD(gyro_range_rad_per_s);
  GPSINS_FIELD(accel_range_mps2);
  GPSINS_FIELD(gyro_bias_cal_rad_per_s);
  GPSINS_FIELD(accel_bias_cal_mps2);
  GPSINS_FIELD(gyro_scale_factor_cal);
  GPSINS_FIELD(accel_scale_factor_cal);
  GPSINS_FIELD(gyro_arw_rad_per_sqrt_s);
  GPSINS_FIELD(accel_vrw_mps_per_sqrt_s);
  GPSINS_FIELD(gyro_flicker_white_rad_per_sqrt_s);
  GPSINS_FIELD(accel_flicker_white_mps_per_sqrt_s);
  GPSINS_FIELD(gyro_bias);
  GPSINS_FIELD(accel_bias);
  GPSINS_FIELD(scale_factor_states);
  GPSINS_FIELD(pseudorange_sis_states);
  GPSINS_FIELD(gyro_scale_factor_sigma);
  GPSINS_FIELD(accel_scale_factor_sigma);
  GPSINS_FIELD(gyro_misalignment_sigma_rad);
  GPSINS_FIELD(attitude_sigma_rad);
  GPSINS_FIELD(velocity_sigma_mps);
  GPSINS_FIELD(position_sigma_m);
  GPSINS_FIELD(gyro_bias_sigma_rad_per_s);
  GPSINS_FIELD(accel_bias_sigma_mps2);
  GPSINS_FIELD(clock_bias_sigma_m);
  GPSINS_FIELD(clock_drift_sigma_mps);
  GPSINS_FIELD(clock_reseed_window_s);
  GPSINS_FIELD(clock_bias_noise_m_per_sqrt_s);
  GPSINS_FIELD(clock_drift_noise_mps_per_sqrt_s);
  GPSINS_FIELD(level_time_s);
  GPSINS_FIELD(initial_yaw_rad);
  GPSINS_FIELD(heading_min_speed_mps);
  GPSINS_FIELD(heading_sigma_rad);
  GPSINS_FIELD(heading_max_course_sigma_rad);
  GPSINS_FIELD(lever_arm_body_m);
  GPSINS_FIELD(antenna_baseline_body);
  GPSINS_FIELD(fix_uere_m);
  GPSINS_FIELD(fix_sigma_ecef_m);
  GPSINS_FIELD(fix_error_gm_sigma_m);
  GPSINS_FIELD(fix_error_gm_tau_s);
  GPSINS_FIELD(fix_error_fast_sigma_m);
  GPSINS_FIELD(fix_error_fast_tau_s);
  GPSINS_FIELD(fix_uere_2d_m);
  GPSINS_FIELD(fix_error_gm_dop_scaled);
  GPSINS_FIELD(use_fix_velocity);
  GPSINS_FIELD(fix_velocity_sigma_mps);
  GPSINS_FIELD(fix_velocity_sigma_hdop_scaled);
  GPSINS_FIELD(fix_velocity_lag_s);
  GPSINS_FIELD(pseudorange_sigma_m);
  GPSINS_FIELD(pseudorange_elevation_mask_rad);
  GPSINS_FIELD(pseudorange_min_cn0_dbhz);
  GPSINS_FIELD(pseudorange_settle_s);
  GPSINS_FIELD(pseudorange_decimation);
  GPSINS_FIELD(pseudorange_error_gm_sigma_m);
  GPSINS_FIELD(pseudorange_error_gm_tau_s);
  GPSINS_FIELD(pseudorange_sis_sigma_m);
  GPSINS_FIELD(pseudorange_sis_use_ura);
  GPSINS_FIELD(pseudorange_sis_tau_s);
  GPSINS_FIELD(pseudorange_ionosphere);
  GPSINS_FIELD(pseudorange_troposphere);
  GPSINS_FIELD(doppler_sigma_mps);
  GPSINS_FIELD(gps_time_offset_s);
  GPSINS_FIELD(estimate_time_offset);
  GPSINS_FIELD(time_offset_sigma_s);
  GPSINS_FIELD(time_offset_rw_s_per_sqrt_s);
  GPSINS_FIELD(zero_velocity_updates);
  GPSINS_FIELD(standstill_window_s);
  GPSINS_FIELD(standstill_block_s);
  GPSINS_FIELD(standstill_accel_shift_mps2);
  GPSINS_FIELD(standstill_holdoff_s);
  GPSINS_FIELD(standstill_max_gnss_speed_mps);
  GPSINS_FIELD(standstill_accel_std_mps2);
  GPSINS_FIELD(standstill_gyro_std_rad_per_s);
  GPSINS_FIELD(standstill_gyro_mean_rad_per_s);
  GPSINS_FIELD(standstill_max_speed_mps);
  GPSINS_FIELD(zero_velocity_sigma_mps);
  GPSINS_FIELD(zero_rate_sigma_rad_per_s);
  GPSINS_FIELD(nonholonomic_constraint);
  GPSINS_FIELD(body_to_vehicle_ypr_rad);
  GPSINS_FIELD(vehicle_point_body_m);
  GPSINS_FIELD(nhc_sigma_mps);
  GPSINS_FIELD(nhc_vertical_sigma_mps);
  GPSINS_FIELD(nhc_min_speed_mps);
  GPSINS_FIELD(nhc_interval_s);
  GPSINS_FIELD(gate_probability);
  GPSINS_FIELD(update_check);
  GPSINS_FIELD(robust_after_rejections);
  GPSINS_FIELD(fix_min_dop);
  GPSINS_FIELD(fix_min_height_m);
  GPSINS_FIELD(fix_max_height_m);
  GPSINS_FIELD(max_attitude_correction_rad);
  GPSINS_FIELD(gnss_reset_timeout_s);
  GPSINS_FIELD(gnss_reset_max_dop);
  GPSINS_FIELD(fix_max_dop);
  GPSINS_FIELD(max_position_sigma_m);
#undef GPSINS_FIELD

  py::class_<PyFilter>(m, "InsFilter", "Streaming integrated navigation filter (one IMU sample or fix at a time).")
      .def(py::init<const InsConfig&, const std::string&>(), py::arg("config"), py::arg("mode") = "loose")
      .def("push_imu", &PyFilter::push_imu, py::arg("t"), py::arg("dtheta"), py::arg("dv"))
      .def("push_fix", &PyFilter::push_fix, py::arg("t"), py::arg("r_ecef"), py::arg("v_ecef"), py::arg("hdop"),
           py::arg("vdop"), py::arg("mode") = kFixMode3D,
           py::arg("sigma_ned") = Vec3::Constant(std::numeric_limits<double>::quiet_NaN()),
           py::arg("sigma_v_ned") = Vec3::Constant(std::numeric_limits<double>::quiet_NaN()))
      .def("run", &PyFilter::run, py::arg("imu"), py::arg("fixes"), py::arg("pseudoranges") = py::none(),
           py::arg("output_every") = 1, py::arg("covariance") = false, py::arg("smooth") = false,
           py::arg("smooth_chunk_mb") = 256.0, py::arg("record") = false, py::arg("imu_row0") = 0,
           py::arg("fix_row0") = 0, py::arg("pr_row0") = 0, py::arg("attitude") = py::none(), py::arg("att_row0") = 0,
           "Batch: imu (n, 7) [t, dtheta xyz, dv xyz], fixes (m, 10) [t, r xyz, v xyz, hdop, vdop, mode], "
           "pseudoranges (k, 5) [t, prn, pr, cn0, lock] or (k, 6) [..., Doppler Hz (NaN: none)] (tight), rows of one "
           "epoch sharing t. smooth: also a "
           "fixed-interval smoother over the run (smooth_state, smooth_covariance, smooth_info); its record of the "
           "forward pass goes to a temporary file in chunks of smooth_chunk_mb. A run split into consecutive "
           "calls (each with the fixes and pseudoranges up to its last IMU time) gives the same rows: *_row0 are "
           "the call's first rows within the whole run (output decimation, messages); record=True keeps the "
           "smoother's record across calls for smooth(). attitude (j, 5) [t, yaw, pitch (NaN: none), sigma yaw, "
           "sigma pitch] (rad): dual-antenna heading and pitch.")
      .def("smooth", &PyFilter::smooth_run, py::arg("covariance") = false, py::arg("sink") = py::none(),
           py::arg("block_rows") = 65536,
           "Backward pass over what run(..., record=True) recorded. With a sink, the smoothed rows are handed "
           "over in blocks of block_rows, newest block first (each in time order), as dicts (state, covariance, "
           "first = index of the block's first row); otherwise returned whole (smooth_state, smooth_covariance). "
           "Both give smooth_info (tape size, wall times).")
      .def("push_pseudoranges", &PyFilter::push_pseudoranges, py::arg("t"), py::arg("prn"), py::arg("pr"),
           py::arg("cn0"), py::arg("lock"), py::arg("doppler") = std::vector<double>{})
      .def("push_attitude", &PyFilter::push_attitude, py::arg("t"), py::arg("yaw"),
           py::arg("pitch") = std::numeric_limits<double>::quiet_NaN(), py::arg("sigma_yaw"),
           py::arg("sigma_pitch") = std::numeric_limits<double>::quiet_NaN(),
           "Dual-antenna heading (and pitch; NaN: none) in rad relative to local NED, with their sigmas.")
      .def("add_ephemeris", &PyFilter::add_ephemeris, py::arg("eph"))
      .def("set_klobuchar", &PyFilter::set_klobuchar, py::arg("alpha"), py::arg("beta"))
      .def_property_readonly("initialised",
                             [](const PyFilter& p) { return p.with([](const auto& f) { return f.initialised(); }); })
      .def_property_readonly("nominal_step_s",
                             [](const PyFilter& p) { return p.with([](const auto& f) { return f.nominal_step_s(); }); })
      .def_property_readonly("standstill",
                             [](const PyFilter& p) { return p.with([](const auto& f) { return f.standstill(); }); })
      .def_property_readonly(
          "n_states", [](const PyFilter& p) { return p.with([](const auto& f) { return static_cast<int>(f.N); }); })
      .def_property_readonly("t",
                             [](const PyFilter& p) { return p.with([](const auto& f) { return f.core().nav.t_s; }); })
      .def_property_readonly(
          "r_ecef", [](const PyFilter& p) { return p.with([](const auto& f) { return Vec3(f.core().nav.r_ecef_m); }); })
      .def_property_readonly(
          "v_ecef",
          [](const PyFilter& p) { return p.with([](const auto& f) { return Vec3(f.core().nav.v_ecef_mps); }); })
      .def_property_readonly("q_eb",
                             [](const PyFilter& p) {
                               return p.with([](const auto& f) {
                                 const Quat& q = f.core().nav.q_eb;
                                 return Eigen::Vector4d(q.w(), q.x(), q.y(), q.z());
                               });
                             })
      .def_property_readonly("gyro_bias",
                             [](const PyFilter& p) {
                               return p.with([](const auto& f) { return Vec3(f.core().imu.gyro_bias_rad_per_s); });
                             })
      .def_property_readonly(
          "accel_bias",
          [](const PyFilter& p) { return p.with([](const auto& f) { return Vec3(f.core().imu.accel_bias_mps2); }); })
      .def_property_readonly(
          "clock",
          [](const PyFilter& p) { return p.with([](const auto& f) { return Eigen::Vector2d(f.core().clock); }); })
      .def_property_readonly(
          "fix_error", [](const PyFilter& p) { return p.with([](const auto& f) { return Vec3(f.core().fix_error); }); })
      .def_property_readonly(
          "time_offset", [](const PyFilter& p) { return p.with([](const auto& f) { return f.core().time_offset_s; }); },
          "The IMU time offset estimate (s; 0 without estimate_time_offset): add it to the declared one.")
      .def_property_readonly(
          "covariance",
          [](const PyFilter& p) { return p.with([](const auto& f) { return Eigen::MatrixXd(f.core().P); }); })
      .def_property_readonly(
          "counters",
          [](const PyFilter& p) { return p.with([](const auto& f) { return counters_dict(f.counters()); }); })
      .def_property_readonly("last_update", [](const PyFilter& p) {
        return p.with([](const auto& f) { return update_dict(f.last_update()); });
      });
}

// The filter's batch results as Python objects: the NumPy tables checked, a
// batch call's result (batch.hpp) as the dict run() returns, the update records
// and counters, and the smoother's backward pass handed over in blocks.
#include <pybind11/numpy.h>
#include <pybind11/pybind11.h>

#include <algorithm>
#include <chrono>
#include <cmath>
#include <string>
#include <utility>
#include <vector>

#include "filter_bind.hpp"
#include "gpsins/rts.hpp"

namespace gpsins::py_filter {

[[noreturn]] void input_error(const char* what, py::ssize_t row, double t, InputStatus s) {
  throw py::value_error(std::string(what) + " row " + std::to_string(row) + " (t = " + std::to_string(t) +
                        " s): " + input_status_text(s));
}

Array table(py::handle obj, int cols, const char* name, int alt_cols) {
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

BatchTable table_of(const Array& a) {
  return BatchTable{a.data(), static_cast<std::ptrdiff_t>(a.shape(0)), static_cast<int>(a.shape(1))};
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

namespace {

// The vector's values as an array of that shape without a copy: the array owns the vector
// (a run's states and covariances are tens of MB per chunk).
Array adopt(std::vector<double>&& v, std::vector<py::ssize_t> shape) {
  auto* owner = new std::vector<double>(std::move(v));
  py::capsule free_owner(owner, [](void* p) { delete static_cast<std::vector<double>*>(p); });
  return Array(std::move(shape), owner->data(), free_owner);
}

// Backward pass over a recorded run. Rows come newest first; they are gathered
// into blocks of block_rows, each in time order, and a block is handed to
// sink(dict(state=..., covariance=..., first=index of its first row)) as soon
// as it is complete, so the caller can write it out. With no sink the whole
// smoothed run is returned as smooth_state / smooth_covariance.
template <int NB, int NC, int NT>
py::dict smooth_recorded(EskfRecorder<NB, NC, NT>& rec, bool with_cov, py::object sink, long block_rows, bool nav_cov) {
  using Rec = EskfRecorder<NB, NC, NT>;
  constexpr int N = Rec::N, kNom = Rec::kNominal;
  const py::ssize_t dim = nav_cov ? kNavigationDim<NT> : N;
  constexpr int kCols = kNom + N;  // nominal without flags, sigma, flags
  const long n = rec.outputs();
  const bool streaming = !sink.is_none();
  const long rows = streaming ? std::max(1L, std::min(block_rows, n)) : n;
  auto new_block = [&](long len) {
    return std::make_pair(Array({static_cast<py::ssize_t>(len), py::ssize_t(kCols)}),
                          Array(std::vector<py::ssize_t>{with_cov ? len : 0, dim, dim}));
  };
  long lo = std::max(0L, n - rows);  // rows [lo, hi) are being filled
  auto block = new_block(n - lo);
  const auto t0 = std::chrono::steady_clock::now();
  const double c0 = thread_cpu_s();
  double sink_s = 0.0, sink_cpu_s = 0.0;  // the caller's work on the blocks, not the smoother's
  {
    py::gil_scoped_release release;
    // Without the whole covariance wanted, only the navigation block's covariances are formed.
    const std::uint64_t blocks = with_cov && !nav_cov ? Rec::Pass::kAllStates : kNavigationStates<N, NT>;
    const auto emit = [&](long k, const double* row, const Eigen::Matrix<double, N, N>& p) {
      double* o = block.first.mutable_data() + (k - lo) * kCols;
      std::copy(row, row + kNom - 1, o);
      for (int i = 0; i < N; ++i) o[kNom - 1 + i] = std::sqrt(std::max(p(i, i), 0.0));
      o[kCols - 1] = row[kNom - 1];
      if (with_cov && nav_cov)
        write_navigation_block<NT>(p, block.second.mutable_data() + (k - lo) * dim * dim);
      else if (with_cov)
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
    };
    rec.smooth(emit, blocks);
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

// The recorder run_batch made for this filter type.
template <int NB, int NC, int NT>
EskfRecorder<NB, NC, NT>* recorder_of(const InsFilter<NB, NC, NT>&, void* p) {
  return static_cast<EskfRecorder<NB, NC, NT>*>(p);
}

}  // namespace

py::dict batch_dict(BatchResult& r, bool with_cov) {
  const py::ssize_t dim = r.covariance_dim;
  auto& covs = r.covariance;
  const auto& log = r.updates;
  const auto& events = r.events;
  py::dict out;
  const py::ssize_t cols = r.state_cols, state_rows = static_cast<py::ssize_t>(r.state.size()) / cols;
  out["state"] = adopt(std::move(r.state), {state_rows, cols});
  if (with_cov) {
    const py::ssize_t rows = dim > 0 ? static_cast<py::ssize_t>(covs.size()) / (dim * dim) : 0;
    out["covariance"] = adopt(std::move(covs), {rows, dim, dim});
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
  out["counters"] = counters_dict(r.counters);
  out["fixes_after_end"] = r.fixes_after_end;
  out["n_states"] = r.n_states;
  return out;
}

py::dict smooth_dict(AnyFilter& f, const BatchCarry& carry, bool with_cov, py::object sink, long block_rows,
                     bool nav_cov) {
  return std::visit(
      [&](auto& g) {
        return smooth_recorded(*recorder_of(g, carry.recorder.get()), with_cov, sink, block_rows, nav_cov);
      },
      f);
}

}  // namespace gpsins::py_filter

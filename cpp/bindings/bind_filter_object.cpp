// pybind11 face of the filter object: a streaming InsFilter (one IMU sample,
// fix, pseudorange epoch or attitude at a time), its batch run() over NumPy
// arrays (the loop is the core's, batch.hpp) and smooth(), and its state.
#include <pybind11/eigen.h>
#include <pybind11/numpy.h>
#include <pybind11/pybind11.h>
#include <pybind11/stl.h>

#include <limits>
#include <string>
#include <variant>
#include <vector>

#include "filter_bind.hpp"

namespace gpsins::py_filter {

namespace {

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
               py::handle attitude, py::ssize_t att_row0, bool navigation_covariance) {
    if ((smooth || record) && !(smooth_chunk_mb > 0.0)) throw py::value_error("smooth_chunk_mb must be > 0");
    if (output_every < 1) throw py::value_error("output_every must be >= 1");
    if (imu_row0 < 0 || fix_row0 < 0 || pr_row0 < 0 || att_row0 < 0) throw py::value_error("row offsets must be >= 0");
    const Array a = table(imu, batch_cols::kImu, "imu"),
                b = table(fixes, batch_cols::kFix, "fixes", batch_cols::kFixSigma);
    const Array c =
        table(prs.is_none() ? py::handle(Array(std::vector<py::ssize_t>{0, batch_cols::kPseudorange})) : prs,
              batch_cols::kPseudorange, "pseudoranges", batch_cols::kPseudorangeDoppler);
    if (c.shape(0) > 0 && !tight_)
      throw py::value_error("pseudoranges given to a loosely coupled filter (mode = 'tight' uses them)");
    const Array d =
        table(attitude.is_none() ? py::handle(Array(std::vector<py::ssize_t>{0, batch_cols::kAttitude})) : attitude,
              batch_cols::kAttitude, "attitude");
    const BatchInputs in{table_of(a), table_of(b), table_of(c), table_of(d)};
    BatchOptions opt;
    opt.output_every = output_every;
    opt.covariance = with_cov;
    opt.covariance_navigation = navigation_covariance;
    opt.record = smooth || record;
    opt.smooth_chunk_mb = smooth_chunk_mb;
    const RowOffsets at{imu_row0, fix_row0, pr_row0, att_row0};
    BatchResult r;
    {
      py::gil_scoped_release release;
      r = std::visit([&](auto& f) { return run_batch(f, in, opt, carry_, at); }, f_);
    }
    if (r.bad != InputStatus::Ok) input_error(r.bad_what, r.bad_row, r.bad_t, r.bad);
    py::dict out = batch_dict(r, with_cov);
    if (smooth) {
      py::dict sm = smooth_run(with_cov, py::none(), 0, navigation_covariance);
      for (auto item : sm) out[item.first] = item.second;
    }
    return out;
  }
  // The backward pass over what run(..., record=True) calls recorded (see bind_filter_batch.cpp).
  py::dict smooth_run(bool with_cov, py::object sink, long block_rows, bool navigation_covariance) {
    if (!carry_.recorder) throw py::value_error("smooth: nothing recorded (run with record=True first)");
    if (!sink.is_none() && block_rows < 1) throw py::value_error("smooth: block_rows must be >= 1");
    py::dict out = smooth_dict(f_, carry_, with_cov, sink, block_rows, navigation_covariance);
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
  Eigen::MatrixXd covariance() {
    return std::visit(
        [](auto& f) {
          f.flush_covariance();
          return Eigen::MatrixXd(f.core().P);
        },
        f_);
  }

 private:
  AnyFilter f_;
  BatchCarry carry_;
  bool tight_ = false;
  py::ssize_t imu_count_ = 0, fix_count_ = 0, pr_count_ = 0, att_count_ = 0;
};

}  // namespace

void bind_filter_object(py::module_& m) {
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
           py::arg("navigation_covariance") = false,
           "Batch: imu (n, 7) [t, dtheta xyz, dv xyz], fixes (m, 10) [t, r xyz, v xyz, hdop, vdop, mode], "
           "pseudoranges (k, 5) [t, prn, pr, cn0, lock] or (k, 6) [..., Doppler Hz (NaN: none)] (tight), rows of one "
           "epoch sharing t. smooth: also a "
           "fixed-interval smoother over the run (smooth_state, smooth_covariance, smooth_info); its record of the "
           "forward pass goes to a temporary file in chunks of smooth_chunk_mb. A run split into consecutive "
           "calls (each with the fixes and pseudoranges up to its last IMU time) gives the same rows: *_row0 are "
           "the call's first rows within the whole run (output decimation, messages); record=True keeps the "
           "smoother's record across calls for smooth(). attitude (j, 5) [t, yaw, pitch (NaN: none), sigma yaw, "
           "sigma pitch] (rad): dual-antenna heading and pitch. navigation_covariance: with covariance, only the "
           "navigation block (attitude, velocity, position, then the IMU time offset when it is a state).")
      .def("smooth", &PyFilter::smooth_run, py::arg("covariance") = false, py::arg("sink") = py::none(),
           py::arg("block_rows") = 65536, py::arg("navigation_covariance") = false,
           "Backward pass over what run(..., record=True) recorded. With a sink, the smoothed rows are handed "
           "over in blocks of block_rows, newest block first (each in time order), as dicts (state, covariance, "
           "first = index of the block's first row); otherwise returned whole (smooth_state, smooth_covariance). "
           "Both give smooth_info (tape size, wall times). navigation_covariance: as run's.")
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
      .def_property_readonly("covariance", [](PyFilter& p) { return p.covariance(); })
      .def_property_readonly(
          "counters",
          [](const PyFilter& p) { return p.with([](const auto& f) { return counters_dict(f.counters()); }); })
      .def_property_readonly("last_update", [](const PyFilter& p) {
        return p.with([](const auto& f) { return update_dict(f.last_update()); });
      });
}

}  // namespace gpsins::py_filter

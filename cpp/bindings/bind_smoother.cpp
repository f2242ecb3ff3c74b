// A plain linear Kalman filter of 4 states recorded and smoothed by the same
// tape and backward pass as the navigation filter (rts.hpp), for tests that
// compare it with an independent textbook RTS smoother. The filter keeps its
// estimate as a "nominal" that every update's K y is injected into (G = I),
// as the error-state filter does.
#include <pybind11/eigen.h>
#include <pybind11/numpy.h>
#include <pybind11/pybind11.h>

#include <memory>

#include "gpsins/rts.hpp"

namespace py = pybind11;
using namespace gpsins;

namespace {

constexpr int kN = 4;
using VecN = Eigen::Matrix<double, kN, 1>;
using MatN = Eigen::Matrix<double, kN, kN>;

class LinearRts final : public EskfObserver<kN> {
 public:
  LinearRts(const VecN& x0, const MatN& p0, double chunk_bytes)
      : x_(x0), p_(p0), tape_(static_cast<std::size_t>(chunk_bytes)) {}

  void predict(const MatN& phi, const MatN& q) {
    x_ = phi * x_;
    p_ = phi * p_ * phi.transpose() + q;
    on_propagate(phi);
  }
  void transition(const MatN& a, const MatN& q) {
    x_ = a * x_;
    p_ = a * p_ * a.transpose() + q;
    on_transition(a);
  }
  void update(const Eigen::MatrixXd& H, const Eigen::MatrixXd& R, const Eigen::VectorXd& z) {
    if (H.cols() != kN || H.rows() != R.rows() || R.rows() != R.cols() || z.size() != H.rows() || H.rows() > 3)
      throw py::value_error("update: H (m x 4), R (m x m), z (m), m <= 3");
    const Eigen::VectorXd y = z - H * x_;
    const Eigen::MatrixXd S = H * p_ * H.transpose() + R;
    const Eigen::MatrixXd s_inv = S.inverse();
    const Eigen::MatrixXd K = p_ * H.transpose() * s_inv;
    const MatN ikh = MatN::Identity() - K * H;
    p_ = ikh * p_ * ikh.transpose() + K * R * K.transpose();
    x_ += K * y;
    on_update(H, K, s_inv, y, Mat3::Identity());
  }
  void output() {
    double* o = tape_.append(SmootherTape::kOutput, kN + BackwardPass<kN>::kPacked);
    Eigen::Map<VecN>{o} = x_;
    BackwardPass<kN>::pack(p_, o + kN);
    ++outputs_;
  }
  py::tuple smooth() {
    py::array_t<double> xs({static_cast<py::ssize_t>(outputs_), py::ssize_t(kN)});
    py::array_t<double> ps({static_cast<py::ssize_t>(outputs_), py::ssize_t(kN), py::ssize_t(kN)});
    double* px = xs.mutable_data();
    double* pp = ps.mutable_data();
    BackwardPass<kN>::run(tape_, outputs_, [&](long k, const double* nom, int, const VecN& dx, const MatN& p) {
      Eigen::Map<VecN>(px + k * kN) = Eigen::Map<const VecN>(nom) + dx;
      Eigen::Map<Eigen::Matrix<double, kN, kN, Eigen::RowMajor>>(pp + k * kN * kN) = p;
    });
    return py::make_tuple(xs, ps);
  }
  VecN x() const { return x_; }
  MatN p() const { return p_; }
  std::size_t spilled() const { return tape_.spilled_bytes(); }

  void on_propagate(const MatN& phi) override {
    BackwardPass<kN>::record_transition(tape_, SmootherTape::kPropagate, phi);
  }
  void on_transition(const MatN& a) override {
    BackwardPass<kN>::record_transition(tape_, SmootherTape::kTransition, a);
  }
  void on_update(const MatRef& H, const MatRef& K, const MatRef& s_inv, const VecRef& y, const Mat3& g) override {
    const int m = static_cast<int>(H.rows());
    double* d = tape_.append(SmootherTape::kUpdate, 1 + 2 * m * kN + m * m + m + 9);
    *d++ = m;
    Eigen::Map<Eigen::MatrixXd>(d, m, kN) = H;
    d += m * kN;
    Eigen::Map<Eigen::MatrixXd>(d, kN, m) = K;
    d += kN * m;
    Eigen::Map<Eigen::MatrixXd>(d, m, m) = s_inv;
    d += m * m;
    Eigen::Map<Eigen::VectorXd>(d, m) = y;
    d += m;
    Eigen::Map<Mat3>{d} = g;
  }

 private:
  VecN x_;
  MatN p_;
  SmootherTape tape_;
  long outputs_ = 0;
};

}  // namespace

void bind_smoother(py::module_& m) {
  py::class_<LinearRts>(m, "LinearRts",
                        "4-state linear Kalman filter smoothed by the navigation smoother's backward pass (tests).")
      .def(py::init<const VecN&, const MatN&, double>(), py::arg("x0"), py::arg("p0"),
           py::arg("chunk_bytes") = 64.0 * 1048576.0)
      .def("predict", &LinearRts::predict, py::arg("phi"), py::arg("q"))
      .def("transition", &LinearRts::transition, py::arg("a"), py::arg("q"))
      .def("update", &LinearRts::update, py::arg("H"), py::arg("R"), py::arg("z"))
      .def("output", &LinearRts::output)
      .def("smooth", &LinearRts::smooth, "Smoothed states (n, 4) and covariances (n, 4, 4) at the outputs.")
      .def_property_readonly("x", &LinearRts::x)
      .def_property_readonly("P", &LinearRts::p)
      .def_property_readonly("spilled_bytes", &LinearRts::spilled);
}

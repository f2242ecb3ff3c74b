#include <doctest/doctest.h>

#include <random>
#include <vector>

#include "gpsins/rts.hpp"

using namespace gpsins;

namespace {

constexpr int kN = 4;
using VecN = Eigen::Matrix<double, kN, 1>;
using MatN = Eigen::Matrix<double, kN, kN>;

// A linear filter recording itself on a tape as the navigation filter does.
struct Recorded {
  SmootherTape tape;
  long outputs = 0;
  explicit Recorded(std::size_t chunk) : tape(chunk) {}
  void propagate(const MatN& phi) { Eigen::Map<MatN>(tape.append(SmootherTape::kPropagate, kN * kN)) = phi; }
  void update(const Eigen::MatrixXd& H, const Eigen::MatrixXd& K, const Eigen::MatrixXd& s_inv, const Eigen::VectorXd& y) {
    const int m = static_cast<int>(H.rows());
    double* d = tape.append(SmootherTape::kUpdate, 1 + 2 * m * kN + m * m + m + 9);
    *d++ = m;
    Eigen::Map<Eigen::MatrixXd>(d, m, kN) = H; d += m * kN;
    Eigen::Map<Eigen::MatrixXd>(d, kN, m) = K; d += kN * m;
    Eigen::Map<Eigen::MatrixXd>(d, m, m) = s_inv; d += m * m;
    Eigen::Map<Eigen::VectorXd>(d, m) = y; d += m;
    Eigen::Map<Mat3>{d} = Mat3::Identity();
  }
  void output(const VecN& x, const MatN& p) {
    double* o = tape.append(SmootherTape::kOutput, kN + BackwardPass<kN>::kPacked);
    Eigen::Map<VecN>{o} = x;
    BackwardPass<kN>::pack(p, o + kN);
    ++outputs;
  }
};

struct Run {
  std::vector<VecN> xs;
  std::vector<MatN> ps;
};

// Constant velocity in 2-D, position measured every third step; the same
// problem smoothed by the tape's backward pass and by the textbook RTS
// (gain C = P+ Phi^T (P-)^-1, with explicit inverses).
void smooth_both(std::size_t chunk, Run& bf, Run& textbook, std::size_t& spilled) {
  std::mt19937 rng(7);
  std::normal_distribution<double> n01;
  const double dt = 0.5;
  MatN phi = MatN::Identity();
  phi(0, 2) = phi(1, 3) = dt;
  MatN q = MatN::Zero();
  q.diagonal() << 0.01, 0.02, 0.05, 0.04;
  Eigen::MatrixXd H = Eigen::MatrixXd::Zero(2, kN);
  H(0, 0) = H(1, 1) = 1.0;
  Eigen::MatrixXd R = Eigen::MatrixXd::Identity(2, 2) * 0.3;
  VecN truth(0.0, 0.0, 1.0, -0.5), x = VecN::Zero();
  MatN p = MatN::Identity() * 4.0;
  Recorded rec(chunk);
  std::vector<VecN> xf, xp;
  std::vector<MatN> pf, pp;
  const int steps = 300;
  for (int k = 0; k < steps; ++k) {
    if (k > 0) {
      truth = phi * truth;
      for (int i = 0; i < kN; ++i) truth(i) += std::sqrt(q(i, i)) * n01(rng);
      x = phi * x;
      p = phi * p * phi.transpose() + q;
      rec.propagate(phi);
    }
    xp.push_back(x);
    pp.push_back(p);
    if (k % 3 == 0) {
      Eigen::VectorXd z = H * truth;
      for (int i = 0; i < 2; ++i) z(i) += std::sqrt(R(i, i)) * n01(rng);
      const Eigen::VectorXd y = z - H * x;
      const Eigen::MatrixXd s_inv = (H * p * H.transpose() + R).inverse();
      const Eigen::MatrixXd K = p * H.transpose() * s_inv;
      const MatN ikh = MatN::Identity() - K * H;
      p = ikh * p * ikh.transpose() + K * R * K.transpose();
      x += K * y;
      rec.update(H, K, s_inv, y);
    }
    xf.push_back(x);
    pf.push_back(p);
    rec.output(x, p);
  }
  bf.xs.assign(steps, VecN::Zero());
  bf.ps.assign(steps, MatN::Zero());
  BackwardPass<kN>::run(rec.tape, rec.outputs, [&](long k, const double* nom, int, const VecN& dx, const MatN& ps) {
    bf.xs[static_cast<std::size_t>(k)] = Eigen::Map<const VecN>(nom) + dx;
    bf.ps[static_cast<std::size_t>(k)] = ps;
  });
  spilled = rec.tape.spilled_bytes();
  textbook.xs = xf;
  textbook.ps = pf;
  for (int k = steps - 2; k >= 0; --k) {
    const auto i = static_cast<std::size_t>(k);
    const MatN c = pf[i] * phi.transpose() * pp[i + 1].inverse();
    textbook.xs[i] = xf[i] + c * (textbook.xs[i + 1] - xp[i + 1]);
    textbook.ps[i] = pf[i] + c * (textbook.ps[i + 1] - pp[i + 1]) * c.transpose();
  }
}

}  // namespace

TEST_CASE("smoother backward pass equals a textbook RTS, in memory and spilled to a file") {
  for (std::size_t chunk : {std::size_t(64) << 20, std::size_t(4096)}) {
    Run bf, tb;
    std::size_t spilled = 0;
    smooth_both(chunk, bf, tb, spilled);
    if (chunk == 4096) CHECK(spilled > 0);
    else CHECK(spilled == 0);
    double dx = 0.0, dp = 0.0, gain = 0.0;
    for (std::size_t k = 0; k < bf.xs.size(); ++k) {
      dx = std::max(dx, (bf.xs[k] - tb.xs[k]).cwiseAbs().maxCoeff());
      dp = std::max(dp, (bf.ps[k] - tb.ps[k]).cwiseAbs().maxCoeff());
      gain = std::max(gain, tb.ps[k].trace());
    }
    CHECK(dx < 1e-9);
    CHECK(dp < 1e-10);
    CHECK(gain > 0.0);
  }
}

TEST_CASE("smoother tape: bytes per record as documented") {
  SmootherTape tape(4096);
  tape.append(SmootherTape::kPropagate, 225);
  CHECK(tape.bytes() == 226 * sizeof(double));
  using R50 = EskfRecorder<5, 0>;
  using R52 = EskfRecorder<5, 2>;
  using R72 = EskfRecorder<7, 2>;
  using R53 = EskfRecorder<5, 3>;  // loose with the fix-error states
  // Output record: nominal + packed covariance + trailer; propagation: N^2 + trailer.
  CHECK(R50::kNominal + BackwardPass<15>::kPacked + 1 == 139);
  CHECK(R52::kNominal + BackwardPass<17>::kPacked + 1 == 174);
  CHECK(R72::kNominal + BackwardPass<23>::kPacked + 1 == 303);
  CHECK(R53::kNominal + BackwardPass<18>::kPacked + 1 == 193);
}

#include <doctest/doctest.h>

#include <random>
#include <vector>

#include "gpsins/aiding/position_fix.hpp"
#include "gpsins/aiding/zero_velocity.hpp"
#include "gpsins/earth.hpp"
#include "gpsins/eskf_update.hpp"
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
  void propagate(const MatN& phi) { BackwardPass<kN>::record_transition(tape, SmootherTape::kPropagate, phi); }
  void update(const Eigen::MatrixXd& H, const Eigen::MatrixXd& K, const Eigen::MatrixXd& s_inv,
              const Eigen::VectorXd& y) {
    const int m = static_cast<int>(H.rows());
    double* d = tape.append(SmootherTape::kUpdate, 1 + 2 * m * kN + m * m + m + 9);
    *d++ = m;
    Eigen::Map<Eigen::MatrixXd>(d, m, kN) = H;
    d += m * kN;
    Eigen::Map<Eigen::MatrixXd>(d, kN, m) = K;
    d += kN * m;
    Eigen::Map<Eigen::MatrixXd>(d, m, m) = s_inv;
    d += m * m;
    Eigen::Map<Eigen::VectorXd>(d, m) = y;
    d += m;
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
    if (chunk == 4096)
      CHECK(spilled > 0);
    else
      CHECK(spilled == 0);
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
  // A transition: one mask per column, its non-zeros (here the identity and 7 more), the trailer.
  Eigen::Matrix<double, 15, 15> a = Eigen::Matrix<double, 15, 15>::Identity();
  for (int k = 0; k < 7; ++k) a(k, 14 - k) = 0.5 + k;
  const std::size_t before = tape.bytes();
  BackwardPass<15>::record_transition(tape, SmootherTape::kTransition, a);
  CHECK(tape.bytes() - before == (15 + 15 + 7 + 1) * sizeof(double));
  using R50 = EskfRecorder<5, 0>;
  using R52 = EskfRecorder<5, 2>;
  using R72 = EskfRecorder<7, 2>;
  using R53 = EskfRecorder<5, 3>;  // loose with the fix-error states
  // Output record: nominal + packed covariance + trailer.
  CHECK(R50::kNominal + BackwardPass<15>::kPacked + 1 == 139);
  CHECK(R52::kNominal + BackwardPass<17>::kPacked + 1 == 174);
  CHECK(R72::kNominal + BackwardPass<23>::kPacked + 1 == 303);
  CHECK(R53::kNominal + BackwardPass<18>::kPacked + 1 == 193);
}

namespace {

// The backward recursion written out densely (rts.hpp's header), for checking the
// pass that skips Phi's zeros and H's zero columns.
template <int N>
struct DenseBackward {
  using VecN = Eigen::Matrix<double, N, 1>;
  using MatN = Eigen::Matrix<double, N, N>;
  VecN lam = VecN::Zero();
  MatN Lam = MatN::Zero();
  void transition(const MatN& phi) {
    lam = phi.transpose() * lam;
    Lam = phi.transpose() * Lam * phi;
  }
  void update(const Eigen::MatrixXd& H, const Eigen::MatrixXd& K, const Eigen::MatrixXd& s_inv,
              const Eigen::VectorXd& y, const Mat3& g) {
    MatN gt = MatN::Identity();
    gt.template topLeftCorner<3, 3>() = g;
    lam = gt.transpose() * lam;
    Lam = gt.transpose() * Lam * gt;
    const MatN L = MatN::Identity() - K * H;
    Lam = L.transpose() * Lam * L + H.transpose() * s_inv * H;
    lam = L.transpose() * lam - H.transpose() * s_inv * y;
  }
};

}  // namespace

TEST_CASE("smoother backward pass: sparse transitions and updates equal the dense recursion (15 states)") {
  constexpr int N = 15;
  using MatN = Eigen::Matrix<double, N, N>;
  using VecN = Eigen::Matrix<double, N, 1>;
  std::mt19937 rng(11);
  std::normal_distribution<double> n01;
  SmootherTape tape(4096);
  DenseBackward<N> dense;
  std::vector<std::pair<int, std::vector<double>>> records;  // replayed newest first by the dense pass
  MatN p = MatN::Zero();
  for (int i = 0; i < N; ++i) p(i, i) = 1.0 + i;
  long outputs = 0;
  for (int k = 0; k < 60; ++k) {
    // A step's Phi with the navigation filter's zero blocks: bias rows diagonal, no
    // velocity or position in the attitude row, no accelerometer bias in it either.
    MatN phi = MatN::Identity();
    for (int i = 0; i < 9; ++i)
      for (int j = 0; j < 15; ++j)
        if (!(i < 3 && (j >= 3 && j < 9)) && !(i < 3 && j >= 12)) phi(i, j) += 0.05 * n01(rng);
    for (int i = 9; i < 15; ++i) phi(i, i) = 0.999;
    BackwardPass<N>::record_transition(tape, SmootherTape::kPropagate, phi);
    records.push_back({1, std::vector<double>(phi.data(), phi.data() + N * N)});
    if (k % 4 == 0) {  // a fix: position and, through a lever arm, attitude columns
      const int m = k % 8 == 0 ? 3 : 1;
      Eigen::MatrixXd H = Eigen::MatrixXd::Zero(m, N), K(N, m), s_inv(m, m);
      for (int r = 0; r < m; ++r) {
        H(r, 6 + r) = 1.0;
        for (int j = 0; j < 3; ++j) H(r, j) = 0.3 * n01(rng);
      }
      for (int r = 0; r < N; ++r)
        for (int c = 0; c < m; ++c) K(r, c) = 0.2 * n01(rng);
      s_inv = Eigen::MatrixXd::Identity(m, m) * 0.5;
      Eigen::VectorXd y(m);
      for (int r = 0; r < m; ++r) y(r) = n01(rng);
      const Vec3 dth(0.1 * n01(rng), 0.1 * n01(rng), 0.3 * n01(rng));  // large injected attitude
      Mat3 g = Mat3::Identity();
      g(0, 1) = 0.5 * dth.z();
      g(1, 0) = -0.5 * dth.z();
      g(0, 2) = -0.5 * dth.y();
      g(2, 0) = 0.5 * dth.y();
      g(1, 2) = 0.5 * dth.x();
      g(2, 1) = -0.5 * dth.x();  // I - [dth/2]x
      double* d = tape.append(SmootherTape::kUpdate, 1 + 2 * m * N + m * m + m + 9);
      std::vector<double> copy;
      *d++ = m;
      Eigen::Map<Eigen::MatrixXd>(d, m, N) = H;
      d += m * N;
      Eigen::Map<Eigen::MatrixXd>(d, N, m) = K;
      d += N * m;
      Eigen::Map<Eigen::MatrixXd>(d, m, m) = s_inv;
      d += m * m;
      Eigen::Map<Eigen::VectorXd>(d, m) = y;
      d += m;
      Eigen::Map<Mat3>{d} = g;
      records.push_back({2, {}});
      auto& r = records.back().second;
      r.push_back(m);
      r.insert(r.end(), H.data(), H.data() + m * N);
      r.insert(r.end(), K.data(), K.data() + N * m);
      r.insert(r.end(), s_inv.data(), s_inv.data() + m * m);
      r.insert(r.end(), y.data(), y.data() + m);
      r.insert(r.end(), g.data(), g.data() + 9);
    }
    double* o = tape.append(SmootherTape::kOutput, 1 + BackwardPass<N>::kPacked);
    o[0] = k;
    BackwardPass<N>::pack(p, o + 1);
    records.push_back({4, {}});
    ++outputs;
  }
  std::vector<VecN> dx_sparse(static_cast<std::size_t>(outputs)), dx_dense = dx_sparse;
  std::vector<MatN> ps_sparse(static_cast<std::size_t>(outputs)), ps_dense = ps_sparse;
  BackwardPass<N>::run(tape, outputs, [&](long k, const double*, int, const VecN& dx, const MatN& ps) {
    dx_sparse[static_cast<std::size_t>(k)] = dx;
    ps_sparse[static_cast<std::size_t>(k)] = ps;
  });
  long k = outputs;
  double scale = 0.0;
  for (auto it = records.rbegin(); it != records.rend(); ++it) {
    const double* d = it->second.data();
    if (it->first == 1) {
      dense.transition(Eigen::Map<const MatN>(d));
    } else if (it->first == 2) {
      const int m = static_cast<int>(d[0]);
      const double* q = d + 1;
      const Eigen::MatrixXd H = Eigen::Map<const Eigen::MatrixXd>(q, m, N);
      const Eigen::MatrixXd K = Eigen::Map<const Eigen::MatrixXd>(q + m * N, N, m);
      const Eigen::MatrixXd s_inv = Eigen::Map<const Eigen::MatrixXd>(q + 2 * m * N, m, m);
      const Eigen::VectorXd y = Eigen::Map<const Eigen::VectorXd>(q + 2 * m * N + m * m, m);
      dense.update(H, K, s_inv, y, Eigen::Map<const Mat3>(q + 2 * m * N + m * m + m));
    } else {
      const auto i = static_cast<std::size_t>(--k);
      dx_dense[i] = -p * dense.lam;
      ps_dense[i] = p - p * dense.Lam * p;
      scale = std::max(scale, ps_dense[i].cwiseAbs().maxCoeff() + dx_dense[i].cwiseAbs().maxCoeff());
    }
  }
  double ddx = 0.0, dps = 0.0;
  for (std::size_t i = 0; i < dx_dense.size(); ++i) {
    ddx = std::max(ddx, (dx_sparse[i] - dx_dense[i]).cwiseAbs().maxCoeff());
    dps = std::max(dps, (ps_sparse[i] - ps_dense[i]).cwiseAbs().maxCoeff());
  }
  CHECK(scale > 1.0);
  CHECK(ddx < 1e-9 * scale);
  CHECK(dps < 1e-9 * scale);
  // Only some states' covariances wanted: those and every variance as the dense pass gives them, the rest zero.
  const std::uint64_t blocks = 0x1FF | std::uint64_t(1) << 14;
  double dblock = 0.0, rest = 0.0;
  BackwardPass<N>::run(
      tape, outputs,
      [&](long i, const double*, int, const VecN&, const MatN& ps) {
        const MatN& want = ps_dense[static_cast<std::size_t>(i)];
        for (int r = 0; r < N; ++r)
          for (int c = 0; c < N; ++c) {
            if (r == c || ((blocks >> r & 1) && (blocks >> c & 1)))
              dblock = std::max(dblock, std::abs(ps(r, c) - want(r, c)));
            else
              rest = std::max(rest, std::abs(ps(r, c)));
          }
      },
      blocks);
  CHECK(dblock < 1e-9 * scale);
  CHECK(rest == 0.0);
}

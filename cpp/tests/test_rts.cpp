#include <doctest/doctest.h>

#include <random>
#include <vector>

#include "gpsins/aiding/position_fix.hpp"
#include "gpsins/aiding/zero_velocity.hpp"
#include "gpsins/earth.hpp"
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
    Eigen::Map<MatN>(tape.append(SmootherTape::kPropagate, N * N)) = phi;
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
      g(0, 1) = 0.5 * dth.z(); g(1, 0) = -0.5 * dth.z();
      g(0, 2) = -0.5 * dth.y(); g(2, 0) = 0.5 * dth.y();
      g(1, 2) = 0.5 * dth.x(); g(2, 1) = -0.5 * dth.x();  // I - [dth/2]x
      double* d = tape.append(SmootherTape::kUpdate, 1 + 2 * m * N + m * m + m + 9);
      std::vector<double> copy;
      *d++ = m;
      Eigen::Map<Eigen::MatrixXd>(d, m, N) = H; d += m * N;
      Eigen::Map<Eigen::MatrixXd>(d, N, m) = K; d += N * m;
      Eigen::Map<Eigen::MatrixXd>(d, m, m) = s_inv; d += m * m;
      Eigen::Map<Eigen::VectorXd>(d, m) = y; d += m;
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
}

namespace {

// What the real core told its observer, with the covariance after each record
// (for an update: after its injection's reset), for a textbook RTS that uses
// the forward covariances and explicit inverses instead of the adjoint.
template <int NB, int NC>
struct Tap final : EskfObserver<3 * NB + NC> {
  static constexpr int N = 3 * NB + NC;
  using MatN = Eigen::Matrix<double, N, N>;
  using VecN = Eigen::Matrix<double, N, 1>;
  using Base = EskfObserver<N>;
  struct Event {
    int kind;       // 1 propagate, 2 update, 3 transition, 4 output
    MatN a;         // Phi or A
    MatN p_after;   // the forward covariance after this record
    VecN ky;        // an update's injected correction
    Mat3 g;         // an update's reset
  };
  const Eskf<NB, NC>* core = nullptr;
  EskfRecorder<NB, NC> rec{std::size_t(64) << 20};
  std::vector<Event> ev;
  void on_propagate(const MatN& phi) override {
    ev.push_back({1, phi, core->P, VecN::Zero(), Mat3::Identity()});
    rec.on_propagate(phi);
  }
  void on_update(const typename Base::MatRef& H, const typename Base::MatRef& K, const typename Base::MatRef& s_inv,
                 const typename Base::VecRef& y, const Mat3& g) override {
    MatN p = core->P;  // after the update, before the reset the core applies next
    p.template topRows<3>() = (g * p.template topRows<3>()).eval();
    p.template leftCols<3>() = (p.template leftCols<3>() * g.transpose()).eval();
    ev.push_back({2, MatN::Identity(), p, VecN(K * y), g});
    rec.on_update(H, K, s_inv, y, g);
  }
  void on_transition(const MatN& a) override {
    ev.push_back({3, a, core->P, VecN::Zero(), Mat3::Identity()});
    rec.on_transition(a);
  }
  void output() {
    ev.push_back({4, MatN::Identity(), core->P, VecN::Zero(), Mat3::Identity()});
    rec.output(*core, 0.0);
  }
  // Textbook RTS over the events, newest first: across Phi (or A) from P_a to
  // P_b = Phi P_a Phi^T + Q, C = P_a Phi^T P_b^-1, dx_a = C dx_b,
  // P_s,a = P_a + C (P_s,b - P_b) C^T; across an update the smoothed estimate is
  // the same, only its reference moves: dx^- = G^-1 dx^+ + K y.
  void textbook(std::vector<VecN>& dx_out, std::vector<MatN>& ps_out) const {
    VecN dx = VecN::Zero();
    MatN ps = ev.back().p_after;
    long k = 0;
    for (const auto& e : ev) k += e.kind == 4;
    dx_out.assign(static_cast<std::size_t>(k), VecN::Zero());
    ps_out.assign(static_cast<std::size_t>(k), MatN::Zero());
    for (std::size_t i = ev.size(); i-- > 1;) {
      const Event& e = ev[i];
      const MatN& pa = ev[i - 1].p_after;
      if (e.kind == 4) {
        --k;
        dx_out[static_cast<std::size_t>(k)] = dx;
        ps_out[static_cast<std::size_t>(k)] = ps;
      } else if (e.kind == 2) {
        MatN gi = MatN::Identity();
        gi.template topLeftCorner<3, 3>() = e.g.inverse();
        dx = gi * dx + e.ky;
        ps = gi * ps * gi.transpose();
      } else {
        const MatN c = pa * e.a.transpose() * e.p_after.inverse();
        dx = c * dx;
        ps = pa + c * (ps - e.p_after) * c.transpose();
      }
    }
  }
};

// A standing IMU with biases, position fixes whose errors are a first-order
// Gauss-Markov process (the fix-error states, NC = 3), zero-velocity updates,
// and the filter's restarts: a GNSS reset of velocity and position, a heading
// set (attitude about the vertical restarted).
struct FixErrorRun {
  using Core = Eskf<5, 3>;
  static constexpr int N = Core::N;
  using MatN = Core::MatN;
  using VecN = Core::VecN;
  Tap<5, 3> tap;
  std::vector<Eigen::Matrix<double, 21, 1>> forward_rows;  // the recorder's nominal layout
  std::vector<Eigen::Matrix<double, 21, 1>> smoothed_rows;
  std::vector<MatN> smoothed_p;
  std::vector<VecN> tb_dx;
  std::vector<MatN> tb_ps;

  FixErrorRun() {
    std::mt19937 rng(5);
    std::normal_distribution<double> n01;
    Core core;
    tap.core = &core;
    core.observer = &tap;
    const Geodetic llh{0.70, -1.83, 1600.0};
    const Vec3 r0 = geodetic_to_ecef(llh);
    Euler e;
    e.yaw_rad = 0.4;
    e.pitch_rad = 0.05;
    e.roll_rad = -0.03;
    const Quat q_true = quat_body_to_ecef(e, llh.lat_rad, llh.lon_rad);
    core.nav.r_ecef_m = r0 + Vec3(0.3, -0.2, 0.5);
    core.nav.q_eb = q_true * quat_from_rotvec(Vec3(0.004, -0.003, 0.05));
    core.noise.gyro_white_var = Vec3::Constant(1e-8);
    core.noise.accel_white_var = Vec3::Constant(1e-5);
    core.noise.gyro_bias_drive_var = Vec3::Constant(1e-12);
    core.noise.accel_bias_drive_var = Vec3::Constant(1e-8);
    core.noise.fix_error_var_ned = Vec3(0.02 * 0.02, 0.02 * 0.02, 0.04 * 0.04);
    core.noise.fix_error_inv_tau = 1.0 / 60.0;
    core.P.setZero();
    core.P.block<3, 3>(es::att, es::att) = Vec3(1e-4, 1e-4, 4e-2).asDiagonal();
    core.P.block<3, 3>(es::vel, es::vel) = Mat3::Identity() * 0.01;
    core.P.block<3, 3>(es::pos, es::pos) = Mat3::Identity() * 1.0;
    core.P.block<3, 3>(es::bg, es::bg) = Mat3::Identity() * 1e-8;
    core.P.block<3, 3>(es::ba, es::ba) = Mat3::Identity() * 1e-3;
    core.P.block<3, 3>(Core::kFixError, Core::kFixError) = core.fix_error_stationary_cov();
    core.note_restart(0, N);
    auto output = [&] {
      tap.output();
      Eigen::Matrix<double, 21, 1> row;
      row << core.nav.t_s, core.nav.r_ecef_m, core.nav.v_ecef_mps, core.nav.q_eb.w(), core.nav.q_eb.x(),
          core.nav.q_eb.y(), core.nav.q_eb.z(), core.imu.gyro_bias_rad_per_s, core.imu.accel_bias_mps2,
          core.fix_error, 0.0;
      forward_rows.push_back(row);
    };
    output();
    const Vec3 bg(2e-4, -1e-4, 3e-4), ba(0.05, -0.03, 0.1);
    const Vec3 f_true = -(q_true.conjugate() * normal_gravity_ecef(r0));
    const Vec3 w_true = q_true.conjugate() * earth_rate_ecef();
    const double dt = 0.01;
    const Mat3 c_en = rot_ned_to_ecef(llh.lat_rad, llh.lon_rad);
    const GaussMarkovStep gm = gauss_markov_step(core.noise.fix_error_inv_tau, 0.25);
    Vec3 b_true = c_en * Vec3(0.02 * n01(rng), 0.02 * n01(rng), 0.04 * n01(rng));
    for (int k = 1; k <= 6000; ++k) {
      Increment inc;
      inc.dt_s = dt;
      for (int i = 0; i < 3; ++i) {
        inc.dtheta_rad(i) = (w_true(i) + bg(i)) * dt + 1e-4 * std::sqrt(dt) * n01(rng);
        inc.dv_mps(i) = (f_true(i) + ba(i)) * dt + 3e-3 * std::sqrt(dt) * n01(rng);
      }
      core.propagate(inc);
      if (k % 25 == 0) {  // a 4 Hz fix, 1 cm white on top of its correlated error
        b_true *= gm.phi;
        const Vec3 w = c_en * Vec3(0.02 * n01(rng), 0.02 * n01(rng), 0.04 * n01(rng)) * std::sqrt(gm.qd_per_var);
        b_true += w;
        Vec3 z = r0 + b_true;
        for (int i = 0; i < 3; ++i) z(i) += 0.01 * n01(rng);
        const auto m = position_fix(core, z, Mat3::Identity() * 1e-4, Vec3::Zero());
        core.update(m.y, m.H, m.R, 0.0);
      }
      if (k % 50 == 10) {
        const auto m = zero_velocity(core, 0.02);
        core.update(m.y, m.H, m.R, 0.0);
      }
      if (k == 2000) {  // reset to GNSS: velocity and position restart (InsFilter::reset_to_fix)
        core.nav.r_ecef_m = r0 + Vec3(0.1, 0.1, -0.2);
        core.P.middleRows<6>(es::vel).setZero();
        core.P.middleCols<6>(es::vel).setZero();
        core.P.block<3, 3>(es::vel, es::vel) = Mat3::Identity() * 0.04;
        core.P.block<3, 3>(es::pos, es::pos) = Mat3::Identity() * 0.25;
        core.note_restart(es::vel, 6);
      }
      if (k == 4000) {  // heading set: the attitude about the body's up axis starts afresh
        const Vec3 up_b = core.nav.q_eb.conjugate() * core.nav.r_ecef_m.normalized();
        const Mat3 keep = Mat3::Identity() - up_b * up_b.transpose();
        core.P.middleRows<3>(es::att) = (keep * core.P.middleRows<3>(es::att)).eval();
        core.P.middleCols<3>(es::att) = (core.P.middleCols<3>(es::att) * keep).eval();
        core.P.block<3, 3>(es::att, es::att) += up_b * up_b.transpose() * 1e-2;
        core.note_attitude_map(keep);
      }
      if (k % 5 == 0) output();
    }
    core.observer = nullptr;
    const long n = tap.rec.outputs();
    smoothed_rows.assign(static_cast<std::size_t>(n), Eigen::Matrix<double, 21, 1>::Zero());
    smoothed_p.assign(static_cast<std::size_t>(n), MatN::Zero());
    tap.rec.smooth([&](long k, const double* row, const MatN& p) {
      smoothed_rows[static_cast<std::size_t>(k)] = Eigen::Map<const Eigen::Matrix<double, 21, 1>>(row);
      smoothed_p[static_cast<std::size_t>(k)] = p;
    });
    tap.textbook(tb_dx, tb_ps);
  }
};

}  // namespace

TEST_CASE("smoother on the loose core with fix-error states, resets and a heading set equals a textbook RTS") {
  FixErrorRun run;
  const std::size_t n = run.smoothed_rows.size();
  REQUIRE(n == run.tb_dx.size());
  REQUIRE(n == run.forward_rows.size());
  double d_pos = 0.0, d_fe = 0.0, d_vel = 0.0, d_p = 0.0, moved = 0.0;
  for (std::size_t k = 0; k < n; ++k) {
    const auto& s = run.smoothed_rows[k];
    const auto& f = run.forward_rows[k];
    const auto& dx = run.tb_dx[k];
    // The textbook's smoothed position, velocity and fix error: forward nominal plus its dx.
    d_pos = std::max(d_pos, (s.segment<3>(1) - (f.segment<3>(1) + dx.segment<3>(es::pos))).cwiseAbs().maxCoeff());
    d_vel = std::max(d_vel, (s.segment<3>(4) - (f.segment<3>(4) + dx.segment<3>(es::vel))).cwiseAbs().maxCoeff());
    d_fe = std::max(d_fe, (s.segment<3>(17) - (f.segment<3>(17) + dx.segment<3>(FixErrorRun::Core::kFixError)))
                              .cwiseAbs().maxCoeff());
    moved = std::max(moved, dx.segment<3>(FixErrorRun::Core::kFixError).cwiseAbs().maxCoeff());
    // Covariance of everything but the attitude (its rows turn with the smoothed attitude).
    const auto a = run.smoothed_p[k].bottomRightCorner<15, 15>();
    const auto b = run.tb_ps[k].bottomRightCorner<15, 15>();
    d_p = std::max(d_p, ((a - b).array() / (a.diagonal() * a.diagonal().transpose()).array().sqrt()).abs().maxCoeff());
  }
  CHECK(moved > 0.005);  // smoothing does move the fix error (by more than rounding)
  CHECK(d_pos < 1e-6);
  CHECK(d_vel < 1e-7);
  CHECK(d_fe < 1e-6);
  CHECK(d_p < 1e-6);
}

// Fixed-interval smoothing of the error-state filter's forward pass.
//
// Form: the modified Bryson-Frazier recursion (Bierman), the RTS smoother
// written with the adjoint lambda (N) and its information Lambda (N x N):
//   at an output epoch   dx_s = -P lambda,  P_s = P - P Lambda P
//   across Phi (or A)    lambda <- Phi^T lambda,  Lambda <- Phi^T Lambda Phi
//   across an update     L = I - K H
//                        lambda <- L^T lambda - H^T S^-1 y
//                        Lambda <- L^T Lambda L + H^T S^-1 H
// It gives the RTS smoother's states and covariances (tests compare with a
// textbook RTS) but needs neither the prior covariances nor an inverse of
// them, so a singular prior (constant states, restarted blocks) is no harm.
//
// Error-state bookkeeping: every injection is followed by the reset
// dx_new = G (dx_old - dx_injected), G = I - [dtheta/2]x on the attitude
// block (the ESKF notes, docs/references.md). Going backwards the adjoint of the new error definition
// is carried to the old one by lambda <- G^T lambda, Lambda <- G^T Lambda G,
// before the update step; the injected dx itself is the update's K y, which the
// update step accounts for. The smoothed error at an output epoch is relative
// to the forward nominal there; it is injected (with its own reset) to give
// the smoothed nominal state and covariance.
//
// Re-initialisations (start-up, heading set, restart after a long IMU gap,
// reset to GNSS, receiver clock re-set) arrive as transitions A that zero the
// restarted states: information flows back through what was kept (IMU errors
// across a gap restart) and not through what restarted (a break there).
//
// The forward pass is recorded on a tape of records kept in memory up to a
// chunk size, then written in chunks to an unnamed temporary file and read
// back chunk by chunk, newest first.
//
// Cost of the backward pass per output epoch: Phi^T Lambda Phi over Phi's
// non-zeros only (a third of a step's Phi loose, a sixth tight), P - P Lambda P
// as one dense product and half of a second (or, where only the variances and a
// block are wanted, their dot products); an update works on the columns its H
// uses. On the default drive, whole covariances, it takes 0.8 of the forward
// pass's CPU time loose and 1.1 tight (benchmarks/bench_smoother.py speed).
#pragma once

#include <cstdint>
#include <array>
#include <cstdio>
#include <cstring>
#include <functional>
#include <string>
#include <vector>

#include "gpsins/eskf.hpp"
#include "gpsins/eskf_observer.hpp"
#include "gpsins/filter_variants.hpp"

namespace gpsins {

// Records of doubles, readable last to first; spills to a temporary file.
class SmootherTape {
 public:
  enum Kind : std::int32_t { kPropagate = 1, kUpdate = 2, kTransition = 3, kOutput = 4 };

  explicit SmootherTape(std::size_t chunk_bytes = std::size_t(64) << 20);
  ~SmootherTape();
  SmootherTape(const SmootherTape&) = delete;
  SmootherTape& operator=(const SmootherTape&) = delete;

  // Appends one record: n doubles of payload, then its kind and length.
  double* append(Kind kind, int n);
  std::size_t bytes() const { return bytes_; }  // everything recorded
  std::size_t spilled_bytes() const { return spilled_; }
  std::size_t chunks_spilled() const { return chunks_.size(); }

  // Visits the records newest first: f(kind, payload, n).
  void for_each_backward(const std::function<void(Kind, const double*, int)>& f);

 private:
  void spill();
  std::size_t chunk_bytes_;
  std::vector<double> buf_;  // current chunk (payload and trailers as doubles)
  struct Chunk {
    long offset;
    std::size_t n;
  };
  std::vector<Chunk> chunks_;
  std::FILE* file_ = nullptr;
  long file_end_ = 0;
  std::size_t bytes_ = 0, spilled_ = 0;
};

// The smoother's backward pass, independent of what the nominal state is:
// emit(output index, stored nominal payload, smoothed error dx, smoothed P).
template <int N>
class BackwardPass {
 public:
  using VecN = Eigen::Matrix<double, N, 1>;
  using MatN = Eigen::Matrix<double, N, N>;
  using Emit = std::function<void(long, const double*, int, const VecN&, const MatN&)>;

  // Output payload: [nominal (n_nominal doubles), P upper triangle by rows].
  static constexpr int kPacked = N * (N + 1) / 2;

  static void pack(const MatN& p, double* o) {
    for (int i = 0; i < N; ++i)
      for (int j = i; j < N; ++j) *o++ = p(i, j);
  }
  static MatN unpack(const double* o) {
    MatN p;
    for (int i = 0; i < N; ++i)
      for (int j = i; j < N; ++j) p(i, j) = p(j, i) = *o++;
    return p;
  }

  // A transition's record (Phi or a re-initialisation's A): for each column a 64-bit
  // mask of its non-zero rows, its bits copied into a double, then the non-zeros
  // column by column. A step's Phi is about two thirds zeros (the tight filter's, with
  // its diagonal slots and clock, five sixths), and the pass visits only the rest.
  static_assert(N <= 64, "a transition record's column mask is 64 bits");
  static void record_transition(SmootherTape& tape, SmootherTape::Kind kind, const MatN& a) {
    const int nz = static_cast<int>((a.array() != 0.0).count());
    double* d = tape.append(kind, N + nz);
    double* v = d + N;
    for (int j = 0; j < N; ++j) {
      std::uint64_t mask = 0;
      for (int i = 0; i < N; ++i)
        if (const double x = a(i, j); x != 0.0) {
          mask |= std::uint64_t(1) << i;
          *v++ = x;
        }
      std::memcpy(d + j, &mask, sizeof mask);
    }
  }

  // blocks: the states whose covariances with each other are wanted (bit i: state i); of
  // the others only the variances are formed, the rest of the emitted matrix is zero.
  static constexpr std::uint64_t kAllStates = N == 64 ? ~std::uint64_t(0) : (std::uint64_t(1) << N) - 1;
  static void run(SmootherTape& tape, long n_outputs, const Emit& emit, std::uint64_t blocks = kAllStates) {
    std::array<int, N> cov_states;
    int n_cov = 0;
    for (int i = 0; i < N; ++i)
      if (blocks >> i & 1) cov_states[n_cov++] = i;
    VecN lam = VecN::Zero();
    MatN Lam = MatN::Zero();
    long index = n_outputs;
    tape.for_each_backward([&](SmootherTape::Kind kind, const double* d, int n) {
      switch (kind) {
        case SmootherTape::kPropagate:
        case SmootherTape::kTransition:
          transition_step(d, lam, Lam);
          break;
        case SmootherTape::kUpdate:
          update_step(d, lam, Lam);
          break;
        case SmootherTape::kOutput: {
          const int n_nom = n - kPacked;
          const MatN p = unpack(d + n_nom);
          const VecN dx = -p * lam;
          // P - P Lambda P: one dense product, then the lower triangle as dot
          // products of columns (P is symmetric), mirrored.
          const MatN w = Lam * p;
          MatN ps;
          if (n_cov == N) {
            for (int j = 0; j < N; ++j)
              for (int i = j; i < N; ++i) ps(i, j) = ps(j, i) = p(i, j) - p.col(i).dot(w.col(j));
          } else {  // the variances and the wanted block only (a replay's sigmas and navigation block)
            ps.setZero();
            for (int i = 0; i < N; ++i) ps(i, i) = p(i, i) - p.col(i).dot(w.col(i));
            for (int b = 0; b < n_cov; ++b)
              for (int a = b + 1; a < n_cov; ++a) {
                const int i = cov_states[a], j = cov_states[b];
                ps(i, j) = ps(j, i) = p(i, j) - p.col(i).dot(w.col(j));
              }
          }
          emit(--index, d, n_nom, dx, ps);
          break;
        }
      }
    });
  }

 private:
  // lambda <- Phi^T lambda, Lambda <- Phi^T Lambda Phi. Only Phi's non-zeros
  // (record_transition) are visited, column by column, each scaling a whole
  // column of Lambda.
  static void transition_step(const double* d, VecN& lam, MatN& Lam) {
    std::array<int, N + 1> start;
    std::array<int, N * N> row;
    const double* val = d + N;  // record_transition's layout
    int nz = 0;
    for (int j = 0; j < N; ++j) {
      start[j] = nz;
      std::uint64_t mask;
      std::memcpy(&mask, d + j, sizeof mask);
      for (; mask; mask &= mask - 1) row[nz++] = __builtin_ctzll(mask);
    }
    start[N] = nz;
    VecN l;
    MatN m;  // Lambda Phi
    for (int j = 0; j < N; ++j) {
      double acc = 0.0;
      auto mj = m.col(j);
      mj.setZero();
      for (int k = start[j]; k < start[j + 1]; ++k) {
        acc += val[k] * lam(row[k]);
        mj.noalias() += val[k] * Lam.col(row[k]);
      }
      l(j) = acc;
    }
    lam = l;
    const MatN mt = m.transpose();  // Phi^T Lambda, Lambda being symmetric
    for (int j = 0; j < N; ++j) {
      auto lj = Lam.col(j);
      lj.setZero();
      for (int k = start[j]; k < start[j + 1]; ++k) lj.noalias() += val[k] * mt.col(row[k]);
    }
    Lam = 0.5 * (Lam + Lam.transpose()).eval();  // keep rounding from building up an asymmetric part
  }

  // Payload: M, H (M x N), K (N x M), S^-1 (M x M), y (M), G (3 x 3), column-major.
  static void update_step(const double* d, VecN& lam, MatN& Lam) {
    const int m = static_cast<int>(d[0]);
    const double* p = d + 1;
    const Eigen::Map<const Eigen::Matrix<double, Eigen::Dynamic, N>> H(p, m, N);
    p += m * N;
    const Eigen::Map<const Eigen::Matrix<double, N, Eigen::Dynamic>> K(p, N, m);
    p += N * m;
    const Eigen::Map<const Eigen::MatrixXd> s_inv(p, m, m);
    p += m * m;
    const Eigen::Map<const Eigen::VectorXd> y(p, m);
    p += m;
    const Eigen::Map<const Mat3> g(p);
    // Reset: to the error definition before it.
    lam.template head<3>() = (g.transpose() * lam.template head<3>()).eval();
    Lam.template topRows<3>() = (g.transpose() * Lam.template topRows<3>()).eval();
    Lam.template leftCols<3>() = (Lam.template leftCols<3>() * g).eval();
    // L = I - K H differs from I only in the columns C where H is non-zero
    // (3 of 15 for a velocity update, 6 for a fix with a lever arm):
    //   L^T Lambda L = Lambda except rows and columns C, which are X = Lambda L_C
    //   and, where both are in C, L_C^T X.
    // L is formed first: when an update nearly pins a state (K H close to I
    // there) this keeps the small result accurate, where Lambda - H^T K^T
    // Lambda - ... would cancel large terms.
    using ColsC = Eigen::Matrix<double, N, Eigen::Dynamic, Eigen::ColMajor, N, N>;
    std::array<int, N> c;
    int nc = 0;
    for (int j = 0; j < N; ++j)
      if ((H.col(j).array() != 0.0).any()) c[nc++] = j;
    ColsC lc(N, nc);
    Eigen::MatrixXd hc(m, nc);  // H's columns C
    for (int t = 0; t < nc; ++t) {
      hc.col(t) = H.col(c[t]);
      lc.col(t).noalias() = -K * hc.col(t);
      lc(c[t], t) += 1.0;
    }
    const ColsC x = Lam * lc;
    Eigen::Matrix<double, Eigen::Dynamic, Eigen::Dynamic, Eigen::ColMajor, N, N> cc = lc.transpose() * x;
    cc = (0.5 * (cc + cc.transpose())).eval();
    cc.noalias() += hc.transpose() * s_inv * hc;
    const Eigen::VectorXd w = s_inv * y;
    VecN lnew = lam;
    for (int t = 0; t < nc; ++t) lnew(c[t]) = lc.col(t).dot(lam) - hc.col(t).dot(w);
    lam = lnew;
    for (int t = 0; t < nc; ++t) {
      Lam.col(c[t]) = x.col(t);
      Lam.row(c[t]) = x.col(t).transpose();
    }
    for (int t = 0; t < nc; ++t)
      for (int u = 0; u < nc; ++u) Lam(c[u], c[t]) = cc(u, t);
    Lam = 0.5 * (Lam + Lam.transpose()).eval();  // the reset's products round asymmetrically
  }
};

// Records the forward pass of an InsFilter's core. Propagation steps between
// two other records are multiplied into one transition (so with output every
// k IMU samples the tape holds one Phi per output or update, not per sample).
// The flags an output row ends with (EskfRecorder::output's flags, a batch run's state rows): their sum.
inline constexpr int kRowFlagStandstill = 1, kRowFlagHeadingKnown = 2;

template <int NB, int NC, int NT = 0>
class EskfRecorder final : public EskfObserver<3 * NB + NC + NT> {
 public:
  static constexpr int N = 3 * NB + NC + NT;
  using Core = Eskf<NB, NC, NT>;
  using MatN = Eigen::Matrix<double, N, N>;
  using Base = EskfObserver<N>;
  // Nominal payload: t, r, v, q (w x y z), bg, ba, [sg, sa], [[sis slots] clock or fix error], [time offset],
  // flags: after the quaternion one value per error state, in its order.
  static constexpr int kNominal = 1 + 3 + 3 + 4 + 6 + (NB == 7 ? 6 : 0) + NC + NT + 1;
  static constexpr int kRowPos = 1, kRowVel = 4, kRowQuat = 7, kRowBias = 11;  // where each starts in it
  using Pass = BackwardPass<N>;

  explicit EskfRecorder(std::size_t chunk_bytes) : tape_(chunk_bytes) {}

  void on_propagate(const MatN& phi) override {
    if (have_phi_)
      phi_ = (phi * phi_).eval();
    else
      phi_ = phi;
    have_phi_ = true;
  }
  void on_update(const typename Base::MatRef& H, const typename Base::MatRef& K, const typename Base::MatRef& s_inv,
                 const typename Base::VecRef& y, const Mat3& g) override {
    flush_phi();
    const int m = static_cast<int>(H.rows());
    double* d = tape_.append(SmootherTape::kUpdate, 1 + 2 * m * N + m * m + m + 9);
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
  }
  void on_transition(const MatN& a) override {
    flush_phi();
    Pass::record_transition(tape_, SmootherTape::kTransition, a);
  }

  // An output epoch: the core's nominal state and covariance now.
  void output(const Core& e, double flags) {
    flush_phi();
    double* o = tape_.append(SmootherTape::kOutput, kNominal + Pass::kPacked);
    *o++ = e.nav.t_s;
    for (int i = 0; i < 3; ++i) *o++ = e.nav.r_ecef_m(i);
    for (int i = 0; i < 3; ++i) *o++ = e.nav.v_ecef_mps(i);
    *o++ = e.nav.q_eb.w();
    *o++ = e.nav.q_eb.x();
    *o++ = e.nav.q_eb.y();
    *o++ = e.nav.q_eb.z();
    for (int i = 0; i < 3; ++i) *o++ = e.imu.gyro_bias_rad_per_s(i);
    for (int i = 0; i < 3; ++i) *o++ = e.imu.accel_bias_mps2(i);
    if constexpr (NB == 7) {
      for (int i = 0; i < 3; ++i) *o++ = e.imu.gyro_scale_factor(i);
      for (int i = 0; i < 3; ++i) *o++ = e.imu.accel_scale_factor(i);
    }
    if constexpr (Core::kSisCount > 0)
      for (int i = 0; i < Core::kSisCount; ++i) *o++ = e.sis(i);
    if constexpr (Core::kHasClock) {
      *o++ = e.clock(0);
      *o++ = e.clock(1);
    }
    if constexpr (NC == 3)
      for (int i = 0; i < 3; ++i) *o++ = e.fix_error(i);
    if constexpr (NT == 1) *o++ = e.time_offset_s;
    *o++ = flags;
    Pass::pack(e.P, o);
    ++outputs_;
  }

  // Backward pass: emit(index, row of the smoothed nominal in the layout above
  // (flags last), smoothed covariance), newest first.
  // blocks: as BackwardPass::run's; the attitude is always among them (the reset after
  // the injection mixes its rows into the others').
  void smooth(const std::function<void(long, const double*, const MatN&)>& emit,
              std::uint64_t blocks = Pass::kAllStates);

  long outputs() const { return outputs_; }
  const SmootherTape& tape() const { return tape_; }

 private:
  void flush_phi() {
    if (!have_phi_) return;
    Pass::record_transition(tape_, SmootherTape::kPropagate, phi_);
    have_phi_ = false;
  }
  SmootherTape tape_;
  MatN phi_ = MatN::Identity();
  bool have_phi_ = false;
  long outputs_ = 0;
};

// Defined out of the class so that the extern declarations below keep it (the backward
// pass, the heaviest code here) out of the files that use a recorder: compiled once, in
// cpp/src/rts_recorders/, for the filters the core builds.
template <int NB, int NC, int NT>
void EskfRecorder<NB, NC, NT>::smooth(const std::function<void(long, const double*, const MatN&)>& emit,
                                      std::uint64_t blocks) {
  flush_phi();
  std::array<double, kNominal> row{};
  const auto smoothed = [&](long k, const double* nom, int, const typename Pass::VecN& dx, const MatN& ps) {
    std::copy(nom, nom + kNominal, row.begin());
    Quat q(nom[kRowQuat], nom[kRowQuat + 1], nom[kRowQuat + 2], nom[kRowQuat + 3]);
    Vec3 dth = dx.template segment<3>(es::att);
    MatN p = ps;
    // Before the first heading the error about the vertical is no estimate: the forward pass keeps it
    // unknown (sigma pi) and uncorrelated. Its smoothed value is left out of the injection, and its
    // variance out of the reset below, which would otherwise turn some of pi^2 into the tilt (the
    // smoothed tilt sigma came out up to 1.4x the forward's); it is put back about the vertical after.
    const bool heading_unknown = (static_cast<int>(nom[kNominal - 1]) & kRowFlagHeadingKnown) == 0;
    Vec3 up_b = Vec3::Zero();
    double yaw_var = 0.0;
    if (heading_unknown) {
      up_b = q.conjugate() * Vec3(nom[kRowPos], nom[kRowPos + 1], nom[kRowPos + 2]).normalized();
      yaw_var = up_b.dot(ps.template block<3, 3>(es::att, es::att) * up_b);
      const Mat3 keep = Mat3::Identity() - up_b * up_b.transpose();
      dth = keep * dth;
      p.template topRows<3>() = (keep * p.template topRows<3>()).eval();
      p.template leftCols<3>() = (p.template leftCols<3>() * keep).eval();
    }
    q = (q * quat_from_rotvec(dth)).normalized();
    for (int i = 0; i < 3; ++i) {
      row[static_cast<std::size_t>(kRowPos + i)] += dx(es::pos + i);
      row[static_cast<std::size_t>(kRowVel + i)] += dx(es::vel + i);
    }
    row[kRowQuat] = q.w();
    row[kRowQuat + 1] = q.x();
    row[kRowQuat + 2] = q.y();
    row[kRowQuat + 3] = q.z();
    for (int i = 0; i < N - es::bg; ++i) row[static_cast<std::size_t>(kRowBias + i)] += dx(es::bg + i);
    // The smoothed covariance in the error definition of the smoothed nominal.
    const Mat3 g = Mat3::Identity() - skew(0.5 * dth);
    p.template topRows<3>() = (g * p.template topRows<3>()).eval();
    p.template leftCols<3>() = (p.template leftCols<3>() * g.transpose()).eval();
    if (heading_unknown) p.template block<3, 3>(es::att, es::att) += yaw_var * up_b * up_b.transpose();
    emit(k, row.data(), p);
  };
  Pass::run(tape_, outputs_, smoothed, blocks | std::uint64_t(7) << es::att);
}

#define GPSINS_RECORDER_EXTERN(NB, NC, NT) extern template class EskfRecorder<NB, NC, NT>;
GPSINS_FOR_EACH_FILTER(GPSINS_RECORDER_EXTERN)
#undef GPSINS_RECORDER_EXTERN

}  // namespace gpsins

// The error-state Kalman filter core: nominal state, error covariance,
// discretisation, generic measurement update, injection and reset. It knows no
// sensor: aiding sources (aiding/*.hpp) hand it an innovation, H and R.
//
// Error state, in this order (the ESKF notes' local attitude error; docs/references.md):
//   dtheta (3)  attitude, body side: q_true = q (x) exp(dtheta)
//   dv (3), dr (3)  velocity and position, ECEF
//   dbg (3), dba (3)  gyro and accelerometer bias
//   [dsg (3), dsa (3)]  gyro and accelerometer scale factor       (NB = 7)
//   then NC augmented states, by sensor:
//   [clock bias c*dt (m), clock drift (m/s)]       NC = 2 (pseudoranges, no bias states)
//   [sis (kSisSlots), clock bias, clock drift]     NC = kTightAugmented (tight: each slot
//                 one tracked satellite's signal-in-space error (m), the broadcast orbit and
//                 clock's error along its line of sight; the filter assigns the slots)
//   [fix error db (3), ECEF (m)]                   NC = 3 (loose: Gauss-Markov fix errors)
//   then NT = 0 or 1 time-offset state (estimate_time_offset):
//   [dt_imu (s)]  the IMU stamps' offset from GNSS time: at filter time t the
//                 nominal state describes the vehicle at true (GNSS) time t + dt_imu,
//                 so dt_imu is what the data set's declared IMU time offset lacks.
//                 A measurement h of the vehicle at GNSS time t is then
//                 h(t) = h(nominal) - h_dot dt_imu (aiding/time_offset.hpp).
// The fix error is the time-correlated part of the receiver's position error
// (multipath, atmosphere residuals: correlated over tens of seconds); the fix is
// then z = r_antenna + b + white (aiding/position_fix.hpp).
// IMU model per axis: measured = (1 + s) true + b + noise, so the corrected
// increment is (measured - b dt) / (1 + s).
//
// Firmware rules: fixed-size Eigen types only, no allocation and no exceptions
// here; work per IMU sample is bounded and the same for every sample.
#pragma once

#include <array>
#include <cmath>

#include "gpsins/attitude.hpp"
#include "gpsins/earth.hpp"
#include "gpsins/eskf_observer.hpp"
#include "gpsins/filter_variants.hpp"
#include "gpsins/strapdown.hpp"

namespace gpsins {

namespace es {  // first index of each 3-block
inline constexpr int att = 0, vel = 3, pos = 6, bg = 9, ba = 12, sg = 15, sa = 18;
inline constexpr int kNavStates = 9;  // attitude, velocity, position: the navigation block
}  // namespace es

// Signal-in-space bias states of the tight filter: one per slot, a satellite to a slot.
inline constexpr int kSisSlots = 12;
inline constexpr int kTightAugmented = kSisSlots + 2;

// Continuous-time noise densities and bias dynamics, per axis.
struct ProcessNoise {
  Vec3 gyro_white_var = Vec3::Zero();        // rad^2/s   (ARW^2)
  Vec3 accel_white_var = Vec3::Zero();       // (m/s)^2/s (VRW^2)
  Vec3 gyro_bias_drive_var = Vec3::Zero();   // (rad/s)^2/s
  Vec3 accel_bias_drive_var = Vec3::Zero();  // (m/s^2)^2/s
  Vec3 gyro_bias_inv_tau = Vec3::Zero();     // 1/s; 0 = random walk or constant
  Vec3 accel_bias_inv_tau = Vec3::Zero();
  Vec3 gyro_sf_drive_var = Vec3::Zero();  // 1/s
  Vec3 accel_sf_drive_var = Vec3::Zero();
  // Gyro misalignment left by the calibration (variance of each off-diagonal element
  // of the triad's matrix, rad^2): white attitude noise driven by the rate, below.
  double gyro_misalignment_var = 0.0;
  double clock_bias_var = 0.0;   // m^2/s
  double clock_drift_var = 0.0;  // m^2/s^3
  double time_offset_var = 0.0;  // s^2/s: the IMU time offset's random walk (NT = 1)
  // Signal-in-space slots: each a first-order Gauss-Markov error with its own
  // stationary variance (m^2, set when a satellite takes the slot) and one 1/tau
  // (0: a random constant, the broadcast error changing over hours).
  Eigen::Matrix<double, kSisSlots, 1> sis_var = Eigen::Matrix<double, kSisSlots, 1>::Zero();
  double sis_inv_tau = 0.0;
  // Fix error (NC = 3): first-order Gauss-Markov per local north, east, down axis,
  // stationary variance (m^2) and 1/tau (1/s), one tau for all axes.
  Vec3 fix_error_var_ned = Vec3::Zero();
  double fix_error_inv_tau = 0.0;
};

// First-order Gauss-Markov process db/dt = -b / tau + w, E[w(t) w(s)] = q delta(t - s)
// with q = 2 sigma^2 / tau (so the stationary variance is sigma^2). Over dt:
//   b(t + dt) = exp(-dt / tau) b(t) + int_0^dt exp(-(dt - s) / tau) w(t + s) ds,
//   Phi = exp(-dt / tau),
//   Qd  = int_0^dt exp(-2 s / tau) q ds = q tau / 2 (1 - exp(-2 dt / tau))
//       = sigma^2 (1 - exp(-2 dt / tau)) = sigma^2 (1 - Phi^2),
// exact for any dt (no series), and the stationary variance is kept: Phi^2 sigma^2 + Qd = sigma^2.
struct GaussMarkovStep {
  double phi = 1.0;
  double qd_per_var = 0.0;  // Qd / sigma^2
};
inline GaussMarkovStep gauss_markov_step(double inv_tau, double dt) {
  const double phi = std::exp(-dt * inv_tau);
  return GaussMarkovStep{phi, -std::expm1(-2.0 * dt * inv_tau)};
}

struct ImuErrorEstimate {
  Vec3 gyro_bias_rad_per_s = Vec3::Zero();
  Vec3 accel_bias_mps2 = Vec3::Zero();
  Vec3 gyro_scale_factor = Vec3::Zero();
  Vec3 accel_scale_factor = Vec3::Zero();
};

// Result of one measurement update.
template <int M>
struct UpdateResult {
  Eigen::Matrix<double, M, 1> innovation = Eigen::Matrix<double, M, 1>::Zero();
  Eigen::Matrix<double, M, 1> innovation_sigma = Eigen::Matrix<double, M, 1>::Zero();
  double nis = 0.0;
  double log_det_s = 0.0;  // ln det S: with the NIS, the update's Gaussian log-likelihood
  double r_scale = 1.0;    // > 1: a robust update, its R scaled by this (InsFilter::apply)
  bool accepted = false;
  bool guarded = false;           // rejected because the result was not a valid covariance
  bool attitude_refused = false;  // rejected: the attitude correction exceeded its limit
};

// Square blocks of 3x3 matrices with a non-zero mask, so products skip the
// structural zeros of F and Phi (about half the work of dense products).
template <int NB>
struct BlockMat {
  std::array<Mat3, NB * NB> b;
  std::array<bool, NB * NB> nz{};
  Mat3& at(int i, int j) { return b[i * NB + j]; }
  const Mat3& at(int i, int j) const { return b[i * NB + j]; }
  bool has(int i, int j) const { return nz[i * NB + j]; }
  void set(int i, int j, const Mat3& m) {
    b[i * NB + j] = m;
    nz[i * NB + j] = true;
  }
  void add(int i, int j, const Mat3& m) {
    if (has(i, j))
      at(i, j) += m;
    else
      set(i, j, m);
  }
  void clear() { nz.fill(false); }
};

template <int NB>
void block_mul(const BlockMat<NB>& a, const BlockMat<NB>& c, BlockMat<NB>& out) {
  out.clear();
  for (int i = 0; i < NB; ++i)
    for (int k = 0; k < NB; ++k) {
      if (!a.has(i, k)) continue;
      for (int j = 0; j < NB; ++j)
        if (c.has(k, j)) out.add(i, j, a.at(i, k) * c.at(k, j));
    }
}

template <int NB, int NC, int NT = 0>
class Eskf {
 public:
  static_assert(NB == 5 || NB == 7, "5 blocks (15 states) or 7 (with scale factors)");
  static_assert(NC == 0 || NC == 2 || NC == kTightAugmented || NC == 3,
                "none, clock bias + drift (with or without signal-in-space slots), or the fix error");
  static_assert(NT == 0 || NT == 1, "no time offset state, or one");
  static constexpr int kNav = 3 * NB;
  static constexpr int N = kNav + NC + NT;
  static constexpr bool kHasClock = NC == 2 || NC == kTightAugmented;
  static constexpr int kSisCount = NC == kTightAugmented ? kSisSlots : 0;
  static constexpr int kSis = kNav;                // kSisCount slots
  static constexpr int kClock = kNav + kSisCount;  // kHasClock
  static constexpr int kFixError = kNav;           // NC == 3
  using VecSis = Eigen::Matrix<double, kSisSlots, 1>;
  static constexpr int kTimeOffset = kNav + NC;  // NT == 1
  using VecN = Eigen::Matrix<double, N, 1>;
  using MatN = Eigen::Matrix<double, N, N>;
  using MatNav = Eigen::Matrix<double, kNav, kNav>;

  NavState nav;
  ImuErrorEstimate imu;
  Eigen::Vector2d clock = Eigen::Vector2d::Zero();  // receiver clock bias (m), drift (m/s)
  Vec3 fix_error = Vec3::Zero();                    // NC == 3: the fix's correlated error estimate, ECEF (m)
  VecSis sis = VecSis::Zero();                      // kSisCount: each slot's signal-in-space error estimate (m)
  double time_offset_s = 0.0;                       // NT == 1: dt_imu (see the layout above)
  MatN P = MatN::Zero();
  ProcessNoise noise;
  EskfObserver<N>* observer = nullptr;  // a smoother recording the forward pass (rts.hpp)

  // Raw increment corrected by the current bias and scale-factor estimates.
  Increment corrected(const Increment& raw) const {
    Increment c = raw;
    c.dtheta_rad =
        (raw.dtheta_rad - imu.gyro_bias_rad_per_s * raw.dt_s).cwiseQuotient(Vec3::Ones() + imu.gyro_scale_factor);
    c.dv_mps = (raw.dv_mps - imu.accel_bias_mps2 * raw.dt_s).cwiseQuotient(Vec3::Ones() + imu.accel_scale_factor);
    return c;
  }

  // The covariance may be carried over several increments at once, up to this long (s): the
  // navigation state is mechanised at every increment, its error's covariance once per
  // interval (0: at every increment). Every update, injection and transition calls
  // flush_covariance() first, as does InsFilter wherever it changes P; a reader between two
  // flushes sees P as of the last one. An increment as long as the interval is carried alone.
  double covariance_interval_s = 0.0;

  // Advance nominal state and covariance across one raw increment.
  void propagate(const Increment& raw) {
    const Increment c = corrected(raw);
    const double dt = c.dt_s;
    if (!(dt > 0.0)) return;
    const Mat3 c0 = nav.q_eb.toRotationMatrix();
    mechanise(nav, c);
    // Clock: bias integrates drift.
    if constexpr (kHasClock) clock(0) += clock(1) * dt;
    if constexpr (kSisCount > 0) sis *= gauss_markov_step(noise.sis_inv_tau, dt).phi;
    // Fix error: its estimate decays as the process's mean does.
    if constexpr (NC == 3) fix_error *= gauss_markov_step(noise.fix_error_inv_tau, dt).phi;
    // Flush when one more increment of this length would overrun the interval; an increment that
    // would be flushed alone (a 64 Hz IMU's every one) goes straight to the propagation.
    const double limit = covariance_interval_s * (1.0 + 1e-9);
    if (!(carried_.dt_s > 0.0) && 2.0 * dt > limit) {
      propagate_covariance(c.dtheta_rad / dt, c.dv_mps / dt, c0, dt);
      return;
    }
    carried_.add(c, c0);
    if (carried_.dt_s + dt > limit) flush_covariance();
  }

  // Propagate the covariance over the increments carried since the last flush, as one
  // increment: the mean rate, and the specific force in the body frame at its start.
  // The linear time-invariant parts (clock, Gauss-Markov states) compose exactly; the
  // rest is the same expansion over the longer step (its error grows as the step's
  // cube: test_eskf and bench_filter's nees measure it).
  void flush_covariance() {
    if (!(carried_.dt_s > 0.0)) return;
    const double dt = carried_.dt_s;
    const Vec3 w = carried_.dtheta_rad / dt, f = carried_.dv_start_body / dt;
    const Mat3 c0 = carried_.c_start;
    carried_ = CarriedIncrements{};
    propagate_covariance(w, f, c0, dt);
  }

  // The fix error's stationary covariance in ECEF at the current position.
  Mat3 fix_error_stationary_cov() const {
    const Geodetic llh = ecef_to_geodetic(nav.r_ecef_m);
    const Mat3 c_en = rot_ned_to_ecef(llh.lat_rad, llh.lon_rad);
    return c_en * noise.fix_error_var_ned.asDiagonal() * c_en.transpose();
  }

  // Continuous-time error dynamics F over an IMU interval of length dt (block form),
  // from the corrected rate w and specific force f = delta-v / dt, both as the
  // increments give them: delta-v expressed in the body frame at the start of the
  // interval, whose attitude is c0 (the mechanisation turns it with c0).
  //   Attitude: the error is in the body frame of its time; over the interval it
  //   turns by -[w]x, and the gyro's bias and scale-factor errors enter through
  //   the corrected rate (m - b) / (1 + s): -(dbg + w .* dsg) / (1 + s).
  //   Velocity: an attitude error at the start turns delta-v, -c0 [delta-v]x, the
  //   exact one-step term. With constant F the series adds F_va F_aa dt^2 / 2, the
  //   error's own turn; F_va = -c0 [f]x R_h, R_h = exp(w dt / 2), takes it back out
  //   to second order (it is c_mid [f_mid]x with both at mid-interval). The
  //   accelerometer's errors enter delta-v in its frame: -c0 (dba + f .* dsa) / (1 + s).
  void error_dynamics(const Vec3& w, const Vec3& f, const Mat3& c0, double dt, BlockMat<NB>& F) const {
    using namespace es;
    F.clear();
    const Vec3 r = nav.r_ecef_m;
    const double rn = r.norm();
    const Vec3 u = r / rn;
    const double we = wgs84::omega_rad_per_s;
    // Gravity gradient: point-mass term plus the centrifugal part of normal gravity.
    Mat3 grad = wgs84::gm_m3_per_s2 / (rn * rn * rn) * (3.0 * u * u.transpose() - Mat3::Identity());
    grad(0, 0) += we * we;
    grad(1, 1) += we * we;
    const Vec3 inv_g = (Vec3::Ones() + imu.gyro_scale_factor).cwiseInverse();
    const Vec3 inv_a = (Vec3::Ones() + imu.accel_scale_factor).cwiseInverse();
    F.set(0, 0, -skew(w));
    F.set(0, 3, Mat3((-inv_g).asDiagonal()));
    F.set(1, 0, -c0 * skew(f) * dcm_from_rotvec(0.5 * dt * w));
    F.set(1, 1, -2.0 * skew(earth_rate_ecef()));
    F.set(1, 2, grad);
    F.set(1, 4, -c0 * inv_a.asDiagonal());
    F.set(2, 1, Mat3::Identity());
    if (noise.gyro_bias_inv_tau.any()) F.set(3, 3, Mat3((-noise.gyro_bias_inv_tau).asDiagonal()));
    if (noise.accel_bias_inv_tau.any()) F.set(4, 4, Mat3((-noise.accel_bias_inv_tau).asDiagonal()));
    if constexpr (NB == 7) {
      F.set(0, 5, Mat3((-w.cwiseProduct(inv_g)).asDiagonal()));
      F.set(1, 6, -c0 * Mat3(f.cwiseProduct(inv_a).asDiagonal()));
    }
  }

  // Misalignment of the gyro triad: the rate error M w, M's off-diagonal elements
  // unknown with variance s^2 (the calibration's uncertainty). It is a constant times
  // the motion, so neither the bias nor the scale-factor states absorb it. Carrying M
  // as 6 more states (or Schmidt "consider" parameters) would grow P by a quarter for
  // an error that stays small: a triad misaligned by m measures a rotation about an
  // axis tilted by m, so after turning by phi about a fixed axis u its body-frame
  // attitude error is bounded, variance 4 s^2 sin^2(phi / 2) on each axis across u
  // (2 s^2 after a quarter turn, 4 s^2 after a half turn, 0 after a full one).
  // Here it is white attitude noise driven by the rate,
  //   q_i = s^2 Theta (|w|^2 - w_i^2) / |w|,
  // which adds s^2 Theta phi across u over a rotation by phi at any rate. Theta = 4 / pi
  // matches the truth's variance after a quarter and after a half turn (it is larger
  // below a quarter turn, and the attitude aiding bounds what it adds beyond a half).
  // The error follows the net rotation, so w is the rate averaged over kNetRateTauS:
  // back-and-forth motion (a hand's swing, a walker's gait, vibration) turns nowhere and
  // leaves an error bounded by its small amplitude, while the instantaneous |w| would
  // add noise at every swing (test_eskf: a tenth of it over a 1.5 Hz swing).
  static constexpr double kCoherentRotationRad = 4.0 / 3.14159265358979323846;
  static constexpr double kNetRateTauS = 1.0;
  Vec3 net_rate = Vec3::Zero();  // rad/s, the corrected rate's exponential average
  Vec3 misalignment_noise_var(const Vec3& w) const {
    const double w2 = w.squaredNorm();
    if (!(noise.gyro_misalignment_var > 0.0) || !(w2 > 0.0)) return Vec3::Zero();
    const Vec3 across = Vec3::Constant(w2) - w.cwiseAbs2();
    return noise.gyro_misalignment_var * kCoherentRotationRad / std::sqrt(w2) * across;
  }

  // Diagonal blocks of the continuous noise covariance Qc = G W G^T; w is the net rate
  // (rad/s) that drives the misalignment term.
  void noise_blocks(const Vec3& w, const Mat3& c, std::array<Mat3, NB>& qc) const {
    qc[0] = (noise.gyro_white_var + misalignment_noise_var(w)).asDiagonal();
    qc[1] = c * noise.accel_white_var.asDiagonal() * c.transpose();
    qc[2].setZero();
    qc[3] = noise.gyro_bias_drive_var.asDiagonal();
    qc[4] = noise.accel_bias_drive_var.asDiagonal();
    if constexpr (NB == 7) {
      qc[5] = noise.gyro_sf_drive_var.asDiagonal();
      qc[6] = noise.accel_sf_drive_var.asDiagonal();
    }
  }

  // Phi = exp(F dt) through dt^3 and Qd = int_0^dt exp(F s) Qc exp(F s)^T ds
  // through dt^4 (Van Loan's blocks expanded). Qd needs the extra order: the
  // velocity-position cross term gets the attitude noise through F_v,theta
  // only at dt^4, and that is 1e-4 of the term at 64 Hz. The rest dropped is
  // below 1e-8 of what is kept (test_eskf compares with a dense Van Loan).
  void discretise(const BlockMat<NB>& F, const std::array<Mat3, NB>& qc, double dt, BlockMat<NB>& phi,
                  MatNav& qd) const {
    BlockMat<NB> f2, f3;
    block_mul(F, F, f2);
    block_mul(f2, F, f3);
    phi.clear();
    for (int i = 0; i < NB; ++i) phi.set(i, i, Mat3::Identity());
    const double h2 = dt * dt / 2.0, h3 = dt * dt * dt / 6.0, h4 = dt * dt * dt * dt / 24.0;
    for (int i = 0; i < NB; ++i)
      for (int j = 0; j < NB; ++j) {
        if (F.has(i, j)) phi.add(i, j, dt * F.at(i, j));
        if (f2.has(i, j)) phi.add(i, j, h2 * f2.at(i, j));
        if (f3.has(i, j)) phi.add(i, j, h3 * f3.at(i, j));
      }
    // With S = F Qc: Qd = Qc dt + (S + S^T) dt^2/2 + (F S + 2 S F^T + (F S)^T) dt^3/6
    //   + (F^2 S + 3 F S F^T + transposes) dt^4/24. Qc is block diagonal.
    qd.setZero();
    for (int i = 0; i < NB; ++i) qd.template block<3, 3>(3 * i, 3 * i) = qc[i] * dt;
    for (int i = 0; i < NB; ++i)
      for (int j = 0; j < NB; ++j) {
        // Terms added together with their transposes.
        Mat3 t = Mat3::Zero();
        if (F.has(i, j)) t += h2 * F.at(i, j) * qc[j];
        if (f2.has(i, j)) t += h3 * f2.at(i, j) * qc[j];
        if (f3.has(i, j)) t += h4 * f3.at(i, j) * qc[j];
        // Symmetric terms: F Qc F^T and F^2 Qc F^T (the latter also with its transpose).
        Mat3 sym = Mat3::Zero();
        for (int k = 0; k < NB; ++k) {
          if (!F.has(j, k)) continue;
          const Mat3 qft = qc[k] * F.at(j, k).transpose();
          if (F.has(i, k)) sym += (2.0 * h3) * F.at(i, k) * qft;
          if (f2.has(i, k)) t += (3.0 * h4) * f2.at(i, k) * qft;
        }
        qd.template block<3, 3>(3 * i, 3 * j) += t + sym;
        qd.template block<3, 3>(3 * j, 3 * i) += t.transpose();
      }
  }

  void propagate_covariance(const Vec3& w, const Vec3& f, const Mat3& c, double dt) {
    BlockMat<NB> F, phi;
    std::array<Mat3, NB> qc;
    MatNav qd;
    error_dynamics(w, f, c, dt, F);
    net_rate += -std::expm1(-dt / kNetRateTauS) * (w - net_rate);
    noise_blocks(net_rate, c, qc);
    discretise(F, qc, dt, phi, qd);

    // P <- Phi P Phi^T + Qd, with Phi = blkdiag(Phi_nav, Phi of the augmented states).
    MatN m;
    for (int i = 0; i < NB; ++i) {
      auto rows = m.template middleRows<3>(3 * i);
      rows.setZero();
      for (int k = 0; k < NB; ++k)
        if (phi.has(i, k)) rows.noalias() += phi.at(i, k) * P.template middleRows<3>(3 * k);
    }
    if constexpr (kHasClock) {
      m.template middleRows<2>(kClock) = P.template middleRows<2>(kClock);
      m.row(kClock) += dt * P.row(kClock + 1);
    }
    // Signal in space: Phi = phi I, Qd = (1 - phi^2) x each slot's stationary variance.
    GaussMarkovStep sis_gm;
    if constexpr (kSisCount > 0) {
      sis_gm = gauss_markov_step(noise.sis_inv_tau, dt);
      m.template middleRows<kSisCount>(kSis) = sis_gm.phi * P.template middleRows<kSisCount>(kSis);
    }
    // Fix error: Phi = phi I, Qd = (1 - phi^2) x its stationary covariance.
    GaussMarkovStep gm;
    if constexpr (NC == 3) {
      gm = gauss_markov_step(noise.fix_error_inv_tau, dt);
      m.template middleRows<3>(kFixError) = gm.phi * P.template middleRows<3>(kFixError);
    }
    // Time offset: constant (Phi = 1) plus its random walk.
    if constexpr (NT == 1) m.row(kTimeOffset) = P.row(kTimeOffset);
    for (int j = 0; j < NB; ++j) {
      auto cols = P.template middleCols<3>(3 * j);
      cols.setZero();
      for (int k = 0; k < NB; ++k)
        if (phi.has(j, k)) cols.noalias() += m.template middleCols<3>(3 * k) * phi.at(j, k).transpose();
    }
    if constexpr (kSisCount > 0) {
      P.template middleCols<kSisCount>(kSis) = sis_gm.phi * m.template middleCols<kSisCount>(kSis);
      P.diagonal().template segment<kSisCount>(kSis) += sis_gm.qd_per_var * noise.sis_var;
    }
    if constexpr (kHasClock) {
      P.template middleCols<2>(kClock) = m.template middleCols<2>(kClock);
      P.col(kClock) += dt * m.col(kClock + 1);
      const double qb = noise.clock_bias_var, qdr = noise.clock_drift_var;
      P(kClock, kClock) += qb * dt + qdr * dt * dt * dt / 3.0;
      P(kClock, kClock + 1) += qdr * dt * dt / 2.0;
      P(kClock + 1, kClock) += qdr * dt * dt / 2.0;
      P(kClock + 1, kClock + 1) += qdr * dt;
    }
    if constexpr (NC == 3) {
      P.template middleCols<3>(kFixError) = gm.phi * m.template middleCols<3>(kFixError);
      P.template block<3, 3>(kFixError, kFixError) += gm.qd_per_var * fix_error_stationary_cov();
    }
    if constexpr (NT == 1) {
      P.col(kTimeOffset) = m.col(kTimeOffset);
      P(kTimeOffset, kTimeOffset) += noise.time_offset_var * dt;
    }
    P.template topLeftCorner<kNav, kNav>() += qd;
    symmetrise();
    if (observer) {
      MatN full = MatN::Zero();
      for (int i = 0; i < NB; ++i)
        for (int k = 0; k < NB; ++k)
          if (phi.has(i, k)) full.template block<3, 3>(3 * i, 3 * k) = phi.at(i, k);
      if constexpr (kHasClock) full.template block<2, 2>(kClock, kClock) << 1.0, dt, 0.0, 1.0;
      if constexpr (kSisCount > 0) full.diagonal().template segment<kSisCount>(kSis).setConstant(sis_gm.phi);
      if constexpr (NC == 3) full.template block<3, 3>(kFixError, kFixError) = gm.phi * Mat3::Identity();
      if constexpr (NT == 1) full(kTimeOffset, kTimeOffset) = 1.0;
      observer->on_propagate(full);
    }
  }

  // The filter's re-initialisations, told to the observer: `count` states from
  // `first` restart independently of their past.
  void note_restart(int first, int count) {
    flush_covariance();
    if (!observer) return;
    MatN a = MatN::Identity();
    a.diagonal().segment(first, count).setZero();
    observer->on_transition(a);
  }
  // Any other linear map the filter applies to the error: P <- A P A^T (plus noise).
  void note_transition(const MatN& a) {
    flush_covariance();
    if (observer) observer->on_transition(a);
  }
  // The attitude error replaced by keep * (attitude error) plus independent noise.
  void note_attitude_map(const Mat3& keep) {
    flush_covariance();
    if (!observer) return;
    MatN a = MatN::Identity();
    a.template block<3, 3>(es::att, es::att) = keep;
    observer->on_transition(a);
  }

  void symmetrise() { P = 0.5 * (P + P.transpose()).eval(); }

  // Kalman update with chi-square gate (gate <= 0 disables it), Joseph form,
  // injection and reset. A result that is not a valid covariance is undone.
  // attitude_limit > 0: the report's divergence test, an update whose attitude
  // correction is larger (rad) is refused.
  template <int M>
  UpdateResult<M> update(const Eigen::Matrix<double, M, 1>& y, const Eigen::Matrix<double, M, N>& H,
                         const Eigen::Matrix<double, M, M>& R, double gate, double attitude_limit = 0.0);

  void inject_and_reset(const VecN& dx) {
    using namespace es;
    flush_covariance();
    const Vec3 dth = dx.template segment<3>(att);
    nav.q_eb = (nav.q_eb * quat_from_rotvec(dth)).normalized();
    nav.v_ecef_mps += dx.template segment<3>(vel);
    nav.r_ecef_m += dx.template segment<3>(pos);
    imu.gyro_bias_rad_per_s += dx.template segment<3>(bg);
    imu.accel_bias_mps2 += dx.template segment<3>(ba);
    if constexpr (NB == 7) {
      imu.gyro_scale_factor += dx.template segment<3>(sg);
      imu.accel_scale_factor += dx.template segment<3>(sa);
    }
    if constexpr (kHasClock) clock += dx.template segment<2>(kClock);
    if constexpr (kSisCount > 0) sis += dx.template segment<kSisCount>(kSis);
    if constexpr (NC == 3) fix_error += dx.template segment<3>(kFixError);
    if constexpr (NT == 1) time_offset_s += dx(kTimeOffset);
    // Reset: the attitude error is now relative to the corrected q (the ESKF notes).
    const Mat3 g = Mat3::Identity() - skew(0.5 * dth);
    P.template middleRows<3>(att) = (g * P.template middleRows<3>(att)).eval();
    P.template middleCols<3>(att) = (P.template middleCols<3>(att) * g.transpose()).eval();
    symmetrise();
  }

  VecN sigma() const { return P.diagonal().cwiseMax(0.0).cwiseSqrt(); }

 private:
  // The corrected increments whose covariance propagation is still to come.
  struct CarriedIncrements {
    double dt_s = 0.0;
    Vec3 dtheta_rad = Vec3::Zero();     // summed rotation increments
    Vec3 dv_start_body = Vec3::Zero();  // summed delta-v, in the body frame at the first one's start
    Mat3 c_start = Mat3::Identity();    // body to ECEF at the first one's start
    void add(const Increment& c, const Mat3& c0) {
      if (dt_s > 0.0) {
        dv_start_body += c_start.transpose() * (c0 * c.dv_mps);
      } else {
        c_start = c0;
        dv_start_body = c.dv_mps;
      }
      dt_s += c.dt_s;
      dtheta_rad += c.dtheta_rad;
    }
  };
  CarriedIncrements carried_;
};

// Eskf::update is defined in eskf_update.hpp, which only the files that compile it include:
// the filter variants' updates with M = 1, 2, 3 rows are compiled once each, in
// cpp/src/eskf_updates/ (an N x 3 gain's products, unrolled by Eigen for each of the
// twelve state layouts, cost 2.3 GB and 3 CPU-minutes in one file), and the declarations
// below send every other caller there.
#define GPSINS_ESKF_UPDATE(NB, NC, NT, M)                                                                    \
  template UpdateResult<M> Eskf<NB, NC, NT>::update<M>(const Eigen::Matrix<double, M, 1>&,                   \
                                                       const Eigen::Matrix<double, M, Eskf<NB, NC, NT>::N>&, \
                                                       const Eigen::Matrix<double, M, M>&, double, double);
#define GPSINS_ESKF_UPDATES_EXTERN(NB, NC, NT)                                                                        \
  extern GPSINS_ESKF_UPDATE(NB, NC, NT, 1) extern GPSINS_ESKF_UPDATE(NB, NC, NT, 2) extern GPSINS_ESKF_UPDATE(NB, NC, \
                                                                                                              NT, 3)

GPSINS_FOR_EACH_FILTER(GPSINS_ESKF_UPDATES_EXTERN)

}  // namespace gpsins

#include <doctest/doctest.h>

#include <random>
#include <vector>

#include "gpsins/aiding/position_fix.hpp"
#include "gpsins/aiding/zero_velocity.hpp"
#include "gpsins/earth.hpp"
#include "gpsins/eskf_update.hpp"
#include "gpsins/rts.hpp"

// The smoother on the real core (test_rts.cpp: on the tape and linear problems); a file
// of its own so that neither needs more compile memory than a small machine has.
using namespace gpsins;

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
    int kind;      // 1 propagate, 2 update, 3 transition, 4 output
    MatN a;        // Phi or A
    MatN p_after;  // the forward covariance after this record
    VecN ky;       // an update's injected correction
    Mat3 g;        // an update's reset
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
          core.nav.q_eb.y(), core.nav.q_eb.z(), core.imu.gyro_bias_rad_per_s, core.imu.accel_bias_mps2, core.fix_error,
          0.0;
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
    d_fe = std::max(
        d_fe,
        (s.segment<3>(17) - (f.segment<3>(17) + dx.segment<3>(FixErrorRun::Core::kFixError))).cwiseAbs().maxCoeff());
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

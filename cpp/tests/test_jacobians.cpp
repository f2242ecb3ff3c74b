// The filter's Jacobians against finite differences of what they linearise.
//
// F (through Phi): a nominal state and a perturbed "true" state (the nominal with one error
// direction injected by the filter's own injection, biases and scale factors
// included) are propagated by the filter's own propagate() over one raw IMU
// increment; the propagated difference, read back in the error state's
// definition, gives Phi column by column (central differences). It is compared
// block by block with the Phi the code builds from its F (what the covariance
// propagation uses), over random states and motions up to roller-coaster rates.
//
// H: every aiding source's H against central differences of an independent
// measurement model written here from the physics (antenna at r + C l, its
// velocity v + C (w_eb x l) with w from the raw gyro and the state's bias and
// scale factor, the Earth rate seen by a standing gyro, the geometric range
// with its Sagnac term), not from the aiding headers' own h.
#include <doctest/doctest.h>

#include <map>
#include <random>
#include <string>

#include "gpsins/aiding/position_fix.hpp"
#include "gpsins/aiding/pseudorange.hpp"
#include "gpsins/aiding/range_rate.hpp"
#include "gpsins/aiding/velocity.hpp"
#include "gpsins/aiding/zero_rate.hpp"
#include "gpsins/aiding/zero_velocity.hpp"
#include "gpsins/eskf.hpp"

using namespace gpsins;

namespace {
constexpr double kDeg = M_PI / 180.0;
using Filter = Eskf<7, 2>;
constexpr int N = Filter::N;
using VecN = Filter::VecN;
using MatN = Filter::MatN;
constexpr std::array<const char*, 7> kBlock{"att", "vel", "pos", "bg", "ba", "sg", "sa"};

// Step sizes per error block: large where the state enters linearly (so the
// difference stays far above rounding at ECEF magnitudes), small for angles.
VecN fd_steps() {
  VecN h;
  h << Vec3::Constant(1e-5), Vec3::Constant(1.0), Vec3::Constant(10.0), Vec3::Constant(1e-5), Vec3::Constant(1e-3),
      Vec3::Constant(1e-5), Vec3::Constant(1e-5), 10.0, 1.0;
  return h;
}

// The navigation and IMU part (the first 21 states) of the error x_true - x_nominal in the filter's
// definitions (inverse of inject_and_reset's injection).
template <class F, class V>
void nav_imu_error(const F& nominal, const F& truth, V& e) {
  e.template segment<3>(es::att) = rotvec_from_quat(nominal.nav.q_eb.conjugate() * truth.nav.q_eb);
  e.template segment<3>(es::vel) = truth.nav.v_ecef_mps - nominal.nav.v_ecef_mps;
  e.template segment<3>(es::pos) = truth.nav.r_ecef_m - nominal.nav.r_ecef_m;
  e.template segment<3>(es::bg) = truth.imu.gyro_bias_rad_per_s - nominal.imu.gyro_bias_rad_per_s;
  e.template segment<3>(es::ba) = truth.imu.accel_bias_mps2 - nominal.imu.accel_bias_mps2;
  e.template segment<3>(es::sg) = truth.imu.gyro_scale_factor - nominal.imu.gyro_scale_factor;
  e.template segment<3>(es::sa) = truth.imu.accel_scale_factor - nominal.imu.accel_scale_factor;
}

VecN error_between(const Filter& nominal, const Filter& truth) {
  VecN e;
  nav_imu_error(nominal, truth, e);
  e.segment<2>(Filter::kClock) = truth.clock - nominal.clock;
  return e;
}

Filter injected(const Filter& f, const VecN& dx) {
  Filter t = f;
  t.inject_and_reset(dx);
  return t;
}

struct Case {
  Filter f;
  Increment raw;
  Vec3 lever;
};

Vec3 uniform3(std::mt19937_64& rng, double a) {
  std::uniform_real_distribution<double> u(-a, a);
  return Vec3(u(rng), u(rng), u(rng));
}

// A random nominal state (anywhere on Earth, 0-1 km high, any attitude, up to
// 100 m/s) with bias, scale-factor and clock estimates, and a raw increment with
// body rates up to 3 rad/s and specific force up to 4 g (the roller coaster).
Case random_case(std::mt19937_64& rng, double dt) {
  std::uniform_real_distribution<double> u(0.0, 1.0);
  Case c;
  const Geodetic site{(u(rng) * 170.0 - 85.0) * kDeg, (u(rng) * 360.0 - 180.0) * kDeg, u(rng) * 1000.0};
  c.f.nav.r_ecef_m = geodetic_to_ecef(site);
  c.f.nav.v_ecef_mps = uniform3(rng, 60.0);
  c.f.nav.q_eb = quat_from_rotvec(uniform3(rng, 2.0)) * quat_body_to_ecef({0, 0, 0}, site.lat_rad, site.lon_rad);
  c.f.imu.gyro_bias_rad_per_s = uniform3(rng, 0.01);
  c.f.imu.accel_bias_mps2 = uniform3(rng, 0.1);
  c.f.imu.gyro_scale_factor = uniform3(rng, 0.003);
  c.f.imu.accel_scale_factor = uniform3(rng, 0.003);
  c.f.clock = Eigen::Vector2d(u(rng) * 1e5, u(rng) * 100.0 - 50.0);
  const Vec3 g_body = c.f.nav.q_eb.conjugate() * normal_gravity_ecef(c.f.nav.r_ecef_m);
  c.raw.dt_s = dt;
  c.raw.dtheta_rad = uniform3(rng, 3.0) * dt;
  c.raw.dv_mps = (uniform3(rng, 30.0) - g_body) * dt;
  c.lever = uniform3(rng, 1.5);
  return c;
}

// Relative error per (row block, column block): |A - B| / |B| in the Frobenius
// norm, or |A - B| alone where B is zero (then it must be zero too).
struct Worst {
  std::map<std::string, double> rel;
  void add(const std::string& key, double v) {
    auto& w = rel[key];
    w = std::max(w, v);
  }
};

template <class A, class B>
double rel_err(const A& a, const B& b, double floor) {
  return (a - b).norm() / std::max(b.norm(), floor);
}

template <int NB>
Eigen::Matrix<double, 3 * NB, 3 * NB> dense(const BlockMat<NB>& m) {
  Eigen::Matrix<double, 3 * NB, 3 * NB> d = Eigen::Matrix<double, 3 * NB, 3 * NB>::Zero();
  for (int i = 0; i < NB; ++i)
    for (int j = 0; j < NB; ++j)
      if (m.has(i, j)) d.template block<3, 3>(3 * i, 3 * j) = m.at(i, j);
  return d;
}

// Phi over one step by central differences of the filter's own propagation.
MatN phi_by_differences(const Case& c) {
  const VecN h = fd_steps();
  Filter nominal = c.f;
  nominal.propagate(c.raw);
  MatN phi;
  for (int j = 0; j < N; ++j) {
    VecN dx = VecN::Zero();
    dx(j) = h(j);
    Filter plus = injected(c.f, dx), minus = injected(c.f, -dx);
    plus.propagate(c.raw);
    minus.propagate(c.raw);
    phi.col(j) = (error_between(nominal, plus) - error_between(nominal, minus)) / (2.0 * h(j));
  }
  return phi;
}

// The code's Phi exactly as propagate() forms it: F from the corrected rates, the
// attitude at the start of the interval and the position after the step, discretised by the code.
Eigen::Matrix<double, 21, 21> code_phi(const Case& c) {
  const Increment k = c.f.corrected(c.raw);
  const double dt = k.dt_s;
  const Mat3 c0 = c.f.nav.q_eb.toRotationMatrix();
  Filter after = c.f;
  mechanise(after.nav, k);
  BlockMat<7> F, phi;
  std::array<Mat3, 7> qc;
  Eigen::Matrix<double, 21, 21> qd;
  after.error_dynamics(k.dtheta_rad / dt, k.dv_mps / dt, c0, dt, F);
  after.noise_blocks(k.dtheta_rad / dt, c0, qc);
  after.discretise(F, qc, dt, phi, qd);
  return dense(phi);
}

// Typical error sizes per block (rad, m/s, m, rad/s, m/s^2, -, -): a block's
// error matters in proportion to s_row^-1 dPhi s_col.
Eigen::Matrix<double, 7, 1> typical_sigma() {
  Eigen::Matrix<double, 7, 1> s;
  s << 0.01, 0.1, 1.0, 1e-3, 0.01, 1e-3, 1e-3;
  return s;
}
}  // namespace

TEST_CASE("Phi matches a finite-difference linearisation of the mechanisation") {
  std::mt19937_64 rng(2005);
  const double dt = 1.0 / 64.0;
  Worst rel, scaled;
  const auto s = typical_sigma();
  double worst_clock = 0.0, worst_bias_rows = 0.0;
  for (int trial = 0; trial < 60; ++trial) {
    const Case c = random_case(rng, dt);
    const MatN phi = phi_by_differences(c);
    // The bias and scale-factor states are constants of the mechanisation: their rows of Phi are identity.
    worst_bias_rows =
        std::max(worst_bias_rows, (phi.middleRows<12>(es::bg) - MatN::Identity().middleRows<12>(es::bg)).norm());
    // Clock: bias integrates drift, nothing else couples.
    Eigen::Matrix2d clk;
    clk << 1.0, dt, 0.0, 1.0;
    worst_clock = std::max(worst_clock, (phi.bottomRightCorner<2, 2>() - clk).norm() +
                                            phi.bottomLeftCorner<2, 21>().norm() + phi.topRightCorner<21, 2>().norm());
    const Eigen::Matrix<double, 21, 21> code = code_phi(c);
    for (int i = 0; i < 3; ++i)  // rows: attitude, velocity, position
      for (int j = 0; j < 7; ++j) {
        const Mat3 a = code.block<3, 3>(3 * i, 3 * j), b = phi.block<3, 3>(3 * i, 3 * j);
        const Mat3 dyn = i == j ? Mat3(b - Mat3::Identity()) : b;
        const std::string key = std::string(kBlock[i]) + "," + kBlock[j];
        // Relative to the block's own change over the step, where it has one.
        if (dyn.norm() > 1e-12) rel.add(key, (a - b).norm() / dyn.norm());
        scaled.add(key, (a - b).norm() * s(j) / s(i));
      }
  }
  for (const auto& [k, v] : scaled.rel)
    MESSAGE("Phi_" << k << ": worst relative error " << (rel.rel.count(k) ? rel.rel.at(k) : 0.0)
                   << ", worst scaled error " << v);
  MESSAGE("bias/scale-factor rows of Phi vs identity " << worst_bias_rows << ", clock block " << worst_clock);
  CHECK(worst_bias_rows < 1e-9);
  CHECK(worst_clock < 1e-9);
  // Blocks exact in the mechanisation: rounding and the series' dt^4 only. (pos,pos changes
  // by the gravity gradient's 1e-10 per step, at ECEF rounding: its scaled error is checked below.)
  CHECK(rel.rel["att,att"] < 1e-4);
  for (const char* k : {"vel,vel", "pos,vel"}) CHECK_MESSAGE(rel.rel[k] < 1e-5, std::string(k));
  // The gravity gradient: point mass + centrifugal against the mechanisation's normal gravity.
  CHECK(rel.rel["vel,pos"] < 2e-2);
  // Gyro and accelerometer bias and scale factor through (m - b) / (1 + s).
  for (const char* k : {"att,bg", "att,sg", "vel,ba", "vel,sa"}) CHECK_MESSAGE(rel.rel[k] < 1e-4, std::string(k));
  // An attitude error turns delta-v where delta-v is expressed, at the start of the interval
  // (F_va = -c0 [f]x exp(w dt / 2)): what is left is O((w dt)^2), 1.6e-4 at 3 rad/s and 64 Hz.
  // (With the mid-interval attitude and f taken as a mid-interval force it was 3.5e-2.)
  CHECK(rel.rel["vel,att"] < 1e-3);
  // Position blocks: a 1e-5 rad or 1e-3 m/s^2 step moves the position by 1e-8 m, near the
  // rounding of ECEF coordinates (1e-9 m), so their relative error is rounding; the scaled check below holds them.
  for (const char* k : {"pos,att", "pos,ba", "pos,sa"}) CHECK_MESSAGE(rel.rel[k] < 5e-2, std::string(k));
  // Everything else is second order over one step; in typical-sigma units below 1e-3 of a sigma.
  for (const auto& [k, v] : scaled.rel) CHECK_MESSAGE(v < 1e-2, k);
}

namespace {
// Independent measurement models of the true state x = nominal (+) dx.
struct World {
  Vec3 lever, raw_rate, sat;
};

Vec3 antenna_position(const Filter& x, const World& w) { return x.nav.r_ecef_m + x.nav.q_eb * w.lever; }

// The same about a fixed origin near the state, so differences are not lost to ECEF rounding.
Vec3 antenna_offset(const Filter& x, const World& w, const Vec3& origin) {
  return (x.nav.r_ecef_m - origin) + x.nav.q_eb * w.lever;
}

Vec3 antenna_velocity(const Filter& x, const World& w) {
  const Vec3 w_ib = (w.raw_rate - x.imu.gyro_bias_rad_per_s).cwiseQuotient(Vec3::Ones() + x.imu.gyro_scale_factor);
  const Vec3 w_eb = w_ib - x.nav.q_eb.conjugate() * earth_rate_ecef();
  return x.nav.v_ecef_mps + x.nav.q_eb * w_eb.cross(w.lever);
}

// What a standing gyro reports after the nominal bias is removed: the Earth rate in
// the true body frame, scaled by the true scale factor, plus the bias the nominal misses.
Vec3 standing_rate(const Filter& x, const Filter& nominal) {
  const Vec3 w_true = x.nav.q_eb.conjugate() * earth_rate_ecef();
  const Vec3 raw = w_true.cwiseProduct(Vec3::Ones() + x.imu.gyro_scale_factor) + x.imu.gyro_bias_rad_per_s;
  return (raw - nominal.imu.gyro_bias_rad_per_s).cwiseQuotient(Vec3::Ones() + nominal.imu.gyro_scale_factor);
}

double range_with_sagnac(const Filter& x, const World& w) {
  const Vec3 ra = antenna_position(x, w);
  const double sagnac = wgs84::omega_rad_per_s / 299792458.0 * (w.sat.x() * ra.y() - w.sat.y() * ra.x());
  return (w.sat - ra).norm() + sagnac + x.clock(0);
}

// Its rate along both ends' motion: the time derivative of range_with_sagnac with the
// satellite moving at sat_v and the antenna at antenna_velocity, plus the clock drift.
double range_rate_with_sagnac(const Filter& x, const World& w, const Vec3& sat_v) {
  const Vec3 ra = antenna_position(x, w), va = antenna_velocity(x, w);
  const Vec3 u = (w.sat - ra).normalized();
  const double sagnac_rate = wgs84::omega_rad_per_s / 299792458.0 *
                             (sat_v.x() * ra.y() + w.sat.x() * va.y() - sat_v.y() * ra.x() - w.sat.y() * va.x());
  return u.dot(sat_v - va) + sagnac_rate + x.clock(1);
}

template <int M, class H>
Eigen::Matrix<double, M, N> differences(const Filter& f, H h) {
  VecN step = fd_steps();
  step.segment<3>(es::att).setConstant(1e-3);  // measurement models are smooth: a larger step beats rounding
  Eigen::Matrix<double, M, N> out;
  for (int j = 0; j < N; ++j) {
    VecN dx = VecN::Zero();
    dx(j) = step(j);
    out.col(j) = (h(injected(f, dx)) - h(injected(f, -dx))) / (2.0 * step(j));
  }
  return out;
}

template <int M>
void compare_h(Worst& worst, const std::string& name, const Eigen::Matrix<double, M, N>& code,
               const Eigen::Matrix<double, M, N>& fd) {
  const double row_scale = fd.norm();
  for (int j = 0; j < 7; ++j) {
    const auto a = code.template middleCols<3>(3 * j), b = fd.template middleCols<3>(3 * j);
    if (a.norm() == 0.0 && b.norm() < 1e-6 * row_scale) continue;  // zero in both
    worst.add(name + "_" + kBlock[j], rel_err(a, b, 1e-3 * row_scale));
  }
  const auto ac = code.template rightCols<2>(), bc = fd.template rightCols<2>();
  if (ac.norm() != 0.0 || bc.norm() > 1e-6 * row_scale) worst.add(name + "_clock", rel_err(ac, bc, 1e-3 * row_scale));
}
}  // namespace

TEST_CASE("every aiding source's H matches finite differences of an independent measurement model") {
  std::mt19937_64 rng(1995);
  Worst worst;
  for (int trial = 0; trial < 100; ++trial) {
    const Case c = random_case(rng, 1.0 / 64.0);
    const Filter& f = c.f;
    World w{c.lever, c.raw.dtheta_rad / c.raw.dt_s, Vec3::Zero()};
    // A satellite 20 000 km up, above the local horizon.
    const Vec3 up = f.nav.r_ecef_m.normalized();
    w.sat = f.nav.r_ecef_m + 2.2e7 * (up + 0.8 * uniform3(rng, 1.0).cross(up)).normalized();

    const auto pf = position_fix(f, Vec3::Zero(), Mat3::Identity(), w.lever);
    compare_h<3>(worst, "position_fix", pf.H,
                 differences<3>(f, [&](const Filter& x) { return antenna_offset(x, w, f.nav.r_ecef_m); }));

    const auto gv = gnss_velocity(f, Vec3::Zero(), Mat3::Identity(), w.lever, w.raw_rate);
    compare_h<3>(worst, "gnss_velocity", gv.H,
                 differences<3>(f, [&](const Filter& x) { return antenna_velocity(x, w); }));

    const auto zv = zero_velocity(f, 0.01);
    compare_h<3>(worst, "zero_velocity", zv.H, differences<3>(f, [&](const Filter& x) { return x.nav.v_ecef_mps; }));

    const auto zr = zero_rate(f, Vec3::Zero(), Vec3::Ones());
    compare_h<3>(worst, "zero_rate", zr.H, differences<3>(f, [&](const Filter& x) { return standing_rate(x, f); }));

    const auto pr = pseudorange(f, w.lever, w.sat, 0.0, 0.0, 1.0);
    compare_h<1>(worst, "pseudorange", pr.H, differences<1>(f, [&](const Filter& x) {
                   return Eigen::Matrix<double, 1, 1>(range_with_sagnac(x, w));
                 }));

    const Vec3 sat_v = uniform3(rng, 3000.0);
    const auto rr = range_rate(f, w.lever, w.raw_rate, w.sat, sat_v, 0.0, 1.0);
    compare_h<1>(worst, "range_rate", rr.H, differences<1>(f, [&](const Filter& x) {
                   return Eigen::Matrix<double, 1, 1>(range_rate_with_sagnac(x, w, sat_v));
                 }));
    // Its innovation is the measurement less that model at the nominal state.
    CHECK(std::abs(rr.y(0) + range_rate_with_sagnac(f, w, sat_v)) < 1e-9 * (1.0 + std::abs(rr.y(0))));
  }
  for (const auto& [k, v] : worst.rel) MESSAGE(k << " worst relative error " << v);
  // Exact: position and velocity states, clock.
  for (const char* k :
       {"position_fix_pos", "position_fix_att", "gnss_velocity_vel", "zero_velocity_vel", "pseudorange_clock"})
    CHECK_MESSAGE(worst.rel[k] < 1e-6, std::string(k));
  // The pseudorange treats the Sagnac term as a constant: omega r_sat / c ~ 6e-6 of the line of sight.
  CHECK(worst.rel["pseudorange_pos"] < 1e-4);
  CHECK(worst.rel["pseudorange_att"] < 1e-4);
  // The range rate likewise treats the Sagnac rate as constant in the antenna's motion (omega |r_sat| / c).
  for (const char* k : {"range_rate_vel", "range_rate_pos", "range_rate_att", "range_rate_bg", "range_rate_sg"})
    CHECK_MESSAGE(worst.rel[k] < 1e-4, std::string(k));
  CHECK(worst.rel["range_rate_clock"] < 1e-6);
  CHECK(worst.rel["zero_rate_att"] < 1e-6);
  // The gyro's bias and scale factor enter through the corrected rate (m - b) / (1 + s): the
  // antenna velocity through its lever arm, the standing rate directly; the antenna velocity's
  // Earth-rate part turns with the attitude.
  for (const char* k : {"gnss_velocity_att", "gnss_velocity_bg", "gnss_velocity_sg", "zero_rate_bg", "zero_rate_sg"})
    CHECK_MESSAGE(worst.rel[k] < 1e-6, std::string(k));
}

// The loose filter's fix-error states (Eskf<7, 3>): the same two checks. Phi from
// central differences of propagate() (the estimate decays by exp(-dt / tau), nothing
// else couples) against the Phi the covariance propagation hands its observer; the
// fix's H against differences of z = r + C l + b.
namespace {
using FixFilter = Eskf<7, 3>;
constexpr int N3 = FixFilter::N;
using Vec3N = FixFilter::VecN;
using Mat3N = FixFilter::MatN;

struct PhiCapture final : EskfObserver<N3> {
  Mat3N phi = Mat3N::Zero();
  void on_propagate(const Mat3N& p) override { phi = p; }
  void on_update(const MatRef&, const MatRef&, const MatRef&, const VecRef&, const Mat3&) override {}
  void on_transition(const Mat3N&) override {}
};

FixFilter with_fix_error(const Filter& f, const Vec3& b, double tau_s) {
  FixFilter g;
  g.nav = f.nav;
  g.imu = f.imu;
  g.noise.fix_error_inv_tau = 1.0 / tau_s;
  g.noise.fix_error_var_ned = Vec3(1.5, 1.5, 3.0).cwiseAbs2();
  g.fix_error = b;
  return g;
}

Vec3N error_between3(const FixFilter& nominal, const FixFilter& truth) {
  Vec3N e;
  nav_imu_error(nominal, truth, e);
  e.segment<3>(FixFilter::kFixError) = truth.fix_error - nominal.fix_error;
  return e;
}

Vec3N fd_steps3() {
  Vec3N h;
  h << fd_steps().head<21>(), Vec3::Constant(1.0);
  return h;
}

FixFilter injected3(const FixFilter& f, const Vec3N& dx) {
  FixFilter t = f;
  t.inject_and_reset(dx);
  return t;
}
}  // namespace

TEST_CASE("fix-error states: Phi and the fix's H match finite differences") {
  std::mt19937_64 rng(2027);
  double worst_gm_phi = 0.0, worst_cross = 0.0, worst_nav = 0.0, worst_h = 0.0, worst_h_gm = 0.0;
  for (int trial = 0; trial < 40; ++trial) {
    const double dt = trial % 2 ? 1.0 / 64.0 : 1.0 / 400.0;
    const double tau = 5.0 + 100.0 * std::uniform_real_distribution<double>(0.0, 1.0)(rng);
    const Case c = random_case(rng, dt);
    const FixFilter f = with_fix_error(c.f, uniform3(rng, 3.0), tau);
    // Phi: differences of the filter's own propagation.
    const Vec3N h = fd_steps3();
    FixFilter nominal = f;
    PhiCapture cap;
    nominal.P = Mat3N::Identity();
    nominal.observer = &cap;
    nominal.propagate(c.raw);
    nominal.observer = nullptr;
    Mat3N fd;
    for (int j = 0; j < N3; ++j) {
      Vec3N dx = Vec3N::Zero();
      dx(j) = h(j);
      FixFilter plus = injected3(f, dx), minus = injected3(f, -dx);
      plus.propagate(c.raw);
      minus.propagate(c.raw);
      fd.col(j) = (error_between3(nominal, plus) - error_between3(nominal, minus)) / (2.0 * h(j));
    }
    const double phi_gm = std::exp(-dt / tau);
    worst_gm_phi = std::max(worst_gm_phi, (fd.bottomRightCorner<3, 3>() - phi_gm * Mat3::Identity()).norm() +
                                              (cap.phi.bottomRightCorner<3, 3>() - phi_gm * Mat3::Identity()).norm());
    worst_cross =
        std::max(worst_cross, fd.bottomLeftCorner<3, 21>().norm() + fd.topRightCorner<21, 3>().norm() +
                                  cap.phi.bottomLeftCorner<3, 21>().norm() + cap.phi.topRightCorner<21, 3>().norm());
    // The navigation block is the one the test above checks; here only that it is the same Phi.
    worst_nav = std::max(worst_nav, (cap.phi.topLeftCorner<21, 21>() - code_phi(c)).norm());

    // H of the fix: an independent model z = r + C l + b about a nearby origin.
    World w{c.lever, Vec3::Zero(), Vec3::Zero()};
    const auto pf = position_fix(f, Vec3::Zero(), Mat3::Identity(), w.lever);
    Vec3N step = fd_steps3();
    step.segment<3>(es::att).setConstant(1e-3);
    Eigen::Matrix<double, 3, N3> hd;
    for (int j = 0; j < N3; ++j) {
      Vec3N dx = Vec3N::Zero();
      dx(j) = step(j);
      const FixFilter p = injected3(f, dx), m = injected3(f, -dx);
      const Vec3 zp = (p.nav.r_ecef_m - f.nav.r_ecef_m) + p.nav.q_eb * w.lever + p.fix_error;
      const Vec3 zm = (m.nav.r_ecef_m - f.nav.r_ecef_m) + m.nav.q_eb * w.lever + m.fix_error;
      hd.col(j) = (zp - zm) / (2.0 * step(j));
    }
    worst_h = std::max(worst_h, rel_err(pf.H.leftCols<21>(), hd.leftCols<21>(), 1e-3));
    worst_h_gm = std::max(worst_h_gm, (pf.H.rightCols<3>() - hd.rightCols<3>()).norm());
    // The innovation removes the estimated fix error: z = h(x) gives y = 0.
    const Vec3 z = f.nav.r_ecef_m + f.nav.q_eb * w.lever + f.fix_error;
    CHECK((position_fix(f, z, Mat3::Identity(), w.lever).y).norm() < 1e-6);
  }
  MESSAGE("fix error: Phi block " << worst_gm_phi << ", cross blocks " << worst_cross
                                  << ", nav block vs the 21-state Phi " << worst_nav << "; H nav columns " << worst_h
                                  << ", H fix-error columns " << worst_h_gm);
  CHECK(worst_gm_phi < 1e-7);
  CHECK(worst_cross < 1e-6);
  CHECK(worst_nav < 1e-12);
  CHECK(worst_h < 1e-6);
  CHECK(worst_h_gm < 1e-9);
}

// InsFilter's vehicle aiding: the land vehicle's non-holonomic constraint and
// a dual-antenna baseline's heading and pitch.
#include <cmath>

#include "gpsins/aiding/baseline_attitude.hpp"
#include "gpsins/aiding/nonholonomic.hpp"
#include "internal.hpp"

namespace gpsins {

namespace {

constexpr double kIntervalTolerance_s = 1e-9;  // rounding in the sample times: an interval is not missed by it

}  // namespace

// The land-vehicle constraint while moving (standing, the zero-velocity update
// says more); at most every nhc_interval_s.
template <int NB, int NC, int NT>
void InsFilter<NB, NC, NT>::constrain_vehicle(const Increment& inc) {
  if (!(inc.dt_s > 0.0) || standstill_ || t_last_ - last_nhc_t_ < cfg_.nhc_interval_s - kIntervalTolerance_s) return;
  if (core_.nav.v_ecef_mps.norm() < cfg_.nhc_min_speed_mps) return;
  last_nhc_t_ = t_last_;
  const double vertical = cfg_.nhc_vertical_sigma_mps > 0.0 ? cfg_.nhc_vertical_sigma_mps : cfg_.nhc_sigma_mps;
  const auto m =
      nonholonomic(core_, c_vb_, cfg_.vehicle_point_body_m, inc.dtheta_rad / inc.dt_s, cfg_.nhc_sigma_mps, vertical);
  record(kNonholonomic, apply(m, 2, kNonholonomic), 2);
  ++counters_.nonholonomic_updates;
}

// A dual-antenna heading (and pitch), carried from its time to now with the
// turn the gyros measured over the last increment. While the heading is not
// yet known its variance is pi^2 about the vertical (decouple_yaw), and a
// heading measurement sets it through the ordinary update: the yaw row is
// linear in the attitude error about the vertical, so one update moves the
// yaw by the whole (wrapped) innovation.
template <int NB, int NC, int NT>
void InsFilter<NB, NC, NT>::process_attitude(const AttitudeInput& a, const Increment& inc) {
  if (!initialised()) return;
  ++counters_.baseline_attitude_updates;
  const Vec3 b = cfg_.antenna_baseline_body.normalized();
  double yaw = a.yaw_rad, pitch = a.pitch_rad;
  if (inc.dt_s > 0.0) {
    const Geodetic llh = ecef_to_geodetic(core_.nav.r_ecef_m);
    const Mat3 c_nb = rot_ned_to_ecef(llh.lat_rad, llh.lon_rad).transpose() * core_.nav.q_eb.toRotationMatrix();
    const BaselineAngles now = baseline_angles(c_nb * b);
    const Vec3 u_dot = c_nb * (inc.dtheta_rad / inc.dt_s).cross(b);
    const Eigen::Vector2d rates = now.d_du * u_dot;
    const double lag = t_last_ - a.t_s;
    yaw += rates(0) * lag;
    pitch += rates(1) * lag;
  }
  const bool was_known = heading_known();
  // The first heading may turn the attitude by anything: not a divergence.
  const double limit = was_known ? attitude_limit() : 0.0;
  auto use = [&](const auto& m, int dof) {
    const auto r = core_.update(m.y, m.H, m.R, gate(dof), limit);
    // Before record(), so that it does not decouple the yaw just measured.
    if (!was_known && r.accepted) advance(PhaseEvent::HeadingMeasured);
    record(kBaselineAttitude, r, dof);
  };
  if (std::isfinite(pitch))
    use(baseline_attitude<2>(core_, b, yaw, pitch, a.sigma_yaw_rad, a.sigma_pitch_rad), 2);
  else
    use(baseline_attitude<1>(core_, b, yaw, pitch, a.sigma_yaw_rad, 0.0), 1);
  if (heading_known() && !was_known) event(kHeadingSet, yaw);
}

#define GPSINS_INSTANTIATE(NB, NC, NT)                                      \
  template void InsFilter<NB, NC, NT>::constrain_vehicle(const Increment&); \
  template void InsFilter<NB, NC, NT>::process_attitude(const AttitudeInput&, const Increment&);
GPSINS_FOR_EACH_FILTER(GPSINS_INSTANTIATE)
#undef GPSINS_INSTANTIATE

}  // namespace gpsins

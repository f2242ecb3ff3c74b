#include "gpsins/strapdown.hpp"

#include "gpsins/attitude.hpp"
#include "gpsins/earth.hpp"

namespace gpsins {

void mechanise(NavState& s, const Increment& inc, const MechanisationOptions& opt) {
  const double dt = inc.dt_s;
  const Vec3 w_ie = opt.earth_rotation ? earth_rate_ecef() : Vec3::Zero();
  const Mat3 c0 = s.q_eb.toRotationMatrix();

  Vec3 dv_e = c0 * inc.dv_mps;
  dv_e -= 0.5 * dt * w_ie.cross(dv_e);

  const Vec3 r_mid = s.r_ecef_m + 0.5 * dt * s.v_ecef_mps;
  const Vec3 gamma = opt.gravity ? normal_gravity_ecef(r_mid) : Vec3::Zero();
  const Vec3 v_mid = s.v_ecef_mps + 0.5 * (dv_e + gamma * dt);
  const Vec3 v1 = s.v_ecef_mps + dv_e + (gamma - 2.0 * w_ie.cross(v_mid)) * dt;

  s.r_ecef_m += 0.5 * dt * (s.v_ecef_mps + v1);
  s.v_ecef_mps = v1;
  const Quat earth_turn(Eigen::AngleAxisd(-w_ie.z() * dt, Vec3::UnitZ()));
  s.q_eb = (earth_turn * s.q_eb * quat_from_rotvec(inc.dtheta_rad)).normalized();
  s.t_s += dt;
}

void split_increment(const Increment& inc, double fraction, Increment& first, Increment& second) {
  const double f = fraction;
  first.dt_s = f * inc.dt_s;
  first.dtheta_rad = f * inc.dtheta_rad;
  first.dv_mps = f * inc.dv_mps;
  second.dt_s = inc.dt_s - first.dt_s;
  second.dtheta_rad = inc.dtheta_rad - first.dtheta_rad;
  // The rest of the specific force, seen from the body frame at the split.
  second.dv_mps = dcm_from_rotvec(first.dtheta_rad).transpose() * ((1.0 - f) * inc.dv_mps);
}

}  // namespace gpsins

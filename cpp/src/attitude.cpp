#include "gpsins/attitude.hpp"

#include <algorithm>
#include <cmath>

#include "gpsins/earth.hpp"

namespace gpsins {

Quat quat_from_rotvec(const Vec3& rotvec_rad) {
  const double angle2 = rotvec_rad.squaredNorm();
  const double angle = std::sqrt(angle2);
  // sin(angle/2)/angle by its Taylor series below 1e-4 rad, where the series'
  // next term is far below double precision.
  const double k = angle < 1e-4 ? 0.5 - angle2 / 48.0 + angle2 * angle2 / 3840.0 : std::sin(0.5 * angle) / angle;
  return Quat(std::cos(0.5 * angle), k * rotvec_rad.x(), k * rotvec_rad.y(), k * rotvec_rad.z());
}

Vec3 rotvec_from_quat(const Quat& q_in) {
  Quat q = q_in.normalized();
  if (q.w() < 0.0) q.coeffs() = -q.coeffs();  // shortest rotation
  const double n = q.vec().norm();
  const double w = q.w();
  if (n < 1e-8) {
    // 2 atan(n/w)/n = (2/w) (1 - (n/w)^2/3 + ...); w is close to 1 here.
    const double r2 = (n / w) * (n / w);
    return (2.0 / w) * (1.0 - r2 / 3.0) * q.vec();
  }
  return (2.0 * std::atan2(n, w) / n) * q.vec();
}

Mat3 dcm_from_rotvec(const Vec3& rotvec_rad) { return dcm_from_quat(quat_from_rotvec(rotvec_rad)); }

Mat3 dcm_from_quat(const Quat& q) { return q.normalized().toRotationMatrix(); }

Quat quat_from_dcm(const Mat3& c) {
  // Shepperd: compute the largest of 4w^2, 4x^2, 4y^2, 4z^2 from the diagonal
  // and divide the off-diagonal sums by it.
  const double tr = c.trace();
  const double d[4] = {tr, c(0, 0), c(1, 1), c(2, 2)};
  const int i = static_cast<int>(std::max_element(d, d + 4) - d);
  double w, x, y, z;
  if (i == 0) {
    const double s = 2.0 * std::sqrt(1.0 + tr);
    w = 0.25 * s;
    x = (c(2, 1) - c(1, 2)) / s;
    y = (c(0, 2) - c(2, 0)) / s;
    z = (c(1, 0) - c(0, 1)) / s;
  } else if (i == 1) {
    const double s = 2.0 * std::sqrt(1.0 + c(0, 0) - c(1, 1) - c(2, 2));
    w = (c(2, 1) - c(1, 2)) / s;
    x = 0.25 * s;
    y = (c(0, 1) + c(1, 0)) / s;
    z = (c(0, 2) + c(2, 0)) / s;
  } else if (i == 2) {
    const double s = 2.0 * std::sqrt(1.0 - c(0, 0) + c(1, 1) - c(2, 2));
    w = (c(0, 2) - c(2, 0)) / s;
    x = (c(0, 1) + c(1, 0)) / s;
    y = 0.25 * s;
    z = (c(1, 2) + c(2, 1)) / s;
  } else {
    const double s = 2.0 * std::sqrt(1.0 - c(0, 0) - c(1, 1) + c(2, 2));
    w = (c(1, 0) - c(0, 1)) / s;
    x = (c(0, 2) + c(2, 0)) / s;
    y = (c(1, 2) + c(2, 1)) / s;
    z = 0.25 * s;
  }
  return quat_canonical(Quat(w, x, y, z));
}

Mat3 dcm_from_euler(const Euler& e) {
  const double cy = std::cos(e.yaw_rad), sy = std::sin(e.yaw_rad);
  const double cp = std::cos(e.pitch_rad), sp = std::sin(e.pitch_rad);
  const double cr = std::cos(e.roll_rad), sr = std::sin(e.roll_rad);
  Mat3 c;  // Rz(yaw) Ry(pitch) Rx(roll)
  c << cy * cp, cy * sp * sr - sy * cr, cy * sp * cr + sy * sr, sy * cp, sy * sp * sr + cy * cr, sy * sp * cr - cy * sr,
      -sp, cp * sr, cp * cr;
  return c;
}

Euler euler_from_dcm(const Mat3& c) {
  Euler e;
  const double cos_pitch = std::hypot(c(0, 0), c(1, 0));
  // atan2 keeps full precision near +-90 deg, where asin(-c20) would not.
  e.pitch_rad = std::atan2(-c(2, 0), cos_pitch);
  if (cos_pitch > 1e-12) {
    e.roll_rad = std::atan2(c(2, 1), c(2, 2));
    e.yaw_rad = std::atan2(c(1, 0), c(0, 0));
  } else {
    e.roll_rad = 0.0;
    e.yaw_rad = std::atan2(-c(0, 1), c(1, 1));
  }
  return e;
}

Quat quat_from_euler(const Euler& e) {
  const Quat qz(Eigen::AngleAxisd(e.yaw_rad, Vec3::UnitZ()));
  const Quat qy(Eigen::AngleAxisd(e.pitch_rad, Vec3::UnitY()));
  const Quat qx(Eigen::AngleAxisd(e.roll_rad, Vec3::UnitX()));
  return quat_canonical(qz * qy * qx);
}

Euler euler_from_quat(const Quat& q) { return euler_from_dcm(dcm_from_quat(q)); }

Quat quat_canonical(const Quat& q) {
  Quat out = q.normalized();
  if (out.w() < 0.0) out.coeffs() = -out.coeffs();
  return out;
}

Quat quat_ned_to_ecef(double lat_rad, double lon_rad) { return quat_from_dcm(rot_ned_to_ecef(lat_rad, lon_rad)); }

Quat quat_body_to_ecef(const Euler& e, double lat_rad, double lon_rad) {
  return quat_canonical(quat_ned_to_ecef(lat_rad, lon_rad) * quat_from_euler(e));
}

Euler euler_from_body_to_ecef(const Quat& q_eb, double lat_rad, double lon_rad) {
  return euler_from_dcm(rot_ned_to_ecef(lat_rad, lon_rad).transpose() * dcm_from_quat(q_eb));
}

}  // namespace gpsins

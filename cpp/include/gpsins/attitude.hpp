// Rotations: Hamilton unit quaternions, rotation matrices, rotation vectors,
// Euler yaw-pitch-roll. Passive body-to-world convention: a quaternion q_wb or
// matrix C_wb takes a body vector to world axes (v_w = C_wb v_b).
//
// Euler angles are intrinsic z-y-x: C_nb = Rz(yaw) Ry(pitch) Rx(roll).
#pragma once

#include "gpsins/types.hpp"

namespace gpsins {

struct Euler {
  double yaw_rad = 0.0;
  double pitch_rad = 0.0;
  double roll_rad = 0.0;
};

// exp map: rotation vector (axis * angle) to unit quaternion; exact for small angles.
Quat quat_from_rotvec(const Vec3& rotvec_rad);
// log map: unit quaternion to rotation vector with angle in [0, pi].
Vec3 rotvec_from_quat(const Quat& q);

Mat3 dcm_from_rotvec(const Vec3& rotvec_rad);
Mat3 dcm_from_quat(const Quat& q);
// Shepperd's method: well conditioned for every rotation; result has w >= 0.
Quat quat_from_dcm(const Mat3& c);

Mat3 dcm_from_euler(const Euler& e);
// Pitch in [-pi/2, pi/2]. At gimbal lock (|pitch| = pi/2) roll is set to 0
// and yaw carries the combined angle.
Euler euler_from_dcm(const Mat3& c);
Quat quat_from_euler(const Euler& e);
Euler euler_from_quat(const Quat& q);

// Normalise and choose the sign with w >= 0 (q and -q are the same rotation).
Quat quat_canonical(const Quat& q);

// Attitude body->ECEF from Euler angles relative to local NED at (lat, lon), and back.
Quat quat_ned_to_ecef(double lat_rad, double lon_rad);
Quat quat_body_to_ecef(const Euler& e, double lat_rad, double lon_rad);
Euler euler_from_body_to_ecef(const Quat& q_eb, double lat_rad, double lon_rad);

}  // namespace gpsins

// Fixed-size Eigen types shared by the whole core. Nothing here allocates.
#pragma once

#include <Eigen/Core>
#include <Eigen/Geometry>

namespace gpsins {

using Vec3 = Eigen::Vector3d;
using Mat3 = Eigen::Matrix3d;
// Hamilton unit quaternion (w, x, y, z); Eigen's product is the Hamilton product.
using Quat = Eigen::Quaterniond;

}  // namespace gpsins

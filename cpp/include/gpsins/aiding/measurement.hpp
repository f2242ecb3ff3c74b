// What an aiding source hands the filter: innovation y = z - h(x), its
// Jacobian H with respect to the error state, and the noise covariance R.
#pragma once

#include <Eigen/Core>

namespace gpsins {

template <int M, int N>
struct Measurement {
  Eigen::Matrix<double, M, 1> y = Eigen::Matrix<double, M, 1>::Zero();
  Eigen::Matrix<double, M, N> H = Eigen::Matrix<double, M, N>::Zero();
  Eigen::Matrix<double, M, M> R = Eigen::Matrix<double, M, M>::Zero();
};

// Keep only the rows `rows` of a measurement expressed in the frame `c` (rows of
// c^T z): used for the horizontal part of a 2D fix in NED.
template <int K, int M, int N>
Measurement<K, N> project(const Measurement<M, N>& m, const Eigen::Matrix<double, K, M>& t) {
  Measurement<K, N> out;
  out.y = t * m.y;
  out.H = t * m.H;
  out.R = t * m.R * t.transpose();
  return out;
}

}  // namespace gpsins

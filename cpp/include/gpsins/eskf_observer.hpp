// What a fixed-interval smoother needs to hear from the forward pass of the
// error-state filter (see rts.hpp). The filter calls these only when an
// observer is attached; without one it does no extra work.
#pragma once

#include <Eigen/Dense>

#include "gpsins/types.hpp"

namespace gpsins {

template <int N>
class EskfObserver {
 public:
  using MatN = Eigen::Matrix<double, N, N>;
  using MatRef = Eigen::Ref<const Eigen::MatrixXd>;
  using VecRef = Eigen::Ref<const Eigen::VectorXd>;
  virtual ~EskfObserver() = default;
  // Covariance propagation P <- Phi P Phi^T + Q over one step.
  virtual void on_propagate(const MatN& phi) = 0;
  // Accepted Kalman update: innovation y, H (M x N), gain K (N x M), S^-1, then
  // injection of K y and the reset whose attitude block is g (the ESKF notes).
  virtual void on_update(const MatRef& H, const MatRef& K, const MatRef& s_inv, const VecRef& y, const Mat3& g) = 0;
  // The filter's own re-initialisations: the new error is A (old error) plus
  // independent noise, P <- A P A^T + Q (rows A zeroes start afresh).
  virtual void on_transition(const MatN& a) = 0;
};

}  // namespace gpsins

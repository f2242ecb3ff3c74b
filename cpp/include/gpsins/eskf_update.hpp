// Eskf's Kalman update (declared in eskf.hpp). Included only where updates are compiled:
// cpp/src/eskf_updates/ for the filter variants the core builds (filter_variants.hpp),
// and tests that update other state layouts.
#pragma once

#include "gpsins/eskf.hpp"

namespace gpsins {

template <int NB, int NC, int NT>
template <int M>
UpdateResult<M> Eskf<NB, NC, NT>::update(const Eigen::Matrix<double, M, 1>& y, const Eigen::Matrix<double, M, N>& H,
                                         const Eigen::Matrix<double, M, M>& R, double gate, double attitude_limit) {
  flush_covariance();
  UpdateResult<M> res;
  res.innovation = y;
  const Eigen::Matrix<double, N, M> pht = P * H.transpose();
  const Eigen::Matrix<double, M, M> S = H * pht + R;
  res.innovation_sigma = S.diagonal().cwiseMax(0.0).cwiseSqrt();
  const Eigen::LLT<Eigen::Matrix<double, M, M>> llt(S);
  if (llt.info() != Eigen::Success || !y.allFinite()) {
    res.guarded = true;
    return res;
  }
  res.nis = y.dot(llt.solve(y));
  res.log_det_s = 2.0 * llt.matrixLLT().diagonal().array().log().sum();
  if (gate > 0.0 && !(res.nis <= gate)) return res;
  const Eigen::Matrix<double, N, M> K = llt.solve(pht.transpose()).transpose();
  const VecN dx = K * y;
  if (attitude_limit > 0.0 && !(dx.template segment<3>(es::att).norm() <= attitude_limit)) {
    res.attitude_refused = true;
    return res;
  }
  // Joseph form (I - K H) P (I - K H)^T + K R K^T, multiplied out with A = P H^T and
  // S = H P H^T + R into P - K A^T - A K^T + K S K^T: the same expression, symmetric
  // term by term, in O(N^2 M) instead of two dense N x N products.
  const Eigen::Matrix<double, N, N> ka = K * pht.transpose();
  const MatN p_new = P - ka - ka.transpose() + K * S * K.transpose();
  if (!p_new.allFinite() || (p_new.diagonal().array() <= 0.0).any() || !dx.allFinite()) {
    res.guarded = true;
    return res;
  }
  P = p_new;
  if (observer) {
    const Eigen::Matrix<double, M, M> s_inv = llt.solve(Eigen::Matrix<double, M, M>::Identity());
    observer->on_update(H, K, s_inv, y, Mat3::Identity() - skew(0.5 * dx.template segment<3>(es::att)));
  }
  inject_and_reset(dx);
  res.accepted = true;
  return res;
}

// The updates of one filter variant (cpp/src/eskf_updates/ instantiates them).
#define GPSINS_ESKF_UPDATES(NB, NC, NT) \
  GPSINS_ESKF_UPDATE(NB, NC, NT, 1) GPSINS_ESKF_UPDATE(NB, NC, NT, 2) GPSINS_ESKF_UPDATE(NB, NC, NT, 3)

}  // namespace gpsins

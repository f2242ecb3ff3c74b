#include "gpsins/standstill.hpp"

#include <algorithm>
#include <cmath>

namespace gpsins {

StandstillDetector::StandstillDetector(const StandstillThresholds& t) : th_(t) {
  th_.block_s = std::max(th_.block_s, 1e-3);
  window_blocks_ = std::clamp(static_cast<int>(std::lround(th_.window_s / th_.block_s)), 2, kMaxBlocks);
}

void StandstillDetector::reset() {
  acc_f_.setZero();
  acc_w_.setZero();
  acc_dt_ = 0.0;
  head_ = count_ = 0;
  standing_ = false;
  have_ref_ = false;
}

bool StandstillDetector::add(const Vec3& f, const Vec3& w, double dt) {
  if (!(dt > 0.0)) return false;
  acc_f_ += f * dt;
  acc_w_ += w * dt;
  acc_dt_ += dt;
  // A block closes at the sample that reaches its duration (less half a sample,
  // so its length does not alternate when block_s is a multiple of the step).
  if (acc_dt_ < th_.block_s - 0.5 * dt) return false;
  close_block();
  if (count_ < window_blocks_) return false;
  statistics();
  return true;
}

void StandstillDetector::close_block() {
  const auto h = static_cast<std::size_t>(head_);
  bf_[h] = acc_f_ / acc_dt_;
  bw_[h] = acc_w_ / acc_dt_;
  bdt_[h] = acc_dt_;
  head_ = (head_ + 1) % window_blocks_;
  count_ = std::min(count_ + 1, window_blocks_);
  acc_f_.setZero();
  acc_w_.setZero();
  acc_dt_ = 0.0;
}

void StandstillDetector::statistics() {
  // Duration-weighted means; spreads of the block means about them.
  Vec3 sf = Vec3::Zero(), sw = Vec3::Zero(), rf = Vec3::Zero();
  double t = 0.0, tr = 0.0;
  const int recent = std::max(1, window_blocks_ / 4);
  for (int k = 0; k < window_blocks_; ++k) {
    const auto i = static_cast<std::size_t>((head_ - 1 - k + 2 * window_blocks_) % window_blocks_);  // newest first
    sf += bf_[i] * bdt_[i];
    sw += bw_[i] * bdt_[i];
    t += bdt_[i];
    if (k < recent) {
      rf += bf_[i] * bdt_[i];
      tr += bdt_[i];
    }
  }
  mean_f_ = sf / t;
  mean_w_ = sw / t;
  recent_f_ = rf / tr;
  window_dt_ = t;
  recent_dt_ = tr;
  Vec3 vf = Vec3::Zero(), vw = Vec3::Zero();
  for (int k = 0; k < window_blocks_; ++k) {
    const auto i = static_cast<std::size_t>(k);
    vf += (bf_[i] - mean_f_).cwiseAbs2();
    vw += (bw_[i] - mean_w_).cwiseAbs2();
  }
  const double n = window_blocks_;
  std_f_ = (vf / (n - 1.0)).cwiseSqrt();
  std_w_ = (vw / (n - 1.0)).cwiseSqrt();
}

Vec3 StandstillDetector::mean_rate_variance() const { return std_w_.cwiseAbs2() / window_blocks_; }

bool StandstillDetector::decide(const Vec3& rate_less_bias_earth, bool may_begin, bool veto, double t_s) {
  const bool was = standing_;
  const bool quiet = std_f_.maxCoeff() < th_.accel_std_mps2 && std_w_.maxCoeff() < th_.gyro_std_rad_per_s &&
                     rate_less_bias_earth.norm() < th_.gyro_mean_rad_per_s;
  const double sigma = th_.accel_vrw_mps_per_sqrt_s.maxCoeff() / std::sqrt(window_dt_);
  const double shift = std::max(th_.accel_shift_mps2, 5.0 * sigma);
  const bool near_ref =
      have_ref_ && (mean_f_ - ref_f_).norm() < shift && (mean_w_ - ref_w_).norm() < th_.gyro_mean_rad_per_s;
  if (veto || !quiet) {
    standing_ = false;
  } else if (!standing_) {
    const bool held_off = t_s - ended_t_ < th_.holdoff_s;
    if (held_off ? near_ref : may_begin) {
      standing_ = true;
      if (!held_off) {
        ref_f_ = mean_f_;
        ref_w_ = mean_w_;
        ref_sum_f_ = mean_f_ * window_blocks_;
        ref_sum_w_ = mean_w_ * window_blocks_;
        ref_blocks_ = window_blocks_;
        have_ref_ = true;
      }
    }
  } else {
    // The newest quarter's mean has more noise: allow three of its sigmas on top.
    const double recent_allow = 3.0 * th_.accel_vrw_mps_per_sqrt_s.maxCoeff() / std::sqrt(recent_dt_);
    standing_ = near_ref && (recent_f_ - ref_f_).norm() < shift + recent_allow;
    if (standing_) {  // the reference: the mean of every block since standing began
      const auto newest = static_cast<std::size_t>((head_ - 1 + window_blocks_) % window_blocks_);
      ref_sum_f_ += bf_[newest];
      ref_sum_w_ += bw_[newest];
      ++ref_blocks_;
      ref_f_ = ref_sum_f_ / ref_blocks_;
      ref_w_ = ref_sum_w_ / ref_blocks_;
    }
  }
  if (was && !standing_) ended_t_ = t_s;
  return standing_;
}

}  // namespace gpsins

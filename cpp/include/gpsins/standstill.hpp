// Standstill detector on statistics whose noise does not depend on the IMU rate.
//
// Samples are averaged over blocks of fixed duration (block_s); the window is
// the last window_s of blocks. A block mean of white noise has the spread
// N / sqrt(block_s) at any sample rate, so thresholds are in physical units:
// - quiet: the spread of the block means of specific force and of angular rate
//   (per axis) and the mean rate less bias and Earth rate are small;
// - at rest: once standing, the window's mean specific force and rate, and the
//   mean of its newest quarter, stay near their mean since standing began
//   (threshold at least five sigmas of the window mean's noise) (pulling away moves the mean specific force by the
//   acceleration even when the motion is smooth; the filter's own velocity cannot show it, since zero-velocity updates
//   pin it).
// Standing can only begin when the caller allows it (the filter's speed, which
// no zero-velocity update has pinned yet, and the GNSS speed); a GNSS speed
// above its limit ends it. For holdoff_s after a standstill ends the filter's
// speed is still the pinned one: standing may then begin again only at the
// specific force it had before (a motion that stopped, not one that started).
#pragma once

#include <array>

#include "gpsins/types.hpp"

namespace gpsins {

struct StandstillThresholds {
  double window_s = 0.5;
  double block_s = 0.05;
  double accel_std_mps2 = 0.12;       // spread of block means, per axis
  double gyro_std_rad_per_s = 0.015;  // spread of block means, per axis
  double gyro_mean_rad_per_s = 0.02;  // |mean rate - bias - Earth rate|, and drift from the start
  double accel_shift_mps2 = 0.05;     // |mean specific force - its value when standing began|
  double holdoff_s = 2.0;
  Vec3 accel_vrw_mps_per_sqrt_s = Vec3::Constant(1e-2);  // for the newest quarter's noise allowance
};

class StandstillDetector {
 public:
  static constexpr int kMaxBlocks = 64;

  explicit StandstillDetector(const StandstillThresholds& t = {});

  // One sample (specific force, angular rate, its interval). True when a block
  // closed and the window is full: statistics are new and decide() may run.
  bool add(const Vec3& f_mps2, const Vec3& w_rad_per_s, double dt_s);
  // Decide from the current window. rate_less_bias_earth: the window's mean rate
  // corrected by the estimated bias and the Earth rate seen in body axes.
  bool decide(const Vec3& rate_less_bias_earth, bool may_begin, bool veto, double t_s);
  void reset();

  bool standing() const { return standing_; }
  int blocks() const { return count_; }
  int window_blocks() const { return window_blocks_; }
  double window_duration_s() const { return window_dt_; }
  const Vec3& mean_f() const { return mean_f_; }
  const Vec3& mean_w() const { return mean_w_; }
  // Variance of the window's mean rate from the spread of its block means
  // (vibration included), per axis.
  Vec3 mean_rate_variance() const;

 private:
  void close_block();
  void statistics();

  StandstillThresholds th_;
  int window_blocks_ = 10;
  // Block being filled.
  Vec3 acc_f_ = Vec3::Zero(), acc_w_ = Vec3::Zero();
  double acc_dt_ = 0.0;
  // Closed blocks (ring).
  std::array<Vec3, kMaxBlocks> bf_{}, bw_{};
  std::array<double, kMaxBlocks> bdt_{};
  int head_ = 0, count_ = 0;
  // Window statistics.
  Vec3 mean_f_ = Vec3::Zero(), mean_w_ = Vec3::Zero(), recent_f_ = Vec3::Zero();
  Vec3 std_f_ = Vec3::Zero(), std_w_ = Vec3::Zero();
  double window_dt_ = 0.0, recent_dt_ = 0.0;
  // At-rest reference.
  bool standing_ = false;
  bool have_ref_ = false;
  static constexpr double kLongAgo_s = -1e300;  // a time before any sample
  double ended_t_ = kLongAgo_s;
  Vec3 ref_f_ = Vec3::Zero(), ref_w_ = Vec3::Zero();
  Vec3 ref_sum_f_ = Vec3::Zero(), ref_sum_w_ = Vec3::Zero();  // newest blocks while standing
  int ref_blocks_ = 0;
};

}  // namespace gpsins

// The integrated navigation filter: an Eskf fed with IMU samples and aiding
// measurements in time order. It owns the jobs around the core: calibration of
// raw increments, initial levelling and heading, measurement timing (a fix
// between two IMU samples splits the increment at the fix time), standstill
// detection with zero-velocity and zero-rate updates, IMU gaps, gating and
// bookkeeping. Inputs are checked; a bad input is reported by status code and
// changes nothing.
#pragma once

#include <array>
#include <cstdint>
#include <vector>

#include "gpsins/eskf.hpp"
#include "gpsins/ins_config.hpp"

namespace gpsins {

enum class InputStatus : int {
  Ok = 0,
  NonFinite = 1,
  TimeNotIncreasing = 2,
  GapTooLong = 3,
  BadValue = 4,
};
const char* input_status_text(InputStatus s);

// One receiver fix. mode: 2 = 3D, 3 = 2D (horizontal used), anything else = no
// solution (counted). Velocity may be NaN when the receiver gave none.
struct FixInput {
  double t_s = 0.0;
  Vec3 r_ecef_m = Vec3::Zero();
  Vec3 v_ecef_mps = Vec3::Constant(std::numeric_limits<double>::quiet_NaN());
  double hdop = 1.0;
  double vdop = 1.0;
  int mode = 2;
};

enum UpdateKind : int {
  kFix3D = 1,
  kFix2D = 2,
  kFixVelocity = 3,
  kZeroVelocity = 4,
  kZeroRate = 5,
  kPseudorange = 6,
};

struct UpdateRecord {
  double t_s = 0.0;
  int kind = 0;
  int id = 0;  // satellite PRN for pseudoranges
  int dof = 0;
  double nis = 0.0;
  double gate = 0.0;
  bool accepted = false;
  bool guarded = false;
  std::array<double, 3> innovation{};
  std::array<double, 3> innovation_sigma{};
};

struct Counters {
  std::int64_t imu_samples = 0;
  std::int64_t imu_gaps_bridged = 0;
  std::int64_t fixes = 0;
  std::int64_t fixes_accepted = 0;
  std::int64_t fixes_rejected = 0;
  std::int64_t fixes_without_solution = 0;
  std::int64_t fixes_before_alignment = 0;
  std::int64_t fixes_late = 0;
  std::int64_t zero_velocity_updates = 0;
  std::int64_t zero_rate_updates = 0;
  std::int64_t updates_rejected = 0;
  std::int64_t updates_guarded = 0;
  std::int64_t standstill_samples = 0;
  bool diverged = false;
};

template <int NB, int NC>
class InsFilter {
 public:
  using Core = Eskf<NB, NC>;
  static constexpr int N = Core::N;

  explicit InsFilter(const InsConfig& cfg);

  InputStatus push_imu(double t_s, const Vec3& dtheta_rad, const Vec3& dv_mps);
  InputStatus push_fix(const FixInput& fix);

  bool initialised() const { return initialised_; }
  bool heading_known() const { return heading_known_; }
  bool standstill() const { return standstill_; }
  const Core& core() const { return core_; }
  const Counters& counters() const { return counters_; }
  const InsConfig& config() const { return cfg_; }
  const UpdateRecord& last_update() const { return last_update_; }
  // Every update is also appended here when set (batch runs).
  void set_update_log(std::vector<UpdateRecord>* log) { log_ = log; }

 private:
  static constexpr int kRing = 256;
  static constexpr int kPending = 16;

  Increment calibrated(double dt, const Vec3& dtheta, const Vec3& dv) const;
  void propagate_to(const Increment& inc);
  void process_fix(const FixInput& fix);
  void initialise(const FixInput& fix);
  void decouple_yaw();
  void set_heading(const FixInput& fix, const Vec3& v_ecef, double course_rad);
  void detect_standstill(const Increment& inc);
  template <int M>
  void record(int kind, const UpdateResult<M>& r, int dof);
  double gate(int dof) const { return gates_[static_cast<std::size_t>(dof)]; }

  InsConfig cfg_;
  Core core_;
  Counters counters_;
  UpdateRecord last_update_;
  std::vector<UpdateRecord>* log_ = nullptr;
  std::array<double, 8> gates_{};

  bool initialised_ = false;
  bool heading_known_ = false;
  bool have_time_ = false;
  double t_last_ = 0.0;
  double dt_nominal_ = 1.0 / 64.0;
  Increment last_inc_;  // calibrated, for gap bridging

  // Levelling sums before initialisation.
  Vec3 level_f_sum_ = Vec3::Zero();
  double level_time_ = 0.0;

  // Standstill window.
  std::array<Vec3, kRing> ring_f_{}, ring_w_{};
  int ring_size_ = 32, ring_count_ = 0, ring_head_ = 0;
  Vec3 sum_f_ = Vec3::Zero(), sum_f2_ = Vec3::Zero(), sum_w_ = Vec3::Zero(), sum_w2_ = Vec3::Zero();
  bool standstill_ = false;
  int standstill_run_ = 0;

  std::array<FixInput, kPending> pending_{};
  int pending_count_ = 0;
  bool have_fix_time_ = false;
  double last_fix_t_ = 0.0;
  bool have_prev_fix_ = false;
  FixInput prev_fix_;
};

extern template class InsFilter<5, 0>;
extern template class InsFilter<7, 0>;
extern template class InsFilter<5, 2>;
extern template class InsFilter<7, 2>;

}  // namespace gpsins

// The integrated navigation filter: an Eskf fed with IMU samples and aiding
// measurements in time order. It owns the jobs around the core: calibration of
// raw increments, initial levelling and heading, measurement timing (a fix
// between two IMU samples splits the increment at the fix time), standstill
// detection with zero-velocity and zero-rate updates, IMU gaps, gating and
// bookkeeping. Inputs are checked; a bad input is reported by status code and
// changes nothing.
#pragma once

#include <algorithm>
#include <array>
#include <cassert>
#include <cmath>
#include <cstdint>
#include <limits>
#include <vector>

#include "gpsins/aiding/measurement.hpp"
#include "gpsins/eskf.hpp"
#include "gpsins/filter_names.hpp"
#include "gpsins/filter_variants.hpp"
#include "gpsins/fixed_queue.hpp"
#include "gpsins/gnss/ephemeris.hpp"
#include "gpsins/gnss/models.hpp"
#include "gpsins/ins_config.hpp"
#include "gpsins/sis_slots.hpp"
#include "gpsins/standstill.hpp"

namespace gpsins {

enum class InputStatus : int {
  Ok = 0,
  NonFinite = 1,
  TimeNotIncreasing = 2,
  // 3 was GapTooLong: long gaps now restart the navigation (Counters::imu_gap_restarts)
  BadValue = 4,
};
const char* input_status_text(InputStatus s);

// FixInput::mode: a 3D fix, or a 2D fix (its height the receiver's assumption: the
// horizontal is used); anything else is no solution (counted), kFixModeNone among them.
inline constexpr int kFixModeNone = 0;
inline constexpr int kFixMode3D = 2;
inline constexpr int kFixMode2D = 3;

// One receiver fix (mode: kFixMode3D, kFixMode2D or no solution). Velocity may be
// NaN when the receiver gave none.
struct FixInput {
  double t_s = 0.0;
  Vec3 r_ecef_m = Vec3::Zero();
  Vec3 v_ecef_mps = Vec3::Constant(std::numeric_limits<double>::quiet_NaN());
  double hdop = 1.0;
  double vdop = 1.0;
  int mode = kFixMode3D;
  // The receiver's stated sigmas, north, east, down; an axis NaN or <= 0 falls
  // back to fix_uere_m x DOP (position) or fix_velocity_sigma_mps (velocity).
  Vec3 sigma_ned_m = Vec3::Constant(std::numeric_limits<double>::quiet_NaN());
  Vec3 sigma_v_ned_mps = Vec3::Constant(std::numeric_limits<double>::quiet_NaN());
};

// One measurement epoch of the receiver: pseudoranges at receiver time t_s (the
// filter's time base). n <= kMaxSats.
struct PseudorangeEpoch {
  static constexpr int kMaxSats = 32;  // GPS and Galileo in view together
  double t_s = 0.0;
  int n = 0;
  std::array<int, kMaxSats> prn{};
  std::array<double, kMaxSats> pr_m{};
  std::array<double, kMaxSats> cn0_dbhz{};
  std::array<int, kMaxSats> lock_count{};
  std::array<double, kMaxSats> doppler_hz = no_doppler();  // positive approaching; NaN: none
  bool ranges = true;  // false: only the Doppler is used (an epoch pseudorange_decimation skips)
  bool has_doppler() const {
    for (int i = 0; i < n; ++i)
      if (std::isfinite(doppler_hz[static_cast<std::size_t>(i)])) return true;
    return false;
  }

 private:
  static constexpr std::array<double, kMaxSats> no_doppler() {
    std::array<double, kMaxSats> a{};
    for (auto& x : a) x = std::numeric_limits<double>::quiet_NaN();
    return a;
  }
};

// Heading (and pitch) of a dual-antenna GNSS baseline at t_s, in local NED
// (aiding/baseline_attitude.hpp); pitch NaN: heading only.
struct AttitudeInput {
  double t_s = 0.0;
  double yaw_rad = 0.0;
  double pitch_rad = std::numeric_limits<double>::quiet_NaN();
  double sigma_yaw_rad = 0.0;
  double sigma_pitch_rad = 0.0;
};

// The filter's phase, from start-up to navigation: one at a time. It changes only by
// InsFilter::advance, on these events:
//   WaitingForImu  -> Levelling       the first IMU sample (FirstImuSample)
//   Levelling      -> HeadingUnknown  the first fix after level_time_s (Initialised), or
//                  -> Navigating      so when initial_yaw_rad is configured
//   HeadingUnknown -> Navigating      a heading from the course over ground or a dual-antenna
//                                     baseline (HeadingMeasured)
//   HeadingUnknown, Navigating -> Coasting  an IMU gap too long to bridge (GapCoast)
//   Coasting       -> HeadingUnknown  the gap's end (GapEnd)
// An IMU gap while levelling restarts the levelling sums; the phase stays.
enum class Phase : std::uint8_t {
  WaitingForImu,   // no IMU sample yet: no time base
  Levelling,       // summing the specific force; the first fix after level_time_s initialises
  HeadingUnknown,  // navigating, the yaw kept decoupled (decouple_yaw) until a heading is measured
  Coasting,        // after an IMU gap: a constant-velocity coast through the gap's fixes (no heading from them)
  Navigating,      // navigating with a known heading
};
enum class PhaseEvent : std::uint8_t { FirstImuSample, Initialised, HeadingMeasured, GapCoast, GapEnd };

// Enumerators from the shared lists (filter_names.hpp).
#define GPSINS_ENUMERATOR(enumerator, value, name) enumerator = value,
enum UpdateKind : int { GPSINS_UPDATE_KINDS(GPSINS_ENUMERATOR) };
// One past the largest update kind: the size of a table indexed by kind.
#define GPSINS_KIND_VALUE(enumerator, value, name) value,
inline constexpr int kUpdateKindEnd = 1 + std::max({GPSINS_UPDATE_KINDS(GPSINS_KIND_VALUE)});
#undef GPSINS_KIND_VALUE

struct UpdateRecord {
  double t_s = 0.0;
  int kind = 0;
  int id = 0;  // satellite PRN for pseudoranges
  int dof = 0;
  double nis = 0.0;
  double gate = 0.0;
  double log_det_s = 0.0;  // ln det S (the NIS's covariance)
  double r_scale = 1.0;    // > 1: used down-weighted (InsConfig::robust_after_rejections)
  bool accepted = false;
  bool guarded = false;
  std::array<double, 3> innovation{};
  std::array<double, 3> innovation_sigma{};
};

// What the filter did besides its regular updates (batch runs log them).
enum EventKind : int { GPSINS_EVENT_KINDS(GPSINS_ENUMERATOR) };
#undef GPSINS_ENUMERATOR

struct FilterEvent {
  double t_s = 0.0;
  int kind = 0;
  double value = 0.0;
};

struct Counters {
#define GPSINS_COUNTER_FIELD(name) std::int64_t name = 0;
  GPSINS_COUNTERS(GPSINS_COUNTER_FIELD)
#undef GPSINS_COUNTER_FIELD
  // Set when the filter stopped explaining its measurements (sustained GNSS
  // rejection) or its covariance or state became invalid; stays set.
  bool diverged = false;
};

// NT = 1: the IMU time offset state (estimate_time_offset; eskf.hpp).
template <int NB, int NC, int NT = 0>
class InsFilter {
 public:
  using Core = Eskf<NB, NC, NT>;
  static constexpr int N = Core::N;

  explicit InsFilter(const InsConfig& cfg);

  InputStatus push_imu(double t_s, const Vec3& dtheta_rad, const Vec3& dv_mps);
  InputStatus push_fix(const FixInput& fix);
  // Tight coupling only (Core::kHasClock); held until the IMU reaches their time.
  // NC == 3 is loose coupling with the fix-error states (fix_error_gm_sigma_m).
  InputStatus push_pseudoranges(const PseudorangeEpoch& epoch);
  // Dual-antenna heading and pitch; used at the first IMU sample at or after
  // their time, carried to it with the measured turn rate.
  InputStatus push_attitude(const AttitudeInput& a);
  bool add_ephemeris(const gnss::Ephemeris& e) { return store_.add(e); }
  void set_klobuchar(const gnss::Klobuchar& k) { iono_ = k; }

  Phase phase() const { return phase_; }
  bool initialised() const { return phase_ != Phase::WaitingForImu && phase_ != Phase::Levelling; }
  // Before initialisation: whether initial_yaw_rad will give it.
  bool heading_known() const {
    switch (phase_) {
      case Phase::WaitingForImu:
      case Phase::Levelling:
        return std::isfinite(cfg_.initial_yaw_rad);
      case Phase::HeadingUnknown:
      case Phase::Coasting:
        return false;
      case Phase::Navigating:
        return true;
    }
    return false;
  }
  bool standstill() const { return standstill_; }
  const Core& core() const { return core_; }
  // Brings the covariance up to the last increment (Eskf::covariance_interval_s): before reading core().P.
  void flush_covariance() { core_.flush_covariance(); }
  const Counters& counters() const { return counters_; }
  const InsConfig& config() const { return cfg_; }
  const UpdateRecord& last_update() const { return last_update_; }
  // Every update is also appended here when set (batch runs).
  void set_update_log(std::vector<UpdateRecord>* log) { log_ = log; }
  void set_event_log(std::vector<FilterEvent>* log) { events_ = log; }
  void set_observer(EskfObserver<N>* o) { core_.observer = o; }  // smoother recording (rts.hpp)
  double nominal_step_s() const { return dt_nominal_; }

 private:
  static constexpr int kPending = 16;
  static constexpr int kSteps = 15;
  static constexpr double kDefaultImuRateHz = 64.0;  // the nominal step's start when imu_rate_hz is not set
  static constexpr int kGateDofs = 8;                // gates_[dof], dof 1 to 7
  static constexpr double kLongAgo_s = -1e300;       // a time before any input
  static constexpr double kNoSpeed = -1.0;           // no GNSS speed yet

  // The phase's transitions (Phase), the only writer of phase_.
  void advance(PhaseEvent e) {
    switch (e) {
      case PhaseEvent::FirstImuSample:
        assert(phase_ == Phase::WaitingForImu);
        phase_ = Phase::Levelling;
        break;
      case PhaseEvent::Initialised:
        assert(phase_ == Phase::Levelling);
        phase_ = std::isfinite(cfg_.initial_yaw_rad) ? Phase::Navigating : Phase::HeadingUnknown;
        break;
      case PhaseEvent::HeadingMeasured:
        assert(phase_ == Phase::HeadingUnknown);
        phase_ = Phase::Navigating;
        break;
      case PhaseEvent::GapCoast:
        assert(phase_ == Phase::HeadingUnknown || phase_ == Phase::Navigating);
        phase_ = Phase::Coasting;
        break;
      case PhaseEvent::GapEnd:
        assert(phase_ == Phase::Coasting);
        phase_ = Phase::HeadingUnknown;
        break;
    }
  }
  bool have_time() const { return phase_ != Phase::WaitingForImu; }
  // Navigating without a heading: the yaw is kept decoupled from the other states.
  bool yaw_decoupled() const { return phase_ == Phase::HeadingUnknown || phase_ == Phase::Coasting; }

  Increment calibrated(double dt, const Vec3& dtheta, const Vec3& dv) const;
  void propagate_to(const Increment& inc);
  void process_fix(const FixInput& fix);
  void process_pseudoranges(const PseudorangeEpoch& epoch);
  struct PrUse {  // one pseudorange with everything but geometry and clock removed
    Vec3 sat;
    double pr_corr, sagnac, var;
    int prn;
    // Its Doppler as a range rate with the satellite's clock drift removed (NaN: none).
    Vec3 sat_v = Vec3::Zero();
    double rate_corr = std::numeric_limits<double>::quiet_NaN(), rate_var = 0.0;
    int sis_slot = -1;  // its signal-in-space state (pseudorange_sis_states), or none: in var
    bool range = true;  // false: only its Doppler is used (a constant error found no slot)
    double el_rad = 0.0;
    const gnss::Ephemeris* eph = nullptr;
  };
  Measurement<1, N> range_measurement(const PrUse& u, const Vec3& v_a) const;
  // The slot holding this satellite's signal-in-space error, (re)assigned as needed;
  // -1: none free (every slot's satellite was ranged at this epoch or the one before).
  int sis_slot(int prn, int iode, double t, double var_m2);
  // Slots for an epoch's ranges, the highest satellites first, and each range's variance.
  void assign_sis(PrUse* use, int n, const PseudorangeEpoch& ep);
  void restart_sis_slot(int slot, double var_m2);
  SisSlots<kSisSlots> sis_slots_;
  void check_clock(const PrUse* use, int n, double t);
  bool update_galileo(const PrUse* use, int n, const Vec3& v_a, double t);
  bool update_range_rates(const PrUse* use, int n);
  void track_locks(const PseudorangeEpoch& epoch);
  double correlated_variance(int prn, double t, double el_rad, double sis_m) const;
  void initialise(const FixInput& fix);
  void decouple_yaw();
  void set_heading(const FixInput& fix, const Vec3& v_ecef, double course_rad, double sigma_rad);
  // Per-axis sigma of a fix's velocity when it states none.
  double fix_velocity_sigma(const FixInput& fix) const {
    return cfg_.fix_velocity_sigma_mps * (cfg_.fix_velocity_sigma_hdop_scaled ? fix.hdop : 1.0);
  }
  // The larger horizontal sigma of a fix's velocity, stated or configured.
  double fix_speed_sigma(const FixInput& fix) const;
  void detect_standstill(const Increment& inc);
  void track_step(double span);
  double out_of_range(const Vec3& dtheta, const Vec3& dv, double dt) const;
  void restart_after_gap(double gap_s, double t_end);
  void note_gnss(bool accepted, double t);
  void reset_to_fix(const FixInput& fix);
  static Vec3 fix_error_dops(const FixInput& fix);
  Mat3 fix_error_map(const FixInput& fix) const;
  Mat3 fast_fix_error_cov(const FixInput& fix, const Mat3& c_en) const;
  // This fix's correlated error as estimated (zero without those states).
  Vec3 fix_error_estimate(const FixInput& fix) const {
    if constexpr (NC == 3) return fix_error_map(fix) * core_.fix_error;
    return Vec3::Zero();
  }
  void event(int kind, double value);
  Vec3 gyro_rate_now() const {  // the last IMU step's mean rate (raw, calibrated)
    return last_inc_.dt_s > 0.0 ? Vec3(last_inc_.dtheta_rad / last_inc_.dt_s) : Vec3::Zero();
  }
  Vec3 antenna_velocity_now() const;
  Vec3 antenna_acceleration_now() const;
  void inflate_unknown_heading(const Increment& inc);
  void constrain_vehicle(const Increment& inc);
  void process_attitude(const AttitudeInput& a, const Increment& inc);
  template <int M>
  void record(int kind, const UpdateResult<M>& r, int dof, int id = 0);
  // robust_kind: the kind whose rejections in a row allow a down-weighted update (0: none).
  template <int M, int K>
  UpdateResult<M> apply(const Measurement<M, K>& m, int dof, int robust_kind = 0, bool standstill = false);
  std::array<int, kUpdateKindEnd> rejections_in_row_{};  // per update kind
  double gate(int dof) const { return gates_[static_cast<std::size_t>(dof)]; }
  double attitude_limit() const {
    return cfg_.update_check == UpdateCheck::AttitudeCorrection || cfg_.update_check == UpdateCheck::Both
               ? cfg_.max_attitude_correction_rad
               : 0.0;
  }

  InsConfig cfg_;
  Core core_;
  Counters counters_;
  UpdateRecord last_update_;
  std::vector<UpdateRecord>* log_ = nullptr;
  std::vector<FilterEvent>* events_ = nullptr;
  std::array<double, kGateDofs> gates_{};

  Phase phase_ = Phase::WaitingForImu;
  double t_last_ = 0.0;
  double dt_nominal_ = 1.0 / kDefaultImuRateHz;
  std::array<double, kSteps> steps_{};
  int steps_count_ = 0, steps_head_ = 0;
  Increment last_inc_;  // calibrated, for gap bridging

  // The navigation velocity's change over each recent propagation step (ECEF, updates
  // excluded): what moves a lagged fix velocity (fix_velocity_lag_s) to its fix's time.
  struct VelocityStep {
    double t_end = 0.0, dt_s = 0.0;
    Vec3 dv = Vec3::Zero();
  };
  static constexpr int kVelocitySteps = 1024;  // 1 s at 1 kHz; a longer lag uses what is kept
  std::vector<VelocityStep> velocity_steps_;   // ring, allocated only with a lag
  int velocity_steps_count_ = 0, velocity_steps_head_ = 0;
  void propagate_nav(const Increment& inc, double t_end);
  Vec3 velocity_change_since(double t0) const;
  Vec3 accel_ecef_ = Vec3::Zero();  // NT == 1: the last propagation step's kinematic acceleration (m/s^2)

  // Levelling sums before initialisation.
  Vec3 level_f_sum_ = Vec3::Zero();
  double level_time_ = 0.0;

  StandstillDetector detector_;
  bool standstill_ = false;
  int standstill_blocks_ = 0;
  double gnss_speed_mps_ = kNoSpeed, gnss_speed_t_ = kLongAgo_s;  // last GNSS speed and its time
  double gnss_speed_sigma_mps_ = 0.0;                             // that speed's sigma (per horizontal axis)
  bool moved_ = false;                                            // the filter or GNSS has shown motion since the start

  // Sustained GNSS rejection.
  double rejected_since_ = 0.0;  // set when a rejection begins (rejecting_)
  bool rejecting_ = false;

  // Inputs held until the IMU reaches their time (the oldest is used at once when one is full).
  FixedQueue<FixInput, kPending> pending_;
  static constexpr int kPendingPr = 4;
  FixedQueue<PseudorangeEpoch, kPendingPr> pending_pr_;
  double last_pr_t_ = kLongAgo_s;
  gnss::EphemerisStore store_;
  gnss::Klobuchar iono_;
  std::array<int, gnss::kMaxSatId + 1> last_lock_{};
  std::array<double, gnss::kMaxSatId + 1> locked_since_{};
  std::array<bool, gnss::kMaxSatId + 1> tracked_{};
  std::array<double, gnss::kMaxSatId + 1>
      pr_used_t_{};  // time of each satellite's last update (NaN: none since acquisition)
  bool clock_set_ = false;
  bool clock_suspect_ = false;  // the last epoch's median residual lay beyond the gate
  double last_clock_median_m_ = 0.0;
  double last_clock_t_ = kLongAgo_s;
  bool have_fix_time_ = false;
  double last_fix_t_ = 0.0;
  FixInput prev_fix_;  // the last fix used; initialise() sets it, so there is one whenever the filter navigates
  Mat3 c_vb_ = Mat3::Identity();
  FixedQueue<AttitudeInput, kPending> pending_att_;
  double last_att_t_ = kLongAgo_s;
  double last_nhc_t_ = kLongAgo_s;
  double zupt_refused_t_ = kLongAgo_s;  // the last zero-velocity update the gate refused
};

#define GPSINS_INS_FILTER_EXTERN(NB, NC, NT) extern template class InsFilter<NB, NC, NT>;
GPSINS_FOR_EACH_FILTER(GPSINS_INS_FILTER_EXTERN)
#undef GPSINS_INS_FILTER_EXTERN

}  // namespace gpsins

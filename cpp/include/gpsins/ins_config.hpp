// Configuration of the integrated navigation filter. Units are in the names;
// the Python layer reads the same names from TOML (gpsins.filter).
#pragma once

#include <limits>

#include "gpsins/types.hpp"

namespace gpsins {

enum class BiasModel { RandomWalk = 0, GaussMarkov = 1, Constant = 2 };

// What refuses a measurement update: the chi-square gate on the innovation, the
// report's divergence test on the correction's attitude part (the FOI report, 7.1.1.3),
// both, or nothing.
enum class UpdateCheck { ChiSquare = 0, AttitudeCorrection = 1, Both = 2, None = 3 };

struct BiasConfig {
  BiasModel model = BiasModel::RandomWalk;
  Vec3 random_walk_per_sqrt_s = Vec3::Zero();  // rate random walk K: rad/s/sqrt(s) or m/s^2/sqrt(s)
  Vec3 gm_sigma = Vec3::Zero();                // Gauss-Markov stationary sigma: rad/s or m/s^2
  Vec3 gm_tau_s = Vec3::Constant(100.0);       // Gauss-Markov time constant
};

struct InsConfig {
  // Only the first sample's interval; after it the nominal step is the running
  // median of the time stamps' steps, and a step over 1.5 times it is a gap.
  double imu_rate_hz = 64.0;
  // Gaps up to this are bridged with the previous rates; a longer one restarts
  // the navigation states (attitude and biases carried, covariance inflated).
  double max_gap_s = 0.5;
  // The error covariance is propagated once per this interval (s), over the increments it
  // holds, and before every update (and a smoother's output); the navigation state at every
  // increment. 0: at every increment. Under an interval shorter than two IMU steps (64 Hz at
  // 0.02 s) only the remainder of a step split at a measurement is carried with the next.
  // An output epoch between two covariance steps reports the last one's sigmas.
  double covariance_interval_s = 0.0;
  // The increments cover the whole step between stamps however long (rates
  // integrated over each interval, as an IMU CSV of rates gives): a step up to
  // max_gap_s is one increment, not a lost frame to bridge.
  bool imu_increments_cover_gaps = false;
  double gap_accel_sigma_mps2 = 2.0;  // unknown acceleration over a long gap
  // Sensor range: a sample beyond it (x 1.05) is bad, replaced like a lost frame.
  // <= 0: no limit.
  double gyro_range_rad_per_s = 0.0;
  double accel_range_mps2 = 0.0;

  // IMU calibration applied to the raw increments: measured = (1 + sf) true + bias.
  Vec3 gyro_bias_cal_rad_per_s = Vec3::Zero();
  Vec3 accel_bias_cal_mps2 = Vec3::Zero();
  Vec3 gyro_scale_factor_cal = Vec3::Zero();
  Vec3 accel_scale_factor_cal = Vec3::Zero();

  // White noise densities (Allan N): process noise V = N^2.
  Vec3 gyro_arw_rad_per_sqrt_s = Vec3::Constant(1e-3);
  Vec3 accel_vrw_mps_per_sqrt_s = Vec3::Constant(1e-2);
  // White density added to the process noise (not to the detectors' noise) for the part
  // of the bias instability the random-walk bias does not reach at short averaging
  // times (gpsins.filter.flicker_white_var); the process noise is then N^2 + this^2.
  Vec3 gyro_flicker_white_rad_per_sqrt_s = Vec3::Zero();
  Vec3 accel_flicker_white_mps_per_sqrt_s = Vec3::Zero();
  BiasConfig gyro_bias;
  BiasConfig accel_bias;
  bool scale_factor_states = false;
  Vec3 gyro_scale_factor_sigma = Vec3::Constant(1e-3);
  Vec3 accel_scale_factor_sigma = Vec3::Constant(1e-3);

  // Misalignment (non-orthogonality) of the gyro triad left by the calibration: 1 sigma
  // of each off-diagonal element of its matrix (a datasheet's cross-axis sensitivity or
  // the calibration's uncertainty), carried as rate-driven attitude noise (eskf.hpp).
  // 0: not modelled.
  double gyro_misalignment_sigma_rad = 0.0;

  // Initial uncertainty (1 sigma). Attitude as roll, pitch, yaw about local NED.
  Vec3 attitude_sigma_rad = Vec3(0.02, 0.02, 0.1);
  double velocity_sigma_mps = 1.0;
  double position_sigma_m = 10.0;
  Vec3 gyro_bias_sigma_rad_per_s = Vec3::Constant(2e-3);
  Vec3 accel_bias_sigma_mps2 = Vec3::Constant(0.05);

  // Receiver clock (tight coupling), random walks on bias and drift.
  double clock_bias_sigma_m = 100.0;  // after the bias is set from the first epoch
  double clock_drift_sigma_mps = 100.0;
  double clock_reseed_window_s = 120.0;  // a re-seed takes the drift from two epochs at most this far apart
  double clock_bias_noise_m_per_sqrt_s = 0.1;
  double clock_drift_noise_mps_per_sqrt_s = 0.01;  // a TCXO; larger for a poorer oscillator

  // Initialisation.
  double level_time_s = 1.0;                                          // accelerometer mean for roll and pitch
  double initial_yaw_rad = std::numeric_limits<double>::quiet_NaN();  // NaN: from GNSS course
  double heading_min_speed_mps = 3.0;
  double heading_sigma_rad = 0.05;
  // Below heading_min_speed_mps a measured velocity gives the heading once its
  // course sigma (velocity sigma / speed) is at most this; 0 turns that off.
  double heading_max_course_sigma_rad = 0.0;

  // GNSS fix. R from the fix's own sigmas when it states them, else from HDOP/VDOP
  // times the UERE; fixed ECEF sigmas (> 0) override both.
  Vec3 lever_arm_body_m = Vec3::Zero();
  // Dual-antenna attitude aiding (push_attitude): the baseline, antenna 1 to
  // antenna 2, in body axes, and a chi-square gate like every other update.
  Vec3 antenna_baseline_body = Vec3(1.0, 0.0, 0.0);
  double fix_uere_m = 3.0;
  // A 2D fix holds the height of an earlier one: that height's error moves it
  // sideways by more than its HDOP says. Its white UERE (<= 0: fix_uere_m).
  double fix_uere_2d_m = 0.0;
  Vec3 fix_sigma_ecef_m = Vec3::Zero();
  // Time-correlated fix errors (multipath, ionosphere and troposphere residuals
  // stay correlated for tens of seconds): first-order Gauss-Markov states per
  // local north, east, down axis with these stationary sigmas and one correlation
  // time, loose coupling only. The fix's own R (its stated sigmas or UERE x DOP)
  // is then its white part only. All sigmas 0: no states, every fix white.
  Vec3 fix_error_gm_sigma_m = Vec3::Zero();
  double fix_error_gm_tau_s = 60.0;
  // The correlated error carried per unit of DOP (a receiver's multipath grows with
  // its geometry's DOP as its noise does): the states' sigmas are then UERE-like and
  // each fix sees them times its HDOP / sqrt(2) (north, east) and VDOP (down).
  bool fix_error_gm_dop_scaled = false;
  // A second, faster correlated part per north, east, down axis (per unit of DOP like
  // the states' when fix_error_gm_dop_scaled), carried without states: each fix's R
  // grows by sigma^2 (1 + a) / (1 - a), a = exp(-dt / tau), dt since the previous fix,
  // so N fixes weigh as much as the mean of N correlated samples (as
  // pseudorange_error_gm_* does). With it the states can carry a slow part alone.
  Vec3 fix_error_fast_sigma_m = Vec3::Zero();
  double fix_error_fast_tau_s = 0.0;  // <= 0: the fast part is white
  bool use_fix_velocity = false;
  double fix_velocity_sigma_mps = 0.1;  // per axis (unless the fix states its own); times HDOP when scaled
  bool fix_velocity_sigma_hdop_scaled = false;
  // How long before its fix's time a fix velocity applies: a receiver that reports the
  // mean velocity over the epoch just ended (carrier-phase or position differences)
  // refers to its middle, half an epoch back. The filter then moves it to the fix's time
  // with its own velocity change since. 0: at the fix's time.
  double fix_velocity_lag_s = 0.0;

  // Pseudoranges (tight coupling). White variance from the elevation model when
  // the sigma is <= 0 (RTKLIB's code, atmosphere and code-bias terms; its broadcast
  // URA term is the signal-in-space part below, not white noise).
  double pseudorange_sigma_m = 0.0;
  double pseudorange_elevation_mask_rad = 0.2617993877991494;  // 15 deg
  double pseudorange_min_cn0_dbhz = 30.0;
  double pseudorange_settle_s = 1.0;  // skip a satellite this long after (re)acquisition
  // Use every n-th measurement epoch. Pseudorange errors (multipath, ionosphere and
  // troposphere residuals) stay correlated for tens of seconds; updating with all
  // of the receiver's 10 Hz epochs as if they were independent makes the filter
  // several times too confident. 1 Hz keeps it consistent (and is the report's rate).
  int pseudorange_decimation = 10;
  // Their correlated part, for updating at any rate (tight coupling's alternative to
  // per-satellite bias states): a first-order Gauss-Markov error with this sigma at
  // zenith (growing as 1 / sin(elevation), as multipath does) and correlation time.
  // Each update of a satellite adds sigma^2 (1 + a) / (1 - a) to its variance, a =
  // exp(-dt / tau), dt the time since that satellite's previous update: N updates
  // then carry the information of their mean, sigma^2 (1 + a) / ((1 - a) N), as
  // correlated samples do, so the rate no longer decides the confidence. 0: off.
  double pseudorange_error_gm_sigma_m = 0.0;
  double pseudorange_error_gm_tau_s = 60.0;
  // Signal-in-space error: the broadcast orbit and clock's error along the line of
  // sight, per satellite, the same at any elevation, changing over hours. Its sigma
  // is this figure, or the satellite's broadcast URA when pseudorange_sis_use_ura
  // (which bounds the error rather than measuring it). With pseudorange_sis_states
  // it is each satellite's state (tau <= 0: a random constant). Without, it is added
  // to each update's variance as the correlated part is, with its own correlation
  // time: the sigma^2 (1 + a) / (1 - a) of a Gauss-Markov error; tau <= 0: white (as
  // the elevation model had it, and the default: URA as white noise).
  double pseudorange_sis_sigma_m = 0.0;
  bool pseudorange_sis_use_ura = true;
  double pseudorange_sis_tau_s = 0.0;
  // Tight: carry each satellite's signal-in-space error as a state (a slot of
  // kSisSlots; eskf.hpp) instead of in each update's variance: the error then stays
  // one error however long the filter remembers its ranges (Doppler keeps it
  // remembering for minutes). Its sigma and tau are the ones above. A satellite
  // finding no free slot falls back to the variance when tau > 0; with tau <= 0 its
  // range is not used (its Doppler is): a constant error taken as white would
  // average into the position as if it were information.
  bool pseudorange_sis_states = false;
  bool pseudorange_ionosphere = true;
  bool pseudorange_troposphere = true;
  // Doppler (tight coupling): each satellite's range rate, with variance
  // sigma^2 (1 + 1 / sin^2 el) / 2 (this sigma at zenith), used once the heading is
  // known, as fix velocities are. Doppler is white (no multipath to speak of) and
  // sees the velocity along each line of sight, so a slow platform's heading
  // becomes observable where pseudoranges' metres cannot show it. <= 0: not used.
  double doppler_sigma_mps = 0.0;
  double gps_time_offset_s = 0.0;  // filter time + this = GPS seconds since the GPS epoch

  // IMU time offset state (eskf.hpp, NT = 1): the residual dt_imu by which the IMU's
  // stamps (after the data set's declared offset) lag GNSS time, i.e. what should be
  // added to the declared offset. Constant plus a slow random walk.
  bool estimate_time_offset = false;
  double time_offset_sigma_s = 0.05;          // initial sigma
  double time_offset_rw_s_per_sqrt_s = 1e-5;  // random walk

  // Standstill (see standstill.hpp): spreads of block means over the window,
  // the mean's shift from its value when standing began, the mean rate. It
  // begins only below standstill_max_speed_mps (filter) and ends or is barred
  // by a GNSS speed above standstill_max_gnss_speed_mps.
  bool zero_velocity_updates = true;
  double standstill_window_s = 0.5;
  double standstill_block_s = 0.05;
  double standstill_accel_std_mps2 = 0.12;
  double standstill_gyro_std_rad_per_s = 0.015;
  double standstill_gyro_mean_rad_per_s = 0.02;
  double standstill_accel_shift_mps2 = 0.05;
  double standstill_holdoff_s = 2.0;  // after a standstill: resume only at its specific force
  double standstill_max_speed_mps = 0.5;
  double standstill_max_gnss_speed_mps = 0.3;
  double zero_velocity_sigma_mps = 0.02;
  double zero_rate_sigma_rad_per_s = 1e-4;

  // Land vehicle (aiding/nonholonomic.hpp): no lateral and no vertical velocity
  // at the vehicle point, while moving with a known heading, every nhc_interval_s
  // (the constraint's errors, bumps and skids, are correlated over a wheel turn).
  bool nonholonomic_constraint = false;
  Vec3 body_to_vehicle_ypr_rad = Vec3::Zero();  // v_vehicle = Rz(y) Ry(p) Rx(r) v_body
  Vec3 vehicle_point_body_m = Vec3::Zero();     // where the constraint holds, from the IMU
  // The lateral row's sigma, and the vertical's unless nhc_vertical_sigma_mps > 0: a car's
  // ride (its body pitching on the springs) violates the vertical row far more than a skid the lateral.
  double nhc_sigma_mps = 0.1;
  double nhc_vertical_sigma_mps = 0.0;
  double nhc_min_speed_mps = 1.0;
  double nhc_interval_s = 0.1;

  // Innovation gate: chi-square probability (<= 0 or >= 1 disables gating).
  double gate_probability = 0.9999;
  UpdateCheck update_check = UpdateCheck::ChiSquare;
  // No lock-out: after this many gate rejections in a row of one kind of GNSS-derived
  // update (3D fix, fix velocity, non-holonomic), each further one beyond the gate is used
  // with its R scaled by NIS / gate until one passes: an isolated outlier is refused, but a
  // filter whose covariance has grown too small is pulled back by every fix instead of
  // refusing them all until a reset. Its pull on the state, in units of its own sigma, then
  // falls as gate / sqrt(NIS), so a run of wild fixes moves it little. Such a fix still counts
  // as rejected (fixes_rejected, the GNSS reset's timer). <= 0: hard rejection.
  int robust_after_rejections = 3;
  // Only the standstill updates (zero velocity, zero rate) are gated; every other update is
  // used whatever its NIS. For the likelihood fits' runs (nav/noise_from_data.py): no
  // hypothesis loses a fix to its gate, while a refused zero-velocity update still ends a
  // standstill the detector began too early or left too late.
  bool gate_standstill_only = false;
  double max_attitude_correction_rad = 0.0873;  // 5 deg, for the attitude-correction check
  // GNSS measurements rejected this long while the receiver reports solutions:
  // position and velocity reset to GNSS with inflated covariance. <= 0: never.
  double gnss_reset_timeout_s = 5.0;
  // ...but only onto a fix whose DOPs are at most this (a data set's fix: the DOP its
  // stated sigma stands for). A receiver's saturated DOP (99.9) marks a solution it
  // cannot vouch for: on a simulated day 4-satellite fixes 58 km off were taken.
  double gnss_reset_max_dop = 10.0;
  // A fix whose HDOP (or, 3D, VDOP) is above this is not used (0: all are): its R
  // cannot be known when the DOP is the receiver's saturated 99.9.
  double fix_max_dop = 0.0;
  // A fix's DOP is taken as at least this for its R: a receiver never has a DOP far below 1,
  // and a 1e-9 would make the fix absolute.
  double fix_min_dop = 0.5;
  // A fix whose ellipsoidal height is outside these is not on or above the Earth's surface as a
  // vehicle can be (the Dead Sea shore is at -430 m plus the geoid; 100 km is the Karman line).
  double fix_min_height_m = -1000.0;
  double fix_max_height_m = 1.0e5;
  // Divergence guard: position sigma beyond this marks the filter diverged.
  double max_position_sigma_m = 1e4;
};

}  // namespace gpsins

// pybind11 face of the filter's configuration: InsConfig, its bias models and
// update checks (the TOML names are gpsins.filter's).
#include <pybind11/eigen.h>
#include <pybind11/pybind11.h>

#include "filter_bind.hpp"
#include "gpsins/ins_config.hpp"

namespace gpsins::py_filter {

void bind_filter_config(py::module_& m) {
  py::enum_<BiasModel>(m, "BiasModel")
      .value("random_walk", BiasModel::RandomWalk)
      .value("gauss_markov", BiasModel::GaussMarkov)
      .value("constant", BiasModel::Constant);

  py::enum_<UpdateCheck>(m, "UpdateCheck")
      .value("chi_square", UpdateCheck::ChiSquare)
      .value("attitude_correction", UpdateCheck::AttitudeCorrection)
      .value("both", UpdateCheck::Both)
      .value("none", UpdateCheck::None);

  py::class_<BiasConfig>(m, "BiasConfig")
      .def(py::init<>())
      .def_readwrite("model", &BiasConfig::model)
      .def_readwrite("random_walk_per_sqrt_s", &BiasConfig::random_walk_per_sqrt_s)
      .def_readwrite("gm_sigma", &BiasConfig::gm_sigma)
      .def_readwrite("gm_tau_s", &BiasConfig::gm_tau_s);

  py::class_<InsConfig> c(m, "InsConfig", "Filter configuration (see gpsins.filter for the TOML names).");
  c.def(py::init<>());
#define GPSINS_FIELD(name) c.def_readwrite(#name, &InsConfig::name)
  GPSINS_FIELD(imu_rate_hz);
  GPSINS_FIELD(max_gap_s);
  GPSINS_FIELD(covariance_interval_s);
  GPSINS_FIELD(gate_standstill_only);
  GPSINS_FIELD(imu_increments_cover_gaps);
  GPSINS_FIELD(gap_accel_sigma_mps2);
  GPSINS_FIELD(gyro_range_rad_per_s);
  GPSINS_FIELD(accel_range_mps2);
  GPSINS_FIELD(gyro_bias_cal_rad_per_s);
  GPSINS_FIELD(accel_bias_cal_mps2);
  GPSINS_FIELD(gyro_scale_factor_cal);
  GPSINS_FIELD(accel_scale_factor_cal);
  GPSINS_FIELD(gyro_arw_rad_per_sqrt_s);
  GPSINS_FIELD(accel_vrw_mps_per_sqrt_s);
  GPSINS_FIELD(gyro_flicker_white_rad_per_sqrt_s);
  GPSINS_FIELD(accel_flicker_white_mps_per_sqrt_s);
  GPSINS_FIELD(gyro_bias);
  GPSINS_FIELD(accel_bias);
  GPSINS_FIELD(scale_factor_states);
  GPSINS_FIELD(pseudorange_sis_states);
  GPSINS_FIELD(gyro_scale_factor_sigma);
  GPSINS_FIELD(accel_scale_factor_sigma);
  GPSINS_FIELD(gyro_misalignment_sigma_rad);
  GPSINS_FIELD(attitude_sigma_rad);
  GPSINS_FIELD(velocity_sigma_mps);
  GPSINS_FIELD(position_sigma_m);
  GPSINS_FIELD(gyro_bias_sigma_rad_per_s);
  GPSINS_FIELD(accel_bias_sigma_mps2);
  GPSINS_FIELD(clock_bias_sigma_m);
  GPSINS_FIELD(clock_drift_sigma_mps);
  GPSINS_FIELD(clock_reseed_window_s);
  GPSINS_FIELD(clock_bias_noise_m_per_sqrt_s);
  GPSINS_FIELD(clock_drift_noise_mps_per_sqrt_s);
  GPSINS_FIELD(level_time_s);
  GPSINS_FIELD(initial_yaw_rad);
  GPSINS_FIELD(heading_min_speed_mps);
  GPSINS_FIELD(heading_sigma_rad);
  GPSINS_FIELD(heading_max_course_sigma_rad);
  GPSINS_FIELD(lever_arm_body_m);
  GPSINS_FIELD(antenna_baseline_body);
  GPSINS_FIELD(fix_uere_m);
  GPSINS_FIELD(fix_sigma_ecef_m);
  GPSINS_FIELD(fix_error_gm_sigma_m);
  GPSINS_FIELD(fix_error_gm_tau_s);
  GPSINS_FIELD(fix_error_fast_sigma_m);
  GPSINS_FIELD(fix_error_fast_tau_s);
  GPSINS_FIELD(fix_uere_2d_m);
  GPSINS_FIELD(fix_error_gm_dop_scaled);
  GPSINS_FIELD(use_fix_velocity);
  GPSINS_FIELD(fix_velocity_sigma_mps);
  GPSINS_FIELD(fix_velocity_sigma_hdop_scaled);
  GPSINS_FIELD(fix_velocity_lag_s);
  GPSINS_FIELD(pseudorange_sigma_m);
  GPSINS_FIELD(pseudorange_elevation_mask_rad);
  GPSINS_FIELD(pseudorange_min_cn0_dbhz);
  GPSINS_FIELD(pseudorange_settle_s);
  GPSINS_FIELD(pseudorange_decimation);
  GPSINS_FIELD(pseudorange_error_gm_sigma_m);
  GPSINS_FIELD(pseudorange_error_gm_tau_s);
  GPSINS_FIELD(pseudorange_sis_sigma_m);
  GPSINS_FIELD(pseudorange_sis_use_ura);
  GPSINS_FIELD(pseudorange_sis_tau_s);
  GPSINS_FIELD(pseudorange_ionosphere);
  GPSINS_FIELD(pseudorange_troposphere);
  GPSINS_FIELD(doppler_sigma_mps);
  GPSINS_FIELD(gps_time_offset_s);
  GPSINS_FIELD(estimate_time_offset);
  GPSINS_FIELD(time_offset_sigma_s);
  GPSINS_FIELD(time_offset_rw_s_per_sqrt_s);
  GPSINS_FIELD(zero_velocity_updates);
  GPSINS_FIELD(standstill_window_s);
  GPSINS_FIELD(standstill_block_s);
  GPSINS_FIELD(standstill_accel_shift_mps2);
  GPSINS_FIELD(standstill_holdoff_s);
  GPSINS_FIELD(standstill_max_gnss_speed_mps);
  GPSINS_FIELD(standstill_accel_std_mps2);
  GPSINS_FIELD(standstill_gyro_std_rad_per_s);
  GPSINS_FIELD(standstill_gyro_mean_rad_per_s);
  GPSINS_FIELD(standstill_max_speed_mps);
  GPSINS_FIELD(zero_velocity_sigma_mps);
  GPSINS_FIELD(zero_rate_sigma_rad_per_s);
  GPSINS_FIELD(nonholonomic_constraint);
  GPSINS_FIELD(body_to_vehicle_ypr_rad);
  GPSINS_FIELD(vehicle_point_body_m);
  GPSINS_FIELD(nhc_sigma_mps);
  GPSINS_FIELD(nhc_vertical_sigma_mps);
  GPSINS_FIELD(nhc_min_speed_mps);
  GPSINS_FIELD(nhc_interval_s);
  GPSINS_FIELD(gate_probability);
  GPSINS_FIELD(update_check);
  GPSINS_FIELD(robust_after_rejections);
  GPSINS_FIELD(fix_min_dop);
  GPSINS_FIELD(fix_min_height_m);
  GPSINS_FIELD(fix_max_height_m);
  GPSINS_FIELD(max_attitude_correction_rad);
  GPSINS_FIELD(gnss_reset_timeout_s);
  GPSINS_FIELD(gnss_reset_max_dop);
  GPSINS_FIELD(fix_max_dop);
  GPSINS_FIELD(max_position_sigma_m);
#undef GPSINS_FIELD
}

}  // namespace gpsins::py_filter

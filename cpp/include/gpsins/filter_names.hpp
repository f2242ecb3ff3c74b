// The names the C++ core and Python share, each listed once: the update kinds
// (UpdateRecord::kind), the filter's events (FilterEvent::kind) and its counters
// (Counters). ins_filter.hpp builds the enums and the Counters struct from these
// lists, and the bindings export them (gpsins._core.UPDATE_KINDS, EVENT_KINDS,
// COUNTER_NAMES), so a kind or counter added here reaches run.json, the report
// and live's status without a second list to keep in step.
#pragma once

// X(enumerator, value, name)
#define GPSINS_UPDATE_KINDS(X)                 \
  X(kFix3D, 1, "fix_3d")                       \
  X(kFix2D, 2, "fix_2d")                       \
  X(kFixVelocity, 3, "fix_velocity")           \
  X(kZeroVelocity, 4, "zero_velocity")         \
  X(kZeroRate, 5, "zero_rate")                 \
  X(kPseudorange, 6, "pseudorange")            \
  X(kNonholonomic, 7, "nonholonomic")          \
  X(kBaselineAttitude, 8, "baseline_attitude") \
  X(kRangeRate, 9, "range_rate")

// X(enumerator, value, name); what FilterEvent::value holds is said beside each.
#define GPSINS_EVENT_KINDS(X)                                                                             \
  X(kImuGapRestart, 1, "imu_gap_restart")         /* the gap (s) */                                       \
  X(kGnssReset, 2, "gnss_reset")                  /* how long GNSS had been rejected (s) */               \
  X(kImuSampleRejected, 3, "imu_sample_rejected") /* the sample's largest rate or force over its range */ \
  X(kHeadingSet, 4, "heading_set")                /* the heading (rad) */                                 \
  X(kClockReseed, 5, "clock_reseed")              /* the receiver clock's jump from its prediction (m) */

// X(field): each an int64 count, named in Python as here.
#define GPSINS_COUNTERS(X)                                                                                   \
  X(imu_samples)                                                                                             \
  X(imu_gaps_bridged)                                                                                        \
  X(imu_gap_restarts)         /* gaps over max_gap_s: navigation restarted */                                \
  X(imu_samples_rejected)     /* beyond the sensor's range, replaced like a lost frame */                    \
  X(gnss_resets)              /* position and velocity reset to GNSS after sustained rejections */           \
  X(updates_attitude_refused) /* the attitude-correction check refused the update */                         \
  X(fixes)                                                                                                   \
  X(fixes_accepted)                                                                                          \
  X(fixes_rejected)                                                                                          \
  X(fixes_implausible) /* not used: a height outside [fix_min_height_m, fix_max_height_m] */                 \
  X(fixes_dop_masked)  /* not used: a DOP beyond fix_max_dop (99.9 says only "at least") */                  \
  X(fixes_without_solution)                                                                                  \
  X(fixes_before_alignment)                                                                                  \
  X(fixes_late)                                                                                              \
  X(fixes_in_imu_gap) /* not used: queued beyond max_gap_s ahead of the IMU */                               \
  X(zero_velocity_updates)                                                                                   \
  X(zero_rate_updates)                                                                                       \
  X(nonholonomic_updates)                                                                                    \
  X(baseline_attitude_updates) /* dual-antenna heading/pitch used (accepted or not) */                       \
  X(updates_rejected)                                                                                        \
  X(updates_guarded)                                                                                         \
  X(updates_downweighted) /* beyond the gate, used with a scaled R (robust_after_rejections) */              \
  X(standstill_samples)                                                                                      \
  X(pseudorange_epochs)                                                                                      \
  X(pseudoranges_used)                                                                                       \
  X(pseudoranges_rejected)                                                                                   \
  X(pseudoranges_no_ephemeris)                                                                               \
  X(pseudoranges_masked) /* elevation, C/N0 or settling after (re)acquisition */                             \
  X(range_rates_used)                                                                                        \
  X(range_rates_rejected)                                                                                    \
  X(clock_reseeds)                 /* receiver clock bias (and drift) re-seeded from an epoch's residuals */ \
  X(sis_slots_taken)               /* signal-in-space slots taken by a satellite without one */              \
  X(sis_slots_restarted)           /* ... restarted by a new ephemeris issue */                              \
  X(pseudoranges_without_sis_slot) /* ... and ranges that found none free (not used with tau <= 0) */

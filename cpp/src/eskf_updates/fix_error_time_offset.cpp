// Eskf's measurement updates (1, 2 and 3 rows) for the loose filters with the fix-error states and the IMU time offset,
// with and without the scale-factor states: one of six files, so that the twelve
// state layouts' updates build in parallel (eskf.hpp).
#include "gpsins/eskf_update.hpp"

namespace gpsins {

GPSINS_ESKF_UPDATES(5, 3, 1)
GPSINS_ESKF_UPDATES(7, 3, 1)

}  // namespace gpsins

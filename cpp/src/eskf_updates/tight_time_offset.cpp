// Eskf's measurement updates (1, 2 and 3 rows) for the tight filters with the IMU time offset,
// with and without the scale-factor states: one of six files, so that the twelve
// state layouts' updates build in parallel (eskf.hpp).
#include "gpsins/eskf_update.hpp"

namespace gpsins {

GPSINS_ESKF_UPDATES(5, kTightAugmented, 1)
GPSINS_ESKF_UPDATES(7, kTightAugmented, 1)

}  // namespace gpsins

// Eskf's measurement updates (1, 2 and 3 rows) for the tight filters (signal-in-space slots and clock),
// with and without the scale-factor states: one of six files, so that the twelve
// state layouts' updates build in parallel (eskf.hpp).
#include "gpsins/eskf_update.hpp"

namespace gpsins {

GPSINS_ESKF_UPDATES(5, kTightAugmented, 0)
GPSINS_ESKF_UPDATES(7, kTightAugmented, 0)

}  // namespace gpsins

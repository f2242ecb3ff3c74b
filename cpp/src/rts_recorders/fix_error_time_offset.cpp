// The smoother's recorders (their backward pass) for the loose filters with the fix-error states and the IMU time
// offset, with and without the scale-factor states: one of six files, so that the twelve state layouts' backward passes
// build in parallel, each file within the memory of a small machine (rts.hpp).
#include "gpsins/rts.hpp"

namespace gpsins {

template class EskfRecorder<5, 3, 1>;
template class EskfRecorder<7, 3, 1>;

}  // namespace gpsins

// The smoother's recorders for the filters with the IMU time offset state
// (rts_recorders.cpp: without it).
#include "gpsins/rts.hpp"

namespace gpsins {

template class EskfRecorder<5, 0, 1>;
template class EskfRecorder<7, 0, 1>;
template class EskfRecorder<5, kTightAugmented, 1>;
template class EskfRecorder<7, kTightAugmented, 1>;
template class EskfRecorder<5, 3, 1>;
template class EskfRecorder<7, 3, 1>;

}  // namespace gpsins

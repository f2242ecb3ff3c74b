// The smoother's recorders for the filters the core builds without the IMU time
// offset state (rts_recorders_time_offset.cpp: with it); two files, so that the
// backward passes of the twelve state layouts build in parallel.
#include "gpsins/rts.hpp"

namespace gpsins {

template class EskfRecorder<5, 0>;
template class EskfRecorder<7, 0>;
template class EskfRecorder<5, kTightAugmented>;
template class EskfRecorder<7, kTightAugmented>;
template class EskfRecorder<5, 3>;
template class EskfRecorder<7, 3>;

}  // namespace gpsins

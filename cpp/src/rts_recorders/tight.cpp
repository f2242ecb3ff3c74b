// The smoother's recorders (their backward pass) for the tight filters (signal-in-space slots and clock),
// with and without the scale-factor states: one of six files, so that the twelve
// state layouts' backward passes build in parallel, each file within the memory
// of a small machine (rts.hpp).
#include "gpsins/rts.hpp"

namespace gpsins {

template class EskfRecorder<5, kTightAugmented>;
template class EskfRecorder<7, kTightAugmented>;

}  // namespace gpsins

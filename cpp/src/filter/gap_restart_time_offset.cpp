// InsFilter's restart after an IMU gap (gap_restart.hpp) for the filters with the IMU time offset state.
#include "gap_restart.hpp"

namespace gpsins {

template void InsFilter<5, 0, 1>::restart_after_gap(double, double);
template void InsFilter<7, 0, 1>::restart_after_gap(double, double);
template void InsFilter<5, kTightAugmented, 1>::restart_after_gap(double, double);
template void InsFilter<7, kTightAugmented, 1>::restart_after_gap(double, double);
template void InsFilter<5, 3, 1>::restart_after_gap(double, double);
template void InsFilter<7, 3, 1>::restart_after_gap(double, double);

}  // namespace gpsins

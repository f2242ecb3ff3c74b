// InsFilter's restart after an IMU gap (gap_restart.hpp) for the filters without the IMU time offset state.
#include "gap_restart.hpp"

namespace gpsins {

template void InsFilter<5, 0, 0>::restart_after_gap(double, double);
template void InsFilter<7, 0, 0>::restart_after_gap(double, double);
template void InsFilter<5, kTightAugmented, 0>::restart_after_gap(double, double);
template void InsFilter<7, kTightAugmented, 0>::restart_after_gap(double, double);
template void InsFilter<5, 3, 0>::restart_after_gap(double, double);
template void InsFilter<7, 3, 0>::restart_after_gap(double, double);

}  // namespace gpsins

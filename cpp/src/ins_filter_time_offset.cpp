// The filter with the IMU time offset state (NT = 1): ins_filter.cpp's
// definitions instantiated in a translation unit of their own, so that the two
// halves of the instantiations build in parallel.
#define GPSINS_INS_FILTER_TIME_OFFSET
#include "ins_filter.cpp"

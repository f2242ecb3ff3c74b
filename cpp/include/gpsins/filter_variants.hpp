// The filter variants the core builds, listed once. A variant is the state layout
// Eskf<NB, NC, NT> (and InsFilter<NB, NC, NT> around it): NB = 5 or 7 IMU error
// blocks (7 adds the gyro and accelerometer scale factors); NC = 0 (no augmented
// states), kTightAugmented (the tight filter's signal-in-space slots and receiver
// clock) or 3 (the loose filter's fix error); NT = 1 adds the IMU time offset.
//
// Every explicit instantiation and its extern declaration (eskf.hpp, rts.hpp,
// ins_filter.hpp, batch.hpp, src/filter/) and batch.hpp's AnyFilter expand this
// list, so a variant added here is declared, compiled and reachable everywhere;
// the files that compile a few variants each (src/eskf_updates/, src/rts_recorders/)
// fail to link until they cover it.
#pragma once

// clang-format off
// X(NB, NC, NT) for each variant, SEP() between two.
#define GPSINS_FILTER_LIST(X, SEP)                                                     \
  X(5, 0, 0) SEP() X(7, 0, 0) SEP() X(5, kTightAugmented, 0) SEP() X(7, kTightAugmented, 0) SEP() \
  X(5, 3, 0) SEP() X(7, 3, 0) SEP() X(5, 0, 1) SEP() X(7, 0, 1) SEP()                    \
  X(5, kTightAugmented, 1) SEP() X(7, kTightAugmented, 1) SEP() X(5, 3, 1) SEP() X(7, 3, 1)
// clang-format on
#define GPSINS_NO_SEPARATOR()
#define GPSINS_COMMA_SEPARATOR() ,
// X(NB, NC, NT) for each variant, one after the other (declarations, instantiations).
#define GPSINS_FOR_EACH_FILTER(X) GPSINS_FILTER_LIST(X, GPSINS_NO_SEPARATOR)

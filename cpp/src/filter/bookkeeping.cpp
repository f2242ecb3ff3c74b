// InsFilter's bookkeeping: input status texts and the event log (the update
// record and the gated update every file uses, record and apply, are member
// templates in internal.hpp).
#include "internal.hpp"

namespace gpsins {

const char* input_status_text(InputStatus s) {
  switch (s) {
    case InputStatus::Ok:
      return "ok";
    case InputStatus::NonFinite:
      return "value is NaN or infinite";
    case InputStatus::TimeNotIncreasing:
      return "time does not increase";
    case InputStatus::BadValue:
      return "value out of range";
  }
  return "unknown";
}

template <int NB, int NC, int NT>
void InsFilter<NB, NC, NT>::event(int kind, double value) {
  if (events_) events_->push_back(FilterEvent{t_last_, kind, value});
}

#define GPSINS_INSTANTIATE(NB, NC, NT) template void InsFilter<NB, NC, NT>::event(int, double);
GPSINS_FOR_EACH_FILTER(GPSINS_INSTANTIATE)
#undef GPSINS_INSTANTIATE

}  // namespace gpsins

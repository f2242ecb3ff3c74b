// pybind11 face of the integrated filter: the names the core and Python share
// (filter_names.hpp), then the configuration (bind_filter_config.cpp) and the
// filter object (bind_filter_object.cpp; its batch results and smoothing in
// bind_filter_batch.cpp, the batch loop itself in the core's batch.hpp).
#include <pybind11/pybind11.h>

#include "filter_bind.hpp"
#include "gpsins/filter_names.hpp"

namespace py = pybind11;
using namespace gpsins;

void bind_filter(py::module_& m) {
  // The tight filter's signal-in-space slots: its output rows carry them before the clock.
  m.attr("SIS_SLOTS") = kSisSlots;
  // The shared names (filter_names.hpp): update and event kinds by value, the counters in order.
  py::dict update_kinds, event_kinds;
#define GPSINS_KIND_ITEM(dict_, enumerator, value, name) dict_[py::int_(value)] = name;
#define GPSINS_UPDATE_ITEM(enumerator, value, name) GPSINS_KIND_ITEM(update_kinds, enumerator, value, name)
#define GPSINS_EVENT_ITEM(enumerator, value, name) GPSINS_KIND_ITEM(event_kinds, enumerator, value, name)
  GPSINS_UPDATE_KINDS(GPSINS_UPDATE_ITEM)
  GPSINS_EVENT_KINDS(GPSINS_EVENT_ITEM)
#undef GPSINS_EVENT_ITEM
#undef GPSINS_UPDATE_ITEM
#undef GPSINS_KIND_ITEM
  m.attr("UPDATE_KINDS") = update_kinds;
  m.attr("EVENT_KINDS") = event_kinds;
  py::list counter_names;
#define GPSINS_COUNTER_NAME(name) counter_names.append(#name);
  GPSINS_COUNTERS(GPSINS_COUNTER_NAME)
#undef GPSINS_COUNTER_NAME
  m.attr("COUNTER_NAMES") = py::tuple(counter_names);
  py_filter::bind_filter_config(m);
  py_filter::bind_filter_object(m);
}

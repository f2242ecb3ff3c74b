// What the filter's binding files share (bind_filter*.cpp): NumPy tables in,
// the filter's records and batch results out as Python objects. Input errors
// raise ValueError naming the array, the row and the reason.
#pragma once

#include <pybind11/numpy.h>
#include <pybind11/pybind11.h>

#include "gpsins/batch.hpp"

namespace gpsins::py_filter {

namespace py = pybind11;
using Array = py::array_t<double, py::array::c_style | py::array::forcecast>;

[[noreturn]] void input_error(const char* what, py::ssize_t row, double t, InputStatus s);
// obj as a float array of shape (n, cols), or (n, alt_cols) when alt_cols > 0.
Array table(py::handle obj, int cols, const char* name, int alt_cols = -1);
BatchTable table_of(const Array& a);

py::dict counters_dict(const Counters& c);
py::dict update_dict(const UpdateRecord& u);
// A batch call's result as run() returns it (state, covariance, updates, events, counters, ...).
py::dict batch_dict(BatchResult& r, bool with_cov);  // moves r's covariances out
// The backward pass over what run(..., record=True) recorded in carry (see bind_filter_batch.cpp).
// The backward pass over the recorded run; nav_cov: the covariance's navigation block only.
py::dict smooth_dict(AnyFilter& f, const BatchCarry& carry, bool with_cov, py::object sink, long block_rows,
                     bool nav_cov);

void bind_filter_config(py::module_& m);  // InsConfig and its enums
void bind_filter_object(py::module_& m);  // the InsFilter class: streaming and batch

}  // namespace gpsins::py_filter

// Helpers to apply fixed-size C++ functions over NumPy arrays of shape
// (..., *tail): every leading index is one item ("row"). Errors name the
// function and the argument.
#pragma once

#include <pybind11/numpy.h>
#include <pybind11/pybind11.h>

#include <initializer_list>
#include <string>
#include <vector>

namespace gpsins::py_rows {

namespace py = pybind11;
using Array = py::array_t<double, py::array::c_style | py::array::forcecast>;

struct Rows {
  Array array;
  std::vector<py::ssize_t> lead;  // leading shape
  py::ssize_t count = 0;          // number of rows
  py::ssize_t stride = 0;         // doubles per row
  const double* row(py::ssize_t i) const { return array.data() + (count == 1 ? 0 : i) * stride; }
};

inline std::string shape_text(const py::array& a) {
  std::string s = "(";
  for (py::ssize_t i = 0; i < a.ndim(); ++i) s += (i ? ", " : "") + std::to_string(a.shape(i));
  return s + (a.ndim() == 1 ? ",)" : ")");
}

inline Rows rows_of(const py::handle& obj, std::initializer_list<py::ssize_t> tail, const char* fn, const char* arg) {
  Rows r;
  r.array = Array::ensure(obj);
  if (!r.array) throw py::type_error(std::string(fn) + ": argument '" + arg + "' is not convertible to a float array");
  const auto nt = static_cast<py::ssize_t>(tail.size());
  bool ok = r.array.ndim() >= nt;
  py::ssize_t k = 0;
  for (py::ssize_t t : tail) {
    if (!ok) break;
    ok = r.array.shape(r.array.ndim() - nt + k) == t;
    ++k;
  }
  if (!ok) {
    std::string want = "(...";
    for (py::ssize_t t : tail) want += ", " + std::to_string(t);
    throw py::value_error(std::string(fn) + ": argument '" + arg + "' must have shape " + want + "), got " +
                          shape_text(r.array));
  }
  r.stride = 1;
  for (py::ssize_t t : tail) r.stride *= t;
  r.count = 1;
  for (py::ssize_t i = 0; i < r.array.ndim() - nt; ++i) {
    r.lead.push_back(r.array.shape(i));
    r.count *= r.array.shape(i);
  }
  return r;
}

// Two inputs must have equal leading shapes, or one of them is a single item.
inline std::vector<py::ssize_t> common_lead(const Rows& a, const Rows& b, const char* fn) {
  if (a.lead == b.lead || b.lead.empty()) return a.lead;
  if (a.lead.empty()) return b.lead;
  throw py::value_error(std::string(fn) + ": leading shapes differ: " + shape_text(a.array) + " vs " +
                        shape_text(b.array));
}

inline Array make_out(const std::vector<py::ssize_t>& lead, std::initializer_list<py::ssize_t> tail) {
  std::vector<py::ssize_t> shape = lead;
  shape.insert(shape.end(), tail.begin(), tail.end());
  return Array(shape);
}

inline py::ssize_t count_of(const std::vector<py::ssize_t>& lead) {
  py::ssize_t n = 1;
  for (auto d : lead) n *= d;
  return n;
}

}  // namespace gpsins::py_rows

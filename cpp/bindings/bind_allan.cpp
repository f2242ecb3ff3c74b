#include <pybind11/numpy.h>
#include <pybind11/pybind11.h>

#include "gpsins/allan.hpp"

namespace py = pybind11;

void bind_allan(py::module_& m) {
  m.def(
      "allan_second_difference_sums",
      [](py::array_t<double, py::array::c_style | py::array::forcecast> x,
         py::array_t<std::int64_t, py::array::c_style | py::array::forcecast> m_list) {
        if (x.ndim() != 1) throw py::value_error("allan_second_difference_sums: x must be 1-D");
        if (m_list.ndim() != 1) throw py::value_error("allan_second_difference_sums: m must be 1-D");
        for (py::ssize_t k = 0; k < m_list.shape(0); ++k)
          if (m_list.at(k) < 1) throw py::value_error("allan_second_difference_sums: cluster sizes must be >= 1");
        py::array_t<double> out(m_list.shape(0));
        const double* px = x.data();
        const std::int64_t* pm = m_list.data();
        double* po = out.mutable_data();
        const auto n = static_cast<std::size_t>(x.shape(0));
        const auto count = static_cast<std::size_t>(m_list.shape(0));
        {
          py::gil_scoped_release release;
          gpsins::allan_second_difference_sums(px, n, pm, count, po);
        }
        return out;
      },
      py::arg("x"), py::arg("m"),
      "Sums of (x[i+2m] - 2 x[i+m] + x[i])^2 per cluster size m (overlapping Allan variance kernel).");
}

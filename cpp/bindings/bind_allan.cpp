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
  m.def(
      "allan_lag1_sums",
      [](py::array_t<double, py::array::c_style | py::array::forcecast> x,
         py::array_t<std::int64_t, py::array::c_style | py::array::forcecast> m_list,
         py::array_t<std::int64_t, py::array::c_style | py::array::forcecast> d_list,
         py::array_t<double, py::array::c_style | py::array::forcecast> means) {
        if (x.ndim() != 1) throw py::value_error("allan_lag1_sums: x must be 1-D");
        const py::ssize_t count = m_list.ndim() == 1 ? m_list.shape(0) : -1;
        if (count < 0 || d_list.ndim() != 1 || means.ndim() != 1 || d_list.shape(0) != count || means.shape(0) != count)
          throw py::value_error("allan_lag1_sums: m, d and mean must be 1-D of one length");
        for (py::ssize_t k = 0; k < count; ++k) {
          if (m_list.at(k) < 1) throw py::value_error("allan_lag1_sums: cluster sizes must be >= 1");
          if (d_list.at(k) < 0 || d_list.at(k) > 2) throw py::value_error("allan_lag1_sums: d must be 0, 1 or 2");
        }
        py::array_t<double> out({count, py::ssize_t{2}});
        const double* px = x.data();
        const std::int64_t* pm = m_list.data();
        const std::int64_t* pd = d_list.data();
        const double* pmean = means.data();
        double* po = out.mutable_data();
        const auto n = static_cast<std::size_t>(x.shape(0));
        {
          py::gil_scoped_release release;
          gpsins::allan_lag1_sums(px, n, pm, pd, pmean, static_cast<std::size_t>(count), po);
        }
        return out;
      },
      py::arg("x"), py::arg("m"), py::arg("d"), py::arg("mean"),
      "Lag-1 sums [sum z^2, sum z_i z_{i+1}] per m of z = (d-th differences of diff(x[::m])) - mean.");
}

#include <pybind11/pybind11.h>

namespace py = pybind11;

void bind_earth(py::module_& m);
void bind_attitude(py::module_& m);
void bind_filter(py::module_& m);
void bind_allan(py::module_& m);
void bind_gnss(py::module_& m);
void bind_smoother(py::module_& m);
void bind_text(py::module_& m);

PYBIND11_MODULE(_core, m) {
  m.doc() = "gpsins C++ core: Earth model, attitude, the integrated navigation filter.";
  bind_earth(m);
  bind_attitude(m);
  bind_filter(m);
  bind_allan(m);
  bind_gnss(m);
  bind_smoother(m);
  bind_text(m);
}

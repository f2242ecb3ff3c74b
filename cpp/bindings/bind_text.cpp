// Text writers whose per-line formatting would dominate a replay if done in Python.
#include <pybind11/numpy.h>
#include <pybind11/pybind11.h>

#include <cstdint>
#include <charconv>
#include <cstring>
#include <string>

namespace py = pybind11;

namespace {

using Ints = py::array_t<std::int64_t, py::array::c_style | py::array::forcecast>;
using Reals = py::array_t<double, py::array::c_style | py::array::forcecast>;

void require_rows(const py::array& a, py::ssize_t n, py::ssize_t cols, const char* name) {
  if (a.ndim() != 2 || a.shape(0) != n || a.shape(1) != cols)
    throw py::value_error(std::string("pos_lines: ") + name + " must have shape (n, " + std::to_string(cols) + ")");
}

// Right-justified in `width` columns, as printf's %W.Pf and %0Wd would write them; to_chars
// gives printf's digits without its format parsing, which dominated the whole line.
void put_fixed(std::string& out, double x, int width, int precision) {
  char buf[64];
  const auto r = std::to_chars(buf, buf + sizeof buf, x, std::chars_format::fixed, precision);
  const auto len = static_cast<int>(r.ptr - buf);
  if (len < width) out.append(static_cast<std::size_t>(width - len), ' ');
  out.append(buf, static_cast<std::size_t>(len));
}

void put_int(std::string& out, std::int64_t v, int width, char pad) {
  char buf[32];
  const auto r = std::to_chars(buf, buf + sizeof buf, v);
  auto len = static_cast<int>(r.ptr - buf);
  if (pad == '0' && v < 0) {  // never for the time fields; keep printf's sign-first order anyway
    out.push_back('-');
    std::memmove(buf, buf + 1, static_cast<std::size_t>(--len));
    --width;
  }
  if (len < width) out.append(static_cast<std::size_t>(width - len), pad);
  out.append(buf, static_cast<std::size_t>(len));
}

// One RTKLIB-style .pos line per row: calendar time to the millisecond, latitude and longitude
// in degrees, height, Q, satellite count, six standard deviations, age and ratio.
std::string pos_lines(const Ints& when, const Reals& llh, const Ints& q_ns, const Reals& sd, const Reals& age_ratio) {
  const py::ssize_t n = when.ndim() == 2 ? when.shape(0) : 0;
  require_rows(when, n, 7, "when (y, mo, d, h, m, s, ms)");
  require_rows(llh, n, 3, "llh");
  require_rows(q_ns, n, 2, "q_ns");
  require_rows(sd, n, 6, "sd");
  require_rows(age_ratio, n, 2, "age_ratio");
  const std::int64_t* w = when.data();
  const double* p = llh.data();
  const std::int64_t* k = q_ns.data();
  const double* s = sd.data();
  const double* a = age_ratio.data();
  std::string out;
  {
    py::gil_scoped_release release;
    out.reserve(static_cast<std::size_t>(n) * 160);
    static const char after_time[] = {'/', '/', ' ', ':', ':', '.', ' '};
    static const int time_width[] = {4, 2, 2, 2, 2, 2, 3};
    for (py::ssize_t i = 0; i < n; ++i, w += 7, p += 3, k += 2, s += 6, a += 2) {
      for (int f = 0; f < 7; ++f) {
        put_int(out, w[f], time_width[f], '0');
        out.push_back(after_time[f]);
      }
      put_fixed(out, p[0], 14, 9);
      out.push_back(' ');
      put_fixed(out, p[1], 14, 9);
      out.push_back(' ');
      put_fixed(out, p[2], 10, 4);
      out.push_back(' ');
      put_int(out, k[0], 3, ' ');
      out.push_back(' ');
      put_int(out, k[1], 3, ' ');
      for (int f = 0; f < 6; ++f) {
        out.push_back(' ');
        put_fixed(out, s[f], 8, 4);
      }
      out.push_back(' ');
      put_fixed(out, a[0], 6, 2);
      out.push_back(' ');
      put_fixed(out, a[1], 6, 1);
      out.push_back('\n');
    }
  }
  return out;
}

}  // namespace

void bind_text(py::module_& m) {
  m.def(
      "pos_lines",
      [](const Ints& when, const Reals& llh, const Ints& q_ns, const Reals& sd, const Reals& age_ratio) {
        return py::bytes(pos_lines(when, llh, q_ns, sd, age_ratio));
      },
      py::arg("when"), py::arg("llh"), py::arg("q_ns"), py::arg("sd"), py::arg("age_ratio"),
      "RTKLIB .pos lines (ASCII bytes, one per row): when (n, 7) = year, month, day, hour, minute, second,\n"
      "millisecond; llh (n, 3) = latitude, longitude (deg), height (m); q_ns (n, 2) = Q, satellites;\n"
      "sd (n, 6) = sdn, sde, sdu, sdne, sdeu, sdun (m); age_ratio (n, 2).");
}

#include <Eigen/Core>

#include "gpsins/earth.hpp"
#include "rows.hpp"

#include <pybind11/eigen.h>

namespace py = pybind11;
using namespace gpsins;
using namespace gpsins::py_rows;

namespace {

Geodetic llh_of(const double* p) { return Geodetic{p[0], p[1], p[2]}; }

// Apply a Vec3 -> Vec3 map over (..., 3) arrays.
template <class F>
Array map3(const py::handle& in, const char* fn, const char* arg, F&& f) {
  const Rows r = rows_of(in, {3}, fn, arg);
  Array out = make_out(r.lead, {3});
  double* o = out.mutable_data();
  {
    py::gil_scoped_release release;
    for (py::ssize_t i = 0; i < r.count; ++i) {
      Eigen::Map<Vec3> row_out(o + 3 * i);
      row_out = f(Eigen::Map<const Vec3>(r.row(i)));
    }
  }
  return out;
}

Geodetic single_llh(const py::handle& ref, const char* fn) {
  const Rows r = rows_of(ref, {3}, fn, "ref_llh");
  if (!r.lead.empty()) throw py::value_error(std::string(fn) + ": 'ref_llh' must be one point of shape (3,)");
  return llh_of(r.row(0));
}

}  // namespace

void bind_earth(py::module_& m) {
  auto w = m.def_submodule("wgs84", "WGS-84 constants");
  w.attr("a") = wgs84::a;
  w.attr("b") = wgs84::b;
  w.attr("f") = wgs84::f;
  w.attr("e2") = wgs84::e2;
  w.attr("gm_m3_per_s2") = wgs84::gm_m3_per_s2;
  w.attr("omega_rad_per_s") = wgs84::omega_rad_per_s;
  w.attr("gamma_equator") = wgs84::gamma_equator;
  w.attr("gamma_pole") = wgs84::gamma_pole;

  m.def(
      "geodetic_to_ecef",
      [](const py::handle& llh) {
        return map3(llh, "geodetic_to_ecef", "llh",
                    [](const Eigen::Map<const Vec3>& p) { return geodetic_to_ecef(llh_of(p.data())); });
      },
      py::arg("llh"), "(..., 3) [lat rad, lon rad, height m] -> (..., 3) ECEF m");
  m.def(
      "ecef_to_geodetic",
      [](const py::handle& xyz) {
        return map3(xyz, "ecef_to_geodetic", "xyz", [](const Eigen::Map<const Vec3>& p) {
          const Geodetic g = ecef_to_geodetic(p);
          return Vec3(g.lat_rad, g.lon_rad, g.height_m);
        });
      },
      py::arg("xyz"), "(..., 3) ECEF m -> (..., 3) [lat rad, lon rad, height m]");

  auto local = [&m](const char* name, Vec3 (*fn)(const Vec3&, const Geodetic&), const char* arg, const char* doc) {
    m.def(
        name,
        [name, fn, arg](const py::handle& v, const py::handle& ref) {
          const Geodetic g = single_llh(ref, name);
          return map3(v, name, arg, [&](const Eigen::Map<const Vec3>& p) { return fn(p, g); });
        },
        py::arg(arg), py::arg("ref_llh"), doc);
  };
  local("ecef_to_ned", &ecef_to_ned, "xyz", "(..., 3) ECEF m -> NED m relative to ref_llh");
  local("ned_to_ecef", &ned_to_ecef, "ned", "(..., 3) NED m relative to ref_llh -> ECEF m");
  local("ecef_to_enu", &ecef_to_enu, "xyz", "(..., 3) ECEF m -> ENU m relative to ref_llh");
  local("enu_to_ecef", &enu_to_ecef, "enu", "(..., 3) ENU m relative to ref_llh -> ECEF m");

  m.def(
      "rot_ned_to_ecef", [](double lat, double lon) -> Mat3 { return rot_ned_to_ecef(lat, lon); }, py::arg("lat_rad"),
      py::arg("lon_rad"), "3x3 rotation taking NED vectors to ECEF");
  m.def(
      "rot_enu_to_ecef", [](double lat, double lon) -> Mat3 { return rot_enu_to_ecef(lat, lon); }, py::arg("lat_rad"),
      py::arg("lon_rad"), "3x3 rotation taking ENU vectors to ECEF");
  m.def("normal_gravity", py::vectorize(&normal_gravity_mps2), py::arg("lat_rad"), py::arg("height_m"),
        "WGS-84 normal gravity magnitude (Somigliana + height terms), m/s^2");
  m.def(
      "normal_gravity_ecef",
      [](const py::handle& xyz) {
        return map3(xyz, "normal_gravity_ecef", "xyz",
                    [](const Eigen::Map<const Vec3>& p) { return normal_gravity_ecef(Vec3(p)); });
      },
      py::arg("xyz"), "(..., 3) ECEF m -> (..., 3) normal gravity vector in ECEF, m/s^2 (includes centrifugal)");
  m.def("meridian_radius", py::vectorize(&meridian_radius_m), py::arg("lat_rad"));
  m.def("prime_vertical_radius", py::vectorize(&prime_vertical_radius_m), py::arg("lat_rad"));
  m.def(
      "earth_rate_ecef", []() -> Vec3 { return earth_rate_ecef(); }, "Earth rotation vector in ECEF, rad/s");
  m.def(
      "skew", [](const Vec3& v) -> Mat3 { return skew(v); }, py::arg("v"), "cross-product matrix");
}

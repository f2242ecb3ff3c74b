#include "gpsins/attitude.hpp"
#include "rows.hpp"

namespace py = pybind11;
using namespace gpsins;
using namespace gpsins::py_rows;

namespace {

// Quaternions cross the boundary as (w, x, y, z); Euler angles as (yaw, pitch, roll).
Quat quat_of(const double* p) { return Quat(p[0], p[1], p[2], p[3]); }
void put_quat(const Quat& q, double* o) {
  o[0] = q.w();
  o[1] = q.x();
  o[2] = q.y();
  o[3] = q.z();
}
Euler euler_of(const double* p) { return Euler{p[0], p[1], p[2]}; }
void put_euler(const Euler& e, double* o) {
  o[0] = e.yaw_rad;
  o[1] = e.pitch_rad;
  o[2] = e.roll_rad;
}
Mat3 mat_of(const double* p) { return Eigen::Map<const Eigen::Matrix<double, 3, 3, Eigen::RowMajor>>(p); }
void put_mat(const Mat3& c, double* o) {
  Eigen::Map<Eigen::Matrix<double, 3, 3, Eigen::RowMajor>> out(o);
  out = c;
}
void put_vec(const Vec3& v, double* o) {
  Eigen::Map<Vec3> out(o);
  out = v;
}

// One input of row shape `in`, one output of row shape `out`.
template <class F>
Array map1(const py::handle& a, std::initializer_list<py::ssize_t> in, std::initializer_list<py::ssize_t> out,
           const char* fn, const char* arg, F&& f) {
  const Rows r = rows_of(a, in, fn, arg);
  Array res = make_out(r.lead, out);
  py::ssize_t step = 1;
  for (auto d : out) step *= d;
  double* o = res.mutable_data();
  {
    py::gil_scoped_release release;
    for (py::ssize_t i = 0; i < r.count; ++i) f(r.row(i), o + i * step);
  }
  return res;
}

// Two inputs, broadcasting a single item against many.
template <class F>
Array map2(const py::handle& a, std::initializer_list<py::ssize_t> in_a, const char* arg_a, const py::handle& b,
           std::initializer_list<py::ssize_t> in_b, const char* arg_b, std::initializer_list<py::ssize_t> out,
           const char* fn, F&& f) {
  const Rows ra = rows_of(a, in_a, fn, arg_a);
  const Rows rb = rows_of(b, in_b, fn, arg_b);
  const auto lead = common_lead(ra, rb, fn);
  Array res = make_out(lead, out);
  py::ssize_t step = 1;
  for (auto d : out) step *= d;
  const py::ssize_t n = count_of(lead);
  double* o = res.mutable_data();
  {
    py::gil_scoped_release release;
    for (py::ssize_t i = 0; i < n; ++i) f(ra.row(i), rb.row(i), o + i * step);
  }
  return res;
}

}  // namespace

void bind_attitude(py::module_& m) {
  m.def(
      "quat_from_rotvec",
      [](const py::handle& v) {
        return map1(v, {3}, {4}, "quat_from_rotvec", "rotvec",
                    [](const double* p, double* o) { put_quat(quat_from_rotvec(Eigen::Map<const Vec3>(p)), o); });
      },
      py::arg("rotvec"), "(..., 3) rotation vectors, rad -> (..., 4) unit quaternions (w, x, y, z)");
  m.def(
      "rotvec_from_quat",
      [](const py::handle& q) {
        return map1(q, {4}, {3}, "rotvec_from_quat", "q",
                    [](const double* p, double* o) { put_vec(rotvec_from_quat(quat_of(p)), o); });
      },
      py::arg("q"), "(..., 4) quaternions (w, x, y, z) -> (..., 3) rotation vectors, angle in [0, pi]");
  m.def(
      "dcm_from_quat",
      [](const py::handle& q) {
        return map1(q, {4}, {3, 3}, "dcm_from_quat", "q",
                    [](const double* p, double* o) { put_mat(dcm_from_quat(quat_of(p)), o); });
      },
      py::arg("q"), "(..., 4) quaternions -> (..., 3, 3) rotation matrices");
  m.def(
      "quat_from_dcm",
      [](const py::handle& c) {
        return map1(c, {3, 3}, {4}, "quat_from_dcm", "dcm",
                    [](const double* p, double* o) { put_quat(quat_from_dcm(mat_of(p)), o); });
      },
      py::arg("dcm"), "(..., 3, 3) rotation matrices -> (..., 4) quaternions with w >= 0");
  m.def(
      "dcm_from_euler",
      [](const py::handle& e) {
        return map1(e, {3}, {3, 3}, "dcm_from_euler", "ypr",
                    [](const double* p, double* o) { put_mat(dcm_from_euler(euler_of(p)), o); });
      },
      py::arg("ypr"), "(..., 3) yaw, pitch, roll in rad (intrinsic z-y-x) -> (..., 3, 3)");
  m.def(
      "euler_from_dcm",
      [](const py::handle& c) {
        return map1(c, {3, 3}, {3}, "euler_from_dcm", "dcm",
                    [](const double* p, double* o) { put_euler(euler_from_dcm(mat_of(p)), o); });
      },
      py::arg("dcm"), "(..., 3, 3) -> (..., 3) yaw, pitch, roll in rad");
  m.def(
      "quat_from_euler",
      [](const py::handle& e) {
        return map1(e, {3}, {4}, "quat_from_euler", "ypr",
                    [](const double* p, double* o) { put_quat(quat_from_euler(euler_of(p)), o); });
      },
      py::arg("ypr"), "(..., 3) yaw, pitch, roll in rad -> (..., 4) quaternions");
  m.def(
      "euler_from_quat",
      [](const py::handle& q) {
        return map1(q, {4}, {3}, "euler_from_quat", "q",
                    [](const double* p, double* o) { put_euler(euler_from_quat(quat_of(p)), o); });
      },
      py::arg("q"), "(..., 4) quaternions -> (..., 3) yaw, pitch, roll in rad");
  m.def(
      "quat_multiply",
      [](const py::handle& a, const py::handle& b) {
        return map2(a, {4}, "a", b, {4}, "b", {4}, "quat_multiply",
                    [](const double* p, const double* q, double* o) { put_quat(quat_of(p) * quat_of(q), o); });
      },
      py::arg("a"), py::arg("b"), "Hamilton product a (x) b over (..., 4) arrays");
  m.def(
      "quat_body_to_ecef",
      [](const py::handle& ypr, const py::handle& llh) {
        return map2(ypr, {3}, "ypr", llh, {3}, "llh", {4}, "quat_body_to_ecef",
                    [](const double* e, const double* g, double* o) {
                      put_quat(quat_body_to_ecef(euler_of(e), g[0], g[1]), o);
                    });
      },
      py::arg("ypr"), py::arg("llh"), "Euler angles relative to local NED at llh -> quaternion body->ECEF");
  m.def(
      "euler_from_body_to_ecef",
      [](const py::handle& q, const py::handle& llh) {
        return map2(q, {4}, "q", llh, {3}, "llh", {3}, "euler_from_body_to_ecef",
                    [](const double* p, const double* g, double* o) {
                      put_euler(euler_from_body_to_ecef(quat_of(p), g[0], g[1]), o);
                    });
      },
      py::arg("q"), py::arg("llh"), "quaternion body->ECEF -> yaw, pitch, roll relative to local NED at llh");
}

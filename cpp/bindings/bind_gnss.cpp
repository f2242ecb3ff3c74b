// pybind11 face of the GNSS models: ephemeris, satellite state, signal models, SPP.
#include <pybind11/eigen.h>
#include <pybind11/numpy.h>
#include <pybind11/pybind11.h>
#include <pybind11/stl.h>

#include <string>
#include <vector>

#include "gpsins/gnss/ephemeris.hpp"
#include "gpsins/gnss/models.hpp"
#include "gpsins/gnss/spp.hpp"

namespace py = pybind11;
using namespace gpsins;
using namespace gpsins::gnss;

namespace {

Geodetic llh_of(const Vec3& v) { return Geodetic{v(0), v(1), v(2)}; }

Klobuchar klob(const std::vector<double>& alpha, const std::vector<double>& beta) {
  Klobuchar k;
  if (alpha.size() == 4 && beta.size() == 4) {
    for (std::size_t i = 0; i < 4; ++i) {
      k.alpha[i] = alpha[i];
      k.beta[i] = beta[i];
    }
    k.valid = true;
  } else if (!alpha.empty() || !beta.empty()) {
    throw py::value_error("Klobuchar coefficients: alpha and beta must have 4 values each");
  }
  return k;
}

}  // namespace

void bind_gnss(py::module_& m) {
  auto g = m.def_submodule("gnss", "GPS models: broadcast ephemeris, signal models, single-point positioning");
  g.attr("SPEED_OF_LIGHT") = kSpeedOfLight;
  g.attr("OMEGA_EARTH") = kOmegaEarth;

  py::class_<Ephemeris> e(g, "Ephemeris", "GPS broadcast ephemeris (SI units, angles in rad)");
  e.def(py::init<>());
#define F(name) e.def_readwrite(#name, &Ephemeris::name)
  F(prn);
  F(week);
  F(toe_s);
  F(toc_s);
  F(sqrt_a);
  F(e);
  F(i0);
  F(omega0);
  F(omega);
  F(m0);
  F(delta_n);
  F(idot);
  F(omega_dot);
  F(cuc);
  F(cus);
  F(crc);
  F(crs);
  F(cic);
  F(cis);
  F(af0);
  F(af1);
  F(af2);
  F(tgd_s);
  F(iode);
  F(iodc);
  F(health);
  F(ura_index);
  F(fit_interval_long);
#undef F
  e.def("__repr__", [](const Ephemeris& x) {
    return "<Ephemeris PRN " + std::to_string(x.prn) + " week " + std::to_string(x.week) + " toe " +
           std::to_string(x.toe_s) + " IODE " + std::to_string(x.iode) + ">";
  });

  g.def(
      "decode_subframes",
      [](const std::vector<std::vector<std::uint32_t>>& words, int prn, int week_hint) {
        if (words.size() != 3) throw py::value_error("decode_subframes: need 3 subframes of 8 words");
        std::array<std::array<std::uint32_t, 8>, 3> w{};
        for (std::size_t i = 0; i < 3; ++i) {
          if (words[i].size() != 8) throw py::value_error("decode_subframes: need 3 subframes of 8 words");
          for (std::size_t j = 0; j < 8; ++j) w[i][j] = words[i][j];
        }
        Ephemeris out;
        if (!decode_subframes(w, prn, week_hint, out))
          throw py::value_error("decode_subframes: PRN " + std::to_string(prn) + ": IODE/IODC disagree or no orbit");
        return out;
      },
      py::arg("words"), py::arg("prn"), py::arg("week_hint"));

  g.def(
      "sat_state",
      [](const Ephemeris& eph, double t_abs) {
        const SatState s = sat_state(eph, t_abs);
        return py::make_tuple(Vec3(s.r_ecef_m), s.clock_s);
      },
      py::arg("eph"), py::arg("t_abs_s"), "Position (ECEF, m) and clock (s, incl. relativity, excl. TGD) at t.");
  g.def("ura_m", &ura_m);
  g.def(
      "az_el",
      [](const Vec3& rx, const Vec3& sat) {
        const AzEl a = az_el(ecef_to_geodetic(rx), rx, sat);
        return py::make_tuple(a.az_rad, a.el_rad);
      },
      py::arg("rx_ecef"), py::arg("sat_ecef"));
  g.def("sagnac_m", &sagnac_m, py::arg("sat_ecef"), py::arg("rx_ecef"));
  g.def(
      "klobuchar_m",
      [](const std::vector<double>& a, const std::vector<double>& b, const Vec3& llh, double az, double el,
         double tow) {
        return klobuchar_m(klob(a, b), llh_of(llh), AzEl{az, el}, tow);
      },
      py::arg("alpha"), py::arg("beta"), py::arg("llh"), py::arg("az_rad"), py::arg("el_rad"), py::arg("tow_s"));
  g.def(
      "saastamoinen_m",
      [](const Vec3& llh, double el, double humidity) { return saastamoinen_m(llh_of(llh), el, humidity); },
      py::arg("llh"), py::arg("el_rad"), py::arg("humidity") = 0.7);
  g.def("pseudorange_variance_m2", &pseudorange_variance_m2, py::arg("el_rad"), py::arg("ura_m"), py::arg("iono_m"));

  py::class_<EphemerisStore>(g, "EphemerisStore", "Ephemerides by PRN; select() picks the healthy one nearest t")
      .def(py::init<>())
      .def("add", &EphemerisStore::add)
      .def("select",
           [](const EphemerisStore& s, int prn, double t) -> py::object {
             const Ephemeris* found = s.select(prn, t);
             return found ? py::cast(*found) : py::none();
           })
      .def("__len__", &EphemerisStore::count);

  g.def(
      "spp",
      [](const EphemerisStore& store, double t_rx_abs, const std::vector<int>& prns, const std::vector<double>& prs,
         const std::vector<double>& alpha, const std::vector<double>& beta, double mask_deg, bool iono, bool trop,
         bool tgd, bool raim, const Vec3& guess) {
        if (prns.size() != prs.size()) throw py::value_error("spp: prns and pseudoranges differ in length");
        std::vector<PseudorangeObs> obs;
        for (std::size_t i = 0; i < prns.size(); ++i) obs.push_back({prns[i], prs[i]});
        SppOptions opt;
        opt.elevation_mask_rad = mask_deg * M_PI / 180.0;
        opt.ionosphere = iono;
        opt.troposphere = trop;
        opt.tgd = tgd;
        opt.raim = raim;
        SppResult r;
        {
          py::gil_scoped_release rel;
          r = spp(store, klob(alpha, beta), t_rx_abs, obs.data(), static_cast<int>(obs.size()), opt, guess);
        }
        py::dict d;
        d["ok"] = r.ok;
        d["r_ecef"] = Vec3(r.r_ecef_m);
        d["clock_m"] = r.clock_m;
        d["gdop"] = r.gdop;
        d["pdop"] = r.pdop;
        d["hdop"] = r.hdop;
        d["vdop"] = r.vdop;
        d["n_used"] = r.n_used;
        d["excluded_prn"] = r.excluded_prn;
        d["chi2"] = r.chi2;
        d["iterations"] = r.iterations;
        py::list sats;
        for (int i = 0; i < r.n_sats; ++i) {
          const auto& s = r.sats[static_cast<std::size_t>(i)];
          sats.append(py::dict(py::arg("prn") = s.prn, py::arg("used") = s.used, py::arg("az_rad") = s.az_rad,
                               py::arg("el_rad") = s.el_rad, py::arg("residual_m") = s.residual_m,
                               py::arg("sigma_m") = s.sigma_m));
        }
        d["sats"] = sats;
        return d;
      },
      py::arg("store"), py::arg("t_rx_abs_s"), py::arg("prns"), py::arg("pseudoranges_m"),
      py::arg("alpha") = std::vector<double>{}, py::arg("beta") = std::vector<double>{}, py::arg("mask_deg") = 15.0,
      py::arg("ionosphere") = true, py::arg("troposphere") = true, py::arg("tgd") = true, py::arg("raim") = true,
      py::arg("guess") = Vec3::Zero());
}

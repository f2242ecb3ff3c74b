#include "gpsins/gnss/spp.hpp"

#include <cmath>

#include "gpsins/chi2.hpp"

namespace gpsins::gnss {

bool sat_at_transmission(const EphemerisStore& store, int prn, double t_rx, double pr, SatState& out,
                         const Ephemeris** eph_out) {
  double t_tx = t_rx - pr / kSpeedOfLight;
  const Ephemeris* eph = store.select(prn, t_tx);
  if (!eph) return false;
  const SatState first = sat_state(*eph, t_tx);
  out = sat_state(*eph, t_tx - first.clock_s);
  if (eph_out) *eph_out = eph;
  return true;
}

namespace {

struct Solve {
  Eigen::Vector4d x = Eigen::Vector4d::Zero();
  double chi2 = 0.0;
  int n = 0, iterations = 0;
  bool converged = false;
  Eigen::Matrix4d q = Eigen::Matrix4d::Zero();  // (H^T H)^-1, ENU + clock
};

struct Prepared {
  int prn;
  SatState sat;
  const Ephemeris* eph;
  double pr;
};

Solve solve(const std::array<Prepared, kMaxSats>& p, int n, int skip, const Klobuchar& iono, double tow,
            const SppOptions& opt, const Vec3& guess, std::array<SatUse, kMaxSats>* uses) {
  Solve s;
  s.x.head<3>() = guess;
  for (int it = 0; it < 12; ++it) {
    Eigen::Matrix<double, kMaxSats, 4> h;
    Eigen::Matrix<double, kMaxSats, 1> v, w;
    int m = 0;
    const Vec3 rr = s.x.head<3>();
    const bool known = rr.norm() > 1e6;
    const Geodetic llh = known ? ecef_to_geodetic(rr) : Geodetic{};
    for (int i = 0; i < n; ++i) {
      if (i == skip) continue;
      const auto& q = p[static_cast<std::size_t>(i)];
      const Vec3 rs = q.sat.r_ecef_m;
      const double range = (rs - rr).norm() + sagnac_m(rs, rr);
      AzEl ae{0.0, M_PI / 2.0};
      double dion = 0.0, dtrp = 0.0;
      if (known) {
        ae = az_el(llh, rr, rs);
        if (ae.el_rad < opt.elevation_mask_rad) {
          if (uses) (*uses)[static_cast<std::size_t>(i)].used = false;
          continue;
        }
        if (opt.ionosphere) dion = klobuchar_m(iono, llh, ae, tow);
        if (opt.troposphere) dtrp = saastamoinen_m(llh, ae.el_rad);
      }
      const double tgd = opt.tgd ? kSpeedOfLight * q.eph->tgd_s : 0.0;
      const double model = range + s.x(3) - kSpeedOfLight * q.sat.clock_s + dion + dtrp;
      const Vec3 u = (rs - rr).normalized();
      const double var = pseudorange_variance_m2(ae.el_rad, ura_m(q.eph->ura_index), dion);
      v(m) = (q.pr - tgd) - model;
      h.row(m) << -u.transpose(), 1.0;
      w(m) = 1.0 / std::sqrt(var);
      if (uses) {
        auto& su = (*uses)[static_cast<std::size_t>(i)];
        su.prn = q.prn;
        su.used = true;
        su.el_rad = ae.el_rad;
        su.az_rad = ae.az_rad;
        su.residual_m = v(m);
        su.sigma_m = std::sqrt(var);
      }
      ++m;
    }
    s.n = m;
    if (m < 4) return s;
    const auto hw = (w.head(m).asDiagonal() * h.topRows(m)).eval();
    const Eigen::Vector4d dx =
        (hw.transpose() * hw).ldlt().solve(hw.transpose() * (w.head(m).asDiagonal() * v.head(m)));
    s.x += dx;
    s.iterations = it + 1;
    s.chi2 = (w.head(m).asDiagonal() * v.head(m)).squaredNorm();
    if (dx.head<3>().norm() < 1e-4) {
      s.converged = true;
      // Residuals and geometry at the final estimate.
      const Vec3 r = s.x.head<3>();
      const Geodetic g = ecef_to_geodetic(r);
      const Mat3 c_en = rot_enu_to_ecef(g.lat_rad, g.lon_rad);
      Eigen::Matrix<double, kMaxSats, 4> henu = h;
      for (int k = 0; k < m; ++k) henu.block<1, 3>(k, 0) = h.block<1, 3>(k, 0) * c_en;
      s.q = (henu.topRows(m).transpose() * henu.topRows(m)).inverse();
      return s;
    }
  }
  return s;
}

}  // namespace

SppResult spp(const EphemerisStore& store, const Klobuchar& iono, double t_rx, const PseudorangeObs* obs, int n,
              const SppOptions& opt, const Vec3& guess) {
  SppResult res;
  std::array<Prepared, kMaxSats> p{};
  int k = 0;
  for (int i = 0; i < n && k < kMaxSats; ++i) {
    SatState st;
    const Ephemeris* eph = nullptr;
    if (!(obs[i].pr_m > 1e7 && obs[i].pr_m < 4e7)) continue;
    if (!sat_at_transmission(store, obs[i].prn, t_rx, obs[i].pr_m, st, &eph)) continue;
    p[static_cast<std::size_t>(k++)] = Prepared{obs[i].prn, st, eph, obs[i].pr_m};
  }
  res.n_sats = k;
  const double tow = std::fmod(t_rx, kSecondsPerWeek);
  auto valid = [&](const Solve& s) {
    if (!s.converged || s.n < 4) return false;
    const int dof = s.n - 4;
    const double gdop = std::sqrt(s.q.trace());
    if (gdop > opt.max_gdop) return false;
    return dof == 0 || s.chi2 <= chi2_quantile(opt.chi2_probability, dof);
  };
  Solve best = solve(p, k, -1, iono, tow, opt, guess, &res.sats);
  bool ok = valid(best);
  if (!ok && opt.raim && best.n >= 6) {
    int best_skip = -1;
    for (int skip = 0; skip < k; ++skip) {
      Solve s = solve(p, k, skip, iono, tow, opt, best.converged ? Vec3(best.x.head<3>()) : guess, nullptr);
      if (valid(s) && (best_skip < 0 || s.chi2 < best.chi2)) {
        best = s;
        best_skip = skip;
      }
    }
    if (best_skip >= 0) {
      ok = true;
      res.excluded_prn = p[static_cast<std::size_t>(best_skip)].prn;
      solve(p, k, best_skip, iono, tow, opt, Vec3(best.x.head<3>()), &res.sats);
      res.sats[static_cast<std::size_t>(best_skip)].used = false;
    }
  }
  res.ok = ok;
  res.r_ecef_m = best.x.head<3>();
  res.clock_m = best.x(3);
  res.chi2 = best.chi2;
  res.n_used = best.n;
  res.iterations = best.iterations;
  if (best.converged) {
    res.gdop = std::sqrt(best.q.trace());
    res.pdop = std::sqrt(best.q.topLeftCorner<3, 3>().trace());
    res.hdop = std::sqrt(best.q(0, 0) + best.q(1, 1));
    res.vdop = std::sqrt(best.q(2, 2));
  }
  return res;
}

}  // namespace gpsins::gnss

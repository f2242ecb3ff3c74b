#include "gpsins/chi2.hpp"

#include <cmath>

namespace gpsins {

namespace {

// Regularised lower incomplete gamma P(a, x): power series below a + 1,
// Lentz's continued fraction for the upper tail above (Numerical Recipes 6.2).
double gamma_p(double a, double x) {
  if (x <= 0.0) return 0.0;
  const double log_prefix = a * std::log(x) - x - std::lgamma(a);
  if (x < a + 1.0) {
    double term = 1.0 / a, sum = term;
    for (int n = 1; n < 1000; ++n) {
      term *= x / (a + n);
      sum += term;
      if (std::abs(term) < std::abs(sum) * 1e-16) break;
    }
    return sum * std::exp(log_prefix);
  }
  const double tiny = 1e-300;
  double b = x + 1.0 - a, c = 1.0 / tiny, d = 1.0 / b, h = d;
  for (int i = 1; i < 1000; ++i) {
    const double an = -i * (i - a);
    b += 2.0;
    d = an * d + b;
    if (std::abs(d) < tiny) d = tiny;
    c = b + an / c;
    if (std::abs(c) < tiny) c = tiny;
    d = 1.0 / d;
    const double step = d * c;
    h *= step;
    if (std::abs(step - 1.0) < 1e-16) break;
  }
  return 1.0 - std::exp(log_prefix) * h;
}

}  // namespace

double chi2_cdf(double x, int dof) { return gamma_p(0.5 * dof, 0.5 * x); }

double chi2_quantile(double p, int dof) {
  if (!(p > 0.0 && p < 1.0) || dof < 1) return std::nan("");
  double lo = 0.0, hi = dof + 10.0 * std::sqrt(2.0 * dof) + 50.0;
  while (chi2_cdf(hi, dof) < p) hi *= 2.0;
  for (int i = 0; i < 200 && hi - lo > 1e-12 * hi; ++i) {
    const double mid = 0.5 * (lo + hi);
    (chi2_cdf(mid, dof) < p ? lo : hi) = mid;
  }
  return 0.5 * (lo + hi);
}

}  // namespace gpsins

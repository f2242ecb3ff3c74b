// Chi-square distribution for innovation gating. Evaluated when a filter is
// configured, never per sample.
#pragma once

namespace gpsins {

// P(X <= x) for X ~ chi-square with `dof` degrees of freedom.
double chi2_cdf(double x, int dof);
// The x with chi2_cdf(x, dof) = p, for 0 < p < 1 (bisection to 1e-12 relative).
double chi2_quantile(double p, int dof);

}  // namespace gpsins

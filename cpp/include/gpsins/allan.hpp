// Overlapping Allan variance kernel: the sums of squared second differences of
// a phase (integrated rate) series at cluster sizes m, one pass per m.
#pragma once

#include <cstddef>
#include <cstdint>

namespace gpsins {

// out[k] = sum_{i=0}^{n-2m-1} (x[i+2m] - 2 x[i+m] + x[i])^2 with m = m_list[k];
// 0 where n <= 2m. The overlapping Allan variance is out[k] / (2 tau^2 (n - 2m)).
void allan_second_difference_sums(const double* x, std::size_t n, const std::int64_t* m_list, std::size_t count,
                                  double* out);

// The lag-1 statistics of the noise identification (Riley and Greenhall): for each m = m_list[k],
// with p_j = x[j m] (j = 0 .. (n - 1) / m) and y the d-th differences (by repeated differencing,
// d = d_list[k] in 0..2) of p's first differences, z = y - mean_list[k]:
// out[2k] = sum z_i^2, out[2k + 1] = sum z_i z_{i+1}. One pass over x for all m (in blocks).
void allan_lag1_sums(const double* x, std::size_t n, const std::int64_t* m_list, const std::int64_t* d_list,
                     const double* mean_list, std::size_t count, double* out);

}  // namespace gpsins

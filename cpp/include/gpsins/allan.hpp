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

}  // namespace gpsins

#include "gpsins/allan.hpp"

namespace gpsins {

void allan_second_difference_sums(const double* x, std::size_t n, const std::int64_t* m_list, std::size_t count,
                                  double* out) {
  for (std::size_t k = 0; k < count; ++k) {
    const auto m = static_cast<std::size_t>(m_list[k]);
    if (m == 0 || n <= 2 * m) {
      out[k] = 0.0;
      continue;
    }
    // Four partial sums: independent chains the compiler can vectorise, and
    // less rounding than one long chain.
    double s0 = 0.0, s1 = 0.0, s2 = 0.0, s3 = 0.0;
    const std::size_t len = n - 2 * m;
    const double* a = x;
    const double* b = x + m;
    const double* c = x + 2 * m;
    std::size_t i = 0;
    for (; i + 4 <= len; i += 4) {
      const double d0 = c[i] - 2.0 * b[i] + a[i];
      const double d1 = c[i + 1] - 2.0 * b[i + 1] + a[i + 1];
      const double d2 = c[i + 2] - 2.0 * b[i + 2] + a[i + 2];
      const double d3 = c[i + 3] - 2.0 * b[i + 3] + a[i + 3];
      s0 += d0 * d0;
      s1 += d1 * d1;
      s2 += d2 * d2;
      s3 += d3 * d3;
    }
    for (; i < len; ++i) {
      const double d = c[i] - 2.0 * b[i] + a[i];
      s0 += d * d;
    }
    out[k] = (s0 + s1) + (s2 + s3);
  }
}

}  // namespace gpsins

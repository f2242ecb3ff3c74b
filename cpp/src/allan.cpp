#include "gpsins/allan.hpp"

#include <algorithm>
#include <vector>

namespace gpsins {

namespace {

// Samples of i per block: every cluster size takes its terms of one block before the next block,
// so x[i] (and x[i + m], x[i + 2m] for m up to about the block) are read from the cache, not from
// memory, once per m: the kernel was bound by memory traffic (three streams per m over the record).
constexpr std::size_t kBlock = std::size_t{1} << 16;

// Terms i0 <= i < i1 (i1 - i0 a multiple of 4) added to the four partial sums s[0..3]: term i goes
// to s[i % 4], in increasing i, exactly as one pass over the whole range adds them.
inline void add_terms(const double* a, const double* b, const double* c, std::size_t i0, std::size_t i1,
                      double* s) {
  double s0 = s[0], s1 = s[1], s2 = s[2], s3 = s[3];
  for (std::size_t i = i0; i < i1; i += 4) {
    const double d0 = c[i] - 2.0 * b[i] + a[i];
    const double d1 = c[i + 1] - 2.0 * b[i + 1] + a[i + 1];
    const double d2 = c[i + 2] - 2.0 * b[i + 2] + a[i + 2];
    const double d3 = c[i + 3] - 2.0 * b[i + 3] + a[i + 3];
    s0 += d0 * d0;
    s1 += d1 * d1;
    s2 += d2 * d2;
    s3 += d3 * d3;
  }
  s[0] = s0;
  s[1] = s1;
  s[2] = s2;
  s[3] = s3;
}

}  // namespace

void allan_second_difference_sums(const double* x, std::size_t n, const std::int64_t* m_list, std::size_t count,
                                  double* out) {
  // Four partial sums per m: independent chains the compiler can vectorise, and less rounding than
  // one long chain. Each sum gets its terms in the same order whatever the blocking, so the result
  // is the same to the last bit as one pass per m.
  std::vector<double> sums(4 * count, 0.0);
  std::vector<std::size_t> whole(count, 0);  // terms in groups of four: n - 2m rounded down to 4
  std::size_t longest = 0;
  for (std::size_t k = 0; k < count; ++k) {
    const auto m = static_cast<std::size_t>(m_list[k]);
    if (m == 0 || n <= 2 * m) continue;
    whole[k] = (n - 2 * m) / 4 * 4;
    longest = std::max(longest, whole[k]);
  }
  for (std::size_t i0 = 0; i0 < longest; i0 += kBlock) {
    for (std::size_t k = 0; k < count; ++k) {
      const std::size_t i1 = std::min(i0 + kBlock, whole[k]);
      if (i1 <= i0) continue;
      const auto m = static_cast<std::size_t>(m_list[k]);
      add_terms(x, x + m, x + 2 * m, i0, i1, &sums[4 * k]);
    }
  }
  for (std::size_t k = 0; k < count; ++k) {
    const auto m = static_cast<std::size_t>(m_list[k]);
    if (m == 0 || n <= 2 * m) {
      out[k] = 0.0;
      continue;
    }
    double* s = &sums[4 * k];
    for (std::size_t i = whole[k]; i < n - 2 * m; ++i) {  // the last 0-3 terms
      const double d = x[i + 2 * m] - 2.0 * x[i + m] + x[i];
      s[0] += d * d;
    }
    out[k] = (s[0] + s[1]) + (s[2] + s[3]);
  }
}

}  // namespace gpsins

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
inline void add_terms(const double* a, const double* b, const double* c, std::size_t i0, std::size_t i1, double* s) {
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

void allan_lag1_sums(const double* x, std::size_t n, const std::int64_t* m_list, const std::int64_t* d_list,
                     const double* mean_list, std::size_t count, double* out) {
  // Per m: the next point j, how many points were seen, the last point, first and second
  // differences (what the next value needs), the last z and the sums. The points of all m are taken
  // block by block of x, so that the record is read once, not once per small m.
  struct State {
    std::size_t m = 1, d = 0, j = 0, seen = 0;
    double p = 0.0, y0 = 0.0, y1 = 0.0, z = 0.0, s11 = 0.0, s12 = 0.0;
  };
  std::vector<State> st(count);
  for (std::size_t k = 0; k < count; ++k) {
    st[k].m = static_cast<std::size_t>(std::max<std::int64_t>(m_list[k], 1));
    st[k].d = static_cast<std::size_t>(std::min<std::int64_t>(std::max<std::int64_t>(d_list[k], 0), 2));
  }
  for (std::size_t i0 = 0; i0 < n; i0 += kBlock) {
    const std::size_t i1 = std::min(n, i0 + kBlock);
    for (std::size_t k = 0; k < count; ++k) {
      State& s = st[k];
      // Locals: the compiler cannot keep fields of a struct that x might alias in registers.
      const std::size_t m = s.m, d = s.d, first_value = d + 2;  // the first value comes with point d + 2
      const double mean = mean_list[k];
      std::size_t j = s.j, seen = s.seen;
      double p_last = s.p, y0_last = s.y0, y1_last = s.y1, z_last = s.z, s11 = s.s11, s12 = s.s12;
      for (; j * m < i1; ++j) {
        const double p = x[j * m];
        ++seen;
        const double y0 = p - p_last;
        const double y1 = y0 - y0_last;
        const double y = d == 0 ? y0 : d == 1 ? y1 : y1 - y1_last;
        p_last = p;
        y0_last = y0;
        y1_last = y1;
        if (seen < first_value) continue;  // not yet a value (the differences above are of nothing)
        const double z = y - mean;
        s11 += z * z;
        if (seen > first_value) s12 += z_last * z;
        z_last = z;
      }
      s.j = j;
      s.seen = seen;
      s.p = p_last;
      s.y0 = y0_last;
      s.y1 = y1_last;
      s.z = z_last;
      s.s11 = s11;
      s.s12 = s12;
    }
  }
  for (std::size_t k = 0; k < count; ++k) {
    out[2 * k] = st[k].s11;
    out[2 * k + 1] = st[k].s12;
  }
}

}  // namespace gpsins

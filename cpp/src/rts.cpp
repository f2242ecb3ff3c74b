#include "gpsins/rts.hpp"

#include <cstring>
#include <stdexcept>

namespace gpsins {

// Each record: payload doubles, then one double holding kind * 2^32 + length
// (exact in a double for any length below 2^20 and kinds below 2^20).
namespace {
double trailer(std::int32_t kind, int n) { return static_cast<double>(kind) * 4294967296.0 + n; }
void read_trailer(double t, std::int32_t& kind, int& n) {
  kind = static_cast<std::int32_t>(t / 4294967296.0);
  n = static_cast<int>(t - static_cast<double>(kind) * 4294967296.0);
}
}  // namespace

SmootherTape::SmootherTape(std::size_t chunk_bytes) : chunk_bytes_(std::max<std::size_t>(chunk_bytes, 4096)) {
  buf_.reserve(chunk_bytes_ / sizeof(double) + 4096);
}

SmootherTape::~SmootherTape() {
  if (file_) std::fclose(file_);
}

double* SmootherTape::append(Kind kind, int n) {
  if ((buf_.size() + static_cast<std::size_t>(n) + 1) * sizeof(double) > chunk_bytes_ && !buf_.empty()) spill();
  const std::size_t at = buf_.size();
  buf_.resize(at + static_cast<std::size_t>(n) + 1);
  buf_.back() = trailer(kind, n);
  bytes_ += (static_cast<std::size_t>(n) + 1) * sizeof(double);
  return buf_.data() + at;
}

void SmootherTape::spill() {
  if (!file_) {
    file_ = std::tmpfile();
    if (!file_) throw std::runtime_error("smoother: cannot create a temporary file to spill the forward pass to");
  }
  if (std::fseek(file_, file_end_, SEEK_SET) != 0 ||
      std::fwrite(buf_.data(), sizeof(double), buf_.size(), file_) != buf_.size())
    throw std::runtime_error("smoother: writing the forward pass to its temporary file failed (disk full?)");
  chunks_.push_back(Chunk{file_end_, buf_.size()});
  file_end_ += static_cast<long>(buf_.size() * sizeof(double));
  spilled_ += buf_.size() * sizeof(double);
  buf_.clear();
}

void SmootherTape::for_each_backward(const std::function<void(Kind, const double*, int)>& f) {
  auto walk = [&](const std::vector<double>& b) {
    std::size_t end = b.size();
    while (end > 0) {
      std::int32_t kind;
      int n;
      read_trailer(b[end - 1], kind, n);
      const std::size_t start = end - 1 - static_cast<std::size_t>(n);
      f(static_cast<Kind>(kind), b.data() + start, n);
      end = start;
    }
  };
  walk(buf_);
  std::vector<double> chunk;
  for (auto it = chunks_.rbegin(); it != chunks_.rend(); ++it) {
    chunk.resize(it->n);
    if (std::fseek(file_, it->offset, SEEK_SET) != 0 || std::fread(chunk.data(), sizeof(double), it->n, file_) != it->n)
      throw std::runtime_error("smoother: reading the forward pass back from its temporary file failed");
    walk(chunk);
  }
}

}  // namespace gpsins

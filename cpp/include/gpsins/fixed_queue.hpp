// A first-in first-out queue of at most N values in a fixed ring: what the
// filter holds of each input (fixes, pseudorange epochs, attitudes) until the
// IMU reaches its time. No allocation; pushing onto a full queue is the
// caller's error (the filter takes the oldest out first).
#pragma once

#include <array>
#include <cstddef>

namespace gpsins {

template <class T, int N>
class FixedQueue {
  static_assert(N > 0, "a queue holds at least one value");

 public:
  static constexpr int kCapacity = N;

  bool empty() const { return count_ == 0; }
  bool full() const { return count_ == N; }
  int size() const { return count_; }
  // The oldest value; the queue must not be empty.
  const T& front() const { return items_[static_cast<std::size_t>(head_)]; }
  void push_back(const T& v) {
    items_[static_cast<std::size_t>((head_ + count_) % N)] = v;
    ++count_;
  }
  // Takes the oldest value out; the queue must not be empty.
  T pop_front() {
    const T v = items_[static_cast<std::size_t>(head_)];
    head_ = (head_ + 1) % N;
    --count_;
    return v;
  }
  void clear() {
    head_ = 0;
    count_ = 0;
  }

 private:
  std::array<T, N> items_{};
  int head_ = 0;  // the oldest value's index
  int count_ = 0;
};

}  // namespace gpsins

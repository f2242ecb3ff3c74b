#include <doctest/doctest.h>

#include "gpsins/fixed_queue.hpp"

using gpsins::FixedQueue;

TEST_CASE("FixedQueue: first in, first out, across the ring's end") {
  FixedQueue<int, 3> q;
  CHECK(q.empty());
  q.push_back(1);
  q.push_back(2);
  q.push_back(3);
  CHECK(q.full());
  CHECK(q.size() == 3);
  CHECK(q.pop_front() == 1);
  q.push_back(4);  // wraps to the ring's first slot
  CHECK(q.full());
  CHECK(q.front() == 2);
  CHECK(q.pop_front() == 2);
  CHECK(q.pop_front() == 3);
  CHECK(q.pop_front() == 4);
  CHECK(q.empty());
  for (int i = 0; i < 10; ++i) {  // many times round
    q.push_back(i);
    CHECK(q.front() == i);
    CHECK(q.pop_front() == i);
  }
  CHECK(q.empty());
}

TEST_CASE("FixedQueue: a full queue keeps the newest when the oldest is taken out first") {
  FixedQueue<int, 2> q;
  for (int i = 0; i < 5; ++i) {
    if (q.full()) q.pop_front();
    q.push_back(i);
  }
  CHECK(q.size() == 2);
  CHECK(q.pop_front() == 3);
  CHECK(q.pop_front() == 4);
  q.push_back(7);
  q.clear();
  CHECK(q.empty());
  q.push_back(8);
  CHECK(q.front() == 8);
}

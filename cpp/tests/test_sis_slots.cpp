#include <doctest/doctest.h>

#include "gpsins/sis_slots.hpp"

using gpsins::SisSlots;
using Outcome = SisSlots<2>::Outcome;

TEST_CASE("SisSlots: a satellite keeps its slot, a new ephemeris issue restarts it") {
  SisSlots<2> s;
  s.begin_epoch(1.0);
  const auto a = s.assign(5, 10, 1.0);
  CHECK(a.outcome == Outcome::Taken);
  CHECK(s.prn(a.slot) == 5);
  s.begin_epoch(2.0);
  CHECK(s.assign(5, 10, 2.0).outcome == Outcome::Kept);
  s.begin_epoch(3.0);
  const auto b = s.assign(5, 11, 3.0);
  CHECK(b.outcome == Outcome::Restarted);
  CHECK(b.slot == a.slot);
}

TEST_CASE("SisSlots: satellites ranged at this epoch or the one before are not robbed") {
  SisSlots<2> s;
  s.begin_epoch(1.0);
  CHECK(s.assign(1, 0, 1.0).outcome == Outcome::Taken);
  CHECK(s.assign(2, 0, 1.0).outcome == Outcome::Taken);
  CHECK(s.assign(3, 0, 1.0).outcome == Outcome::None);  // both ranged now
  s.begin_epoch(2.0);
  CHECK(s.assign(1, 0, 2.0).outcome == Outcome::Kept);
  CHECK(s.assign(3, 0, 2.0).outcome == Outcome::None);  // 2 was ranged the epoch before
  s.begin_epoch(3.0);
  const auto c = s.assign(3, 0, 3.0);  // 2 last ranged two epochs ago: its slot is taken
  CHECK(c.outcome == Outcome::Taken);
  CHECK(s.prn(c.slot) == 3);
  s.begin_epoch(4.0);
  s.begin_epoch(5.0);
  s.begin_epoch(4.5);                  // not later: ignored
  const auto d = s.assign(2, 0, 5.0);  // the one used longest ago goes: satellite 1's (t = 2)
  CHECK(d.outcome == Outcome::Taken);
  CHECK(s.prn(d.slot) == 2);
  CHECK(s.prn(c.slot) == 3);
  s.free_all();
  CHECK(s.prn(0) == -1);
  CHECK(s.prn(1) == -1);
}

// Which satellite's signal-in-space error (its broadcast orbit and clock error)
// each of the tight filter's N slot states carries (pseudorange_sis_states).
//
// A satellite keeps its slot while it is away (its broadcast error is still the
// same when it returns); a new ephemeris issue restarts it (a new upload, a new
// error). A satellite without one takes a free slot, else the one used longest
// ago, never one whose satellite was ranged at this epoch or the one before: a
// tracked satellite is not robbed (each theft would restart an error the filter
// has learnt, and the robbed one would rob the next), a satellite gone for an
// epoch may be. The filter restarts a slot's state when assign says so.
#pragma once

#include <array>
#include <cstddef>
#include <limits>

namespace gpsins {

template <int N>
class SisSlots {
 public:
  enum class Outcome {
    Kept,       // the satellite's own slot, same ephemeris issue
    Restarted,  // its own slot, a new ephemeris issue: the error restarts
    Taken,      // a slot new to it: the error restarts
    None,       // none free
  };
  struct Assignment {
    int slot = -1;
    Outcome outcome = Outcome::None;
  };

  SisSlots() { free_all(); }

  // Every slot free (the epochs seen are kept).
  void free_all() {
    prn_.fill(-1);
    iode_.fill(-1);
    used_t_.fill(-std::numeric_limits<double>::infinity());
  }
  // A ranged epoch at t (slots are protected for it and the one before).
  void begin_epoch(double t) {
    if (t > epoch_t_) {
      prev_epoch_t_ = epoch_t_;
      epoch_t_ = t;
    }
  }
  // The slot for satellite prn's range at t with ephemeris issue iode.
  Assignment assign(int prn, int iode, double t) {
    int pick = -1;
    for (int s = 0; s < N; ++s) {
      const auto k = static_cast<std::size_t>(s);
      if (prn_[k] == prn) {
        const Outcome o = iode_[k] != iode ? Outcome::Restarted : Outcome::Kept;
        iode_[k] = iode;
        used_t_[k] = t;
        return {s, o};
      }
      if (used_t_[k] < prev_epoch_t_ || prn_[k] < 0)
        if (pick < 0 || used_t_[k] < used_t_[static_cast<std::size_t>(pick)]) pick = s;
    }
    if (pick < 0) return {};
    const auto k = static_cast<std::size_t>(pick);
    prn_[k] = prn;
    iode_[k] = iode;
    used_t_[k] = t;
    return {pick, Outcome::Taken};
  }
  int prn(int slot) const { return prn_[static_cast<std::size_t>(slot)]; }

 private:
  std::array<int, N> prn_{}, iode_{};
  std::array<double, N> used_t_{};
  double epoch_t_ = -std::numeric_limits<double>::infinity();       // the ranged epoch slots are for
  double prev_epoch_t_ = -std::numeric_limits<double>::infinity();  // and the one before it
};

}  // namespace gpsins

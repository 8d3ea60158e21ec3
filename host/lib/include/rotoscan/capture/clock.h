// The host clock that cameras, boards and the scan share: microseconds on CLOCK_MONOTONIC for real
// hardware, or a virtual clock for the simulated rig (the sim board and the virtual camera), where waiting
// runs the simulated world forward instead of sleeping, so a 1,200-step scan takes seconds, not minutes.
//
// Every time in the capture module (frame exposure starts, board changes, deadlines) is on this clock.
// Waiting is only ever for a computed instant (a frame's end, a board deadline): never a fixed sleep.
#pragma once

#include <cstdint>
#include <functional>
#include <memory>
#include <mutex>
#include <vector>

namespace rotoscan::capture {

class Clock {
 public:
  virtual ~Clock() = default;
  // Now, in microseconds. The real clock is CLOCK_MONOTONIC; a virtual one starts at 0.
  virtual int64_t NowUs() = 0;
  // Returns once NowUs() >= `us` (at once if it already is). Real: sleeps until that absolute instant.
  // Virtual: advances the time to `us`, running every listener (the simulated board) on the way.
  virtual void WaitUntilUs(int64_t us) = 0;
  // True for a virtual clock.
  virtual bool is_virtual() const = 0;
};

// CLOCK_MONOTONIC in microseconds (the clock V4L2 and libusb-side host stamps use).
int64_t MonotonicNowUs();

// The process's real clock.
std::shared_ptr<Clock> MakeRealClock();

// Virtual time: moves only in WaitUntilUs()/Advance(). Listeners are called with the new time each time it
// moves (in order of registration, from the thread that moved it), and may not move it themselves.
// Thread-safe.
class VirtualClock : public Clock {
 public:
  using Listener = std::function<void(int64_t now_us)>;
  int64_t NowUs() override;
  void WaitUntilUs(int64_t us) override;
  bool is_virtual() const override { return true; }
  void Advance(int64_t us) { WaitUntilUs(NowUs() + us); }
  // Returns an id for RemoveListener.
  int AddListener(Listener listener);
  void RemoveListener(int id);

 private:
  std::recursive_mutex mutex_;
  int64_t now_us_ = 0;
  int next_id_ = 0;
  std::vector<std::pair<int, Listener>> listeners_;
};

}  // namespace rotoscan::capture

#include "rotoscan/capture/clock.h"

#include <algorithm>
#include <cerrno>
#include <ctime>

namespace rotoscan::capture {

int64_t MonotonicNowUs() {
  timespec ts{};
  clock_gettime(CLOCK_MONOTONIC, &ts);
  return static_cast<int64_t>(ts.tv_sec) * 1'000'000 + ts.tv_nsec / 1000;
}

namespace {

class RealClock : public Clock {
 public:
  int64_t NowUs() override { return MonotonicNowUs(); }
  void WaitUntilUs(int64_t us) override {
    timespec ts{};
    ts.tv_sec = static_cast<time_t>(us / 1'000'000);
    ts.tv_nsec = static_cast<long>((us % 1'000'000) * 1000);
    while (clock_nanosleep(CLOCK_MONOTONIC, TIMER_ABSTIME, &ts, nullptr) == EINTR) {
    }
  }
  bool is_virtual() const override { return false; }
};

}  // namespace

std::shared_ptr<Clock> MakeRealClock() { return std::make_shared<RealClock>(); }

int64_t VirtualClock::NowUs() {
  std::lock_guard<std::recursive_mutex> lock(mutex_);
  return now_us_;
}

void VirtualClock::WaitUntilUs(int64_t us) {
  std::lock_guard<std::recursive_mutex> lock(mutex_);
  if (us <= now_us_) return;
  now_us_ = us;
  for (auto& [id, listener] : listeners_) listener(now_us_);
}

int VirtualClock::AddListener(Listener listener) {
  std::lock_guard<std::recursive_mutex> lock(mutex_);
  listeners_.emplace_back(next_id_, std::move(listener));
  return next_id_++;
}

void VirtualClock::RemoveListener(int id) {
  std::lock_guard<std::recursive_mutex> lock(mutex_);
  listeners_.erase(std::remove_if(listeners_.begin(), listeners_.end(),
                                  [id](const auto& entry) { return entry.first == id; }),
                   listeners_.end());
}

}  // namespace rotoscan::capture

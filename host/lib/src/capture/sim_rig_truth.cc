#include "sim_rig_truth.h"

#include <algorithm>
#include <iterator>

#include "sim_port.h"

namespace rotoscan::capture::internal {

void SimRigTruth::LaserFractions(int64_t from_us, int64_t to_us, double* left, double* right) {
  Update();
  *left = Fraction(0, from_us, to_us);
  *right = Fraction(1, from_us, to_us);
}

double SimRigTruth::TableAngleAt(int64_t us) {
  Update();
  const auto it = std::upper_bound(step_times_.begin(), step_times_.end(), us);
  const auto index = static_cast<size_t>(it - step_times_.begin());
  return (index == 0 ? 0 : step_positions_[index - 1]) * radians_per_step_;
}

std::vector<int64_t> SimRigTruth::TriggerEdges(int64_t after_us, int64_t until_us) {
  Update();
  std::vector<int64_t> out;
  auto it = std::upper_bound(triggers_.begin(), triggers_.end(), after_us);
  for (; it != triggers_.end() && *it <= until_us; ++it) out.push_back(*it);
  return out;
}

std::vector<int64_t> SimRigTruth::LaserSwitches(int64_t from_us, int64_t to_us) {
  Update();
  std::vector<int64_t> out;
  for (int laser = 0; laser < 2; ++laser) {
    for (const auto& [t, level] : laser_[laser]) {
      if (t >= from_us && t <= to_us) out.push_back(t);
    }
  }
  std::sort(out.begin(), out.end());
  return out;
}

bool SimRigTruth::LaserAt(int laser, int64_t us) {
  Update();
  const auto& timeline = laser_[laser];
  auto it = std::upper_bound(timeline.begin(), timeline.end(), std::make_pair(us, true));
  return it != timeline.begin() && std::prev(it)->second;
}

void SimRigTruth::Update() {
  if (locked_) {
    locked_([this] { ReadLog(); });
  } else {
    ReadLog();
  }
}

void SimRigTruth::ReadLog() {
  const size_t count = sim_edge_count();
  const sim_edge_t* edges = sim_edges();
  for (; seen_ < count; ++seen_) {
    const sim_edge_t& e = edges[seen_];
    const int64_t t = static_cast<int64_t>(e.time_us) + offset_;
    switch (e.pin) {
      case SIM_PIN_LASER_LEFT: AddEdge(t, Pin::kLaserLeft, e.level != 0); break;
      case SIM_PIN_LASER_RIGHT: AddEdge(t, Pin::kLaserRight, e.level != 0); break;
      case SIM_PIN_DIR: AddEdge(t, Pin::kDir, e.level != 0); break;
      case SIM_PIN_STEP: AddEdge(t, Pin::kStep, e.level != 0); break;
      case SIM_PIN_TRIGGER: AddEdge(t, Pin::kTrigger, e.level != 0); break;
      default: break;
    }
  }
}

void SimRigTruth::AddEdge(int64_t t, Pin pin, bool level) {
  switch (pin) {
    case Pin::kLaserLeft: laser_[0].emplace_back(t, level); break;
    case Pin::kLaserRight: laser_[1].emplace_back(t, level); break;
    case Pin::kDir: dir_ = level ? 1 : -1; break;
    case Pin::kStep:
      if (level) {
        position_ += dir_;
        step_times_.push_back(t);
        step_positions_.push_back(position_);
      }
      break;
    case Pin::kTrigger:
      if (level) triggers_.push_back(t);
      break;
  }
}

// Fraction of [from, to) during which laser `i` was on.
double SimRigTruth::Fraction(int i, int64_t from, int64_t to) const {
  if (to <= from) return 0.0;
  const auto& timeline = laser_[i];
  auto it = std::upper_bound(timeline.begin(), timeline.end(), std::make_pair(from, true));
  bool level = it == timeline.begin() ? false : std::prev(it)->second;
  int64_t t = from;
  int64_t on = 0;
  for (; it != timeline.end() && it->first < to; ++it) {
    if (level) on += it->first - t;
    t = it->first;
    level = it->second;
  }
  if (level) on += to - t;
  return static_cast<double>(on) / static_cast<double>(to - from);
}

}  // namespace rotoscan::capture::internal

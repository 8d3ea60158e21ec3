// The rig's truth for the virtual camera from the emulated chip's pin edges (F411Emu::edges(): the laser
// pins, STEP and DIR, the trigger pin) on the host's clock: the flashed image on the emulated STM32F411
// behind the mocked USB bus (MockUsbBoard with Options::real_time) with its time following the host's
// CLOCK_MONOTONIC. The emulated cycle `c` is host time zero_host_us + (c - zero_cycle) / (SYSCLK in MHz),
// zero_cycle being the emulator's cycle count when the mock started its clock (device_zero_host_us): the
// physical time of each edge, not the host's estimate of it (the client's clock fit, which the scan under
// test uses).
//
// The emulator runs in the mock's clock thread, a tick (100 us) or more behind the host: each query first
// waits (at most 1 s) until the emulated time has reached the end of what it asks about, so that a frame
// is never rendered from a log that stops short of its exposure.
#pragma once

#include <chrono>
#include <cstdint>
#include <thread>
#include <vector>

#include "capture/sim_rig_truth.h"
#include "emu_board.h"
#include "mock_usb_board.h"

namespace rotoscan::device::testing {

class EmuRigTruth : public capture::internal::SimRigTruth {
 public:
  EmuRigTruth(MockUsbBoard* usb, EmuBoard* board, uint64_t zero_cycle, double radians_per_step)
      : SimRigTruth(0, radians_per_step, [usb](const std::function<void()>& f) { usb->WithBoardLocked(f); }),
        usb_(usb),
        board_(board),
        zero_cycle_(zero_cycle),
        zero_host_us_(usb->device_zero_host_us()),
        cycles_per_us_(board->emu().sysclk_hz() / 1'000'000u) {}

  // Host time (us) of an emulated cycle.
  int64_t HostUs(uint64_t cycle) const {
    return zero_host_us_ + static_cast<int64_t>((cycle - zero_cycle_ + cycles_per_us_ / 2) / cycles_per_us_);
  }

  void LaserFractions(int64_t from_us, int64_t to_us, double* left, double* right) override {
    WaitFor(to_us);
    SimRigTruth::LaserFractions(from_us, to_us, left, right);
  }
  double TableAngleAt(int64_t us) override {
    WaitFor(us);
    return SimRigTruth::TableAngleAt(us);
  }
  std::vector<int64_t> TriggerEdges(int64_t after_us, int64_t until_us) override {
    WaitFor(until_us);
    return SimRigTruth::TriggerEdges(after_us, until_us);
  }
  std::vector<int64_t> LaserSwitches(int64_t from_us, int64_t to_us) override {
    WaitFor(to_us);
    return SimRigTruth::LaserSwitches(from_us, to_us);
  }
  bool LaserAt(int laser, int64_t us) {
    WaitFor(us);
    return SimRigTruth::LaserAt(laser, us);
  }
  // The longest a query waited for the emulator (us): how far it ran behind the host.
  int64_t max_wait_us() const { return max_wait_us_; }

 protected:
  // Runs with the board held.
  void ReadLog() override {
    const std::vector<fw_emu::PinEdge>& edges = board_->emu().edges();
    for (; seen_ < edges.size(); ++seen_) {
      const fw_emu::PinEdge& e = edges[seen_];
      if (e.cycle < zero_cycle_) continue;  // before the mock's clock: enumeration, no scan yet
      const int64_t t = HostUs(e.cycle);
      switch (EmuRigPin(e)) {
        case RigPin::kLaserLeft: AddEdge(t, Pin::kLaserLeft, e.level); break;
        case RigPin::kLaserRight: AddEdge(t, Pin::kLaserRight, e.level); break;
        case RigPin::kDir: AddEdge(t, Pin::kDir, e.level); break;
        case RigPin::kStep: AddEdge(t, Pin::kStep, e.level); break;
        case RigPin::kTrigger: AddEdge(t, Pin::kTrigger, e.level); break;
        case RigPin::kOther: break;
      }
    }
  }

 private:
  void WaitFor(int64_t host_us) {
    const auto start = std::chrono::steady_clock::now();
    while (true) {
      uint64_t cycle = 0;
      usb_->WithBoardLocked([&] { cycle = board_->emu().cycles(); });
      const auto waited = std::chrono::steady_clock::now() - start;
      if (HostUs(cycle) >= host_us || waited > std::chrono::seconds(1)) {
        max_wait_us_ = std::max<int64_t>(
            max_wait_us_, std::chrono::duration_cast<std::chrono::microseconds>(waited).count());
        return;
      }
      std::this_thread::sleep_for(std::chrono::microseconds(200));
    }
  }

  MockUsbBoard* usb_;
  EmuBoard* board_;
  uint64_t zero_cycle_;
  int64_t zero_host_us_;
  uint64_t cycles_per_us_;
  size_t seen_ = 0;
  int64_t max_wait_us_ = 0;
};

}  // namespace rotoscan::device::testing

// The parts the device hardware-in-the-loop tests share (hil_sim_test: the firmware core built for the host;
// hil_emu_test and emu_scan_test: the flashed image on the emulated chip): the scan program and motion
// config they run, the decoding of a board's pin-edge log into the truth at each trigger edge, the check of
// every TRIGGER_EVENT against that truth (hil_common.cc), and the scan loop over a mocked bus with faults
// injected (hil_scan.cc).
#pragma once

#include <chrono>
#include <cstdint>
#include <functional>
#include <map>
#include <optional>
#include <string>
#include <utility>
#include <vector>

#include "rotoscan/device/client.h"

namespace rotoscan::device::testing {

class MockUsbBoard;

constexpr int32_t kHilStepsPerMove = 16;

// `steps` steps of 16 motor steps, four shots each: left, right, lasers off, natural (longer).
ScanProgram HilProgram(uint32_t steps);
MotionConfig HilConfig(uint32_t laser_timeout_ms);

// The pins of a board's log that make the rig's truth.
enum class RigPin { kLaserLeft, kLaserRight, kDir, kStep, kTrigger, kOther };

// What a pin log says at one trigger rising edge: its time (in the log's own unit: device microseconds or
// TIM2 counts less the boot count), the laser pins' levels (bit 0 left, bit 1 right) and the table position
// counted from the STEP pulses and DIR.
struct EdgeTruth {
  uint64_t time;
  uint8_t lasers;
  int32_t position;
};

// Feed it a log's edges in order; it keeps the trigger edges' truth and counts the STEP pulses.
class PinLogDecoder {
 public:
  void Add(uint64_t time, RigPin pin, bool level);
  const std::vector<EdgeTruth>& triggers() const { return triggers_; }
  int step_pulses() const { return step_pulses_; }

 private:
  std::vector<EdgeTruth> triggers_;
  uint8_t lasers_ = 0;
  int dir_ = 1;
  int32_t position_ = 0;
  int step_pulses_ = 0;
};

// The accepted TRIGGER_EVENT of every (step, shot): the one of the latest run.
using HilShots = std::map<std::pair<uint32_t, uint8_t>, TriggerEvent>;

struct HilScanResult {
  HilShots shots;
  int triggers_seen = 0;
  bool safety_seen = false;  // a STATUS said the laser-safety timeout stopped the program
  std::optional<uint32_t> resumed_at;
};

// Faults armed on the mocked endpoint once so many TRIGGER_EVENTs have arrived (0: not armed).
struct HilFaults {
  int drop_at = 0, corrupt_at = 0, duplicate_at = 0, unplug_at = 0;
  // Called at `unplug_at` triggers: unplugs and arranges the re-plug (the test's own way).
  std::function<void()> unplug;
};

// Loads `program` and runs it to the end through `client`: pings every 20 ms (the board's laser-safety
// keep-alive), injects the faults, resumes after a re-plug or a laser-safety stop (a host stalled by a
// loaded machine can miss its keep-alive too). `board_error` (may be null) adds the board's own error to a
// failure. Gives up after `give_up` of real time, only against a hang.
HilScanResult RunHilScan(Client& client, MockUsbBoard& usb, const MotionConfig& config,
                         const ScanProgram& program, const HilFaults& faults, std::chrono::seconds give_up,
                         const std::function<std::string()>& board_error = nullptr);

// Every (step, shot) of `program` arrived once, each at a trigger edge of the log (by time), with the shot's
// lasers lit and the table at its step; the STEP pulses are exactly the program's. Without a laser-safety
// stop the events' sequence numbers are the edges' indices too; with one, a shot aborted between its edge and
// the end of its exposure made an edge but no event, so they are not, and at most two edges lack an event.
void CheckHilShots(const HilScanResult& scan, const ScanProgram& program, const std::vector<EdgeTruth>& edges,
                   int step_pulses);

}  // namespace rotoscan::device::testing

// RunHilScan (hil_common.h): the scan loop over the mocked bus, apart so that the tests without umockdev
// (emu_scan_test) can use the rest of hil_common.
#include <gtest/gtest.h>

#include "hil_common.h"
#include "mock_usb_board.h"

namespace rotoscan::device::testing {

HilScanResult RunHilScan(Client& client, MockUsbBoard& usb, const MotionConfig& config,
                         const ScanProgram& program, const HilFaults& faults, std::chrono::seconds give_up,
                         const std::function<std::string()>& board_error) {
  auto board = [&] { return board_error ? " / " + board_error() : std::string(); };
  HilScanResult r;
  EXPECT_TRUE(client.SetConfig(config).ok()) << board();
  EXPECT_TRUE(client.EnableMotor(true).ok()) << board();
  EXPECT_TRUE(client.LoadProgram(program).ok()) << board();
  EXPECT_TRUE(client.Start(0).ok()) << board();
  auto last_ping = std::chrono::steady_clock::now();
  int reconnects_handled = 0;
  bool unplugged = false, resume = false;
  const auto end = std::chrono::steady_clock::now() + give_up;
  while (std::chrono::steady_clock::now() < end) {
    const int seen = r.triggers_seen;
    const MockUsbBoard::Counters n = usb.counters();
    if (faults.drop_at > 0 && seen >= faults.drop_at && n.dropped == 0) usb.DropNextOut();
    if (faults.corrupt_at > 0 && seen >= faults.corrupt_at && n.corrupted == 0) usb.CorruptNextOut();
    if (faults.duplicate_at > 0 && seen >= faults.duplicate_at && n.duplicated == 0) usb.DuplicateNextOut();
    if (faults.unplug_at > 0 && seen >= faults.unplug_at && !unplugged) {
      unplugged = true;
      faults.unplug();
    }
    if (std::chrono::steady_clock::now() - last_ping > std::chrono::milliseconds(20)) {
      auto ping = client.Ping();
      EXPECT_TRUE(ping.ok()) << ping.status().ToString() << board();
      last_ping = std::chrono::steady_clock::now();
    }
    // After a re-plug, or when the board says its laser timeout stopped the program, carry on at the step
    // the board says comes next.
    if (client.stats().reconnects > reconnects_handled || resume) {
      reconnects_handled = client.stats().reconnects;
      resume = false;
      auto resumed = client.ResumeProgram();
      EXPECT_TRUE(resumed.ok()) << resumed.status().ToString() << board();
      if (resumed.ok() && resumed->has_value()) r.resumed_at = *resumed;
    }
    auto event = client.NextEvent(20'000);
    if (!event.ok()) {
      ADD_FAILURE() << event.status().ToString() << board();
      break;
    }
    if (!event->has_value()) continue;
    if (const auto* t = std::get_if<TriggerEvent>(&**event)) {
      ++r.triggers_seen;
      EXPECT_TRUE(t->step_index.has_value());
      auto& slot = r.shots[{t->step_index.value_or(0), t->shot}];
      if (slot.run <= t->run) slot = *t;
    } else if (const auto* s = std::get_if<BoardStatus>(&**event)) {
      if (s->cause == StatusCause::kSafety) r.safety_seen = resume = true;
      if (s->cause == StatusCause::kProgramDone) return r;
    }
  }
  ADD_FAILURE() << "the program did not end within " << give_up.count() << " s" << board();
  return r;
}

}  // namespace rotoscan::device::testing

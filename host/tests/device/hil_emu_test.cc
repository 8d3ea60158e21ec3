// Issue 18, hardware in the loop with the flashed image: the host's real libusb transport and client, through
// umockdev's emulated usbdevfs (mock_usb_board), talk to rotoscan-fw.elf running on the emulated STM32F411
// (firmware/tests/emu, EmuBoard): each bulk URB becomes OUT or IN transactions on the emulated OTG_FS core.
// A 16-step scan program (short, to keep the test near a second) with the
// faults of hil_sim_test injected on the mocked endpoint -- a lost packet, a corrupted byte, a duplicated
// command, an unplug long enough for the image's laser-safety timeout to stop the program, a re-plug (the
// harness re-enumerates the board as the kernel would) and a resume. Every TRIGGER_EVENT is checked against
// the emulator's pin edges: the TIM2 count of the trigger's rising edge exact to the tick, the laser pins and
// the table position at it, no (step, shot) lost or taken twice.
#include <gtest/gtest.h>

#include <chrono>
#include <map>
#include <thread>
#include <utility>
#include <vector>

#include "emu_board.h"
#include "mock_usb_board.h"
#include "rotoscan/device/client.h"
#include "rotoscan_protocol.h"

namespace rotoscan::device {
namespace {

using testing::EmuBoard;
using testing::MockUsbBoard;

constexpr uint32_t kSteps = 16;
constexpr int32_t kStepsPerMove = 16;
constexpr uint32_t kLaserTimeoutMs = 100;  // the least SET_CONFIG takes

ScanProgram Program() {
  ScanProgram p;
  p.step_count = kSteps;
  p.steps_per_move = kStepsPerMove;
  p.settle_us = 500;
  p.laser_lead_us = 200;
  p.shots = {{kLaserLeft, 1000}, {kLaserRight, 1000}, {0, 1000}, {0, 4000}};
  return p;
}

MotionConfig Config() {
  MotionConfig c;
  c.start_rate_hz = 1000;
  c.max_rate_hz = 20000;
  c.accel_hz_per_s = 2'000'000;
  c.trigger_pulse_us = 50;
  c.laser_timeout_ms = kLaserTimeoutMs;
  return c;
}

class HilEmuTest : public ::testing::Test {
 protected:
  void SetUp() override {
    if (!fw_emu::ImageExists(fw_emu::ImagePath())) {
      GTEST_SKIP() << "no firmware image at " << fw_emu::ImagePath()
                   << " (the cross build, firmware.cross_build, needs arm-none-eabi-gcc)";
    }
    ASSERT_TRUE(MockUsbBoard::InMockEnvironment()) << "run this test under umockdev-wrapper (ctest does)";
    std::string error;
    ASSERT_TRUE(board_.Boot(&error)) << error;
    MockUsbBoard::Options o;
    // The image sleeps (WFI) most of a scan and the emulator skips that time, so board time could outrun the
    // host's 20 ms keep-alive: at most 200 us of board time per 100 us of real time.
    o.virtual_us_per_tick = 200;
    o.real_us_per_tick = 100;
    usb_ = std::make_unique<MockUsbBoard>(&board_, o);
    ClientOptions options;
    options.ack_timeout_us = 150'000;
    auto transport = MakeLibusbTransport();
    ASSERT_TRUE(transport.ok()) << transport.status().ToString();
    auto client = Client::Connect(std::move(transport).value(), options);
    ASSERT_TRUE(client.ok()) << client.status().ToString() << " / " << board_.error();
    client_ = std::move(client).value();
  }
  void TearDown() override {
    if (replug_.joinable()) replug_.join();
    client_.reset();
    usb_.reset();
  }

  uint64_t BoardCycles() {
    uint64_t c = 0;
    usb_->WithBoardLocked([&] { c = board_.emu().cycles(); });
    return c;
  }

  std::map<std::pair<uint32_t, uint8_t>, TriggerEvent> RunScan(bool with_faults, int* triggers_seen) {
    triggers_seen_ = triggers_seen;
    std::map<std::pair<uint32_t, uint8_t>, TriggerEvent> shots;
    *triggers_seen = 0;
    EXPECT_TRUE(client_->SetConfig(Config()).ok());
    EXPECT_TRUE(client_->EnableMotor(true).ok());
    EXPECT_TRUE(client_->LoadProgram(Program()).ok());
    EXPECT_TRUE(client_->Start(0).ok());
    auto last_ping = std::chrono::steady_clock::now();
    int reconnects_handled = 0;
    bool unplugged = false, resume = false;
    const auto give_up = std::chrono::steady_clock::now() + std::chrono::seconds(90);  // only against a hang
    while (std::chrono::steady_clock::now() < give_up) {
      if (with_faults) {
        if (*triggers_seen >= 2 && usb_->counters().dropped == 0) usb_->DropNextOut();
        if (*triggers_seen >= 4 && usb_->counters().corrupted == 0) usb_->CorruptNextOut();
        if (*triggers_seen >= 6 && usb_->counters().duplicated == 0) usb_->DuplicateNextOut();
        if (*triggers_seen >= 10 && !unplugged) {
          unplugged = true;
          usb_->Unplug();
          // Re-plugged once the board has run twice its laser timeout on its own; the kernel enumerates it
          // again before libusb sees it.
          const uint64_t from = BoardCycles();
          replug_ = std::thread([this, from] {
            while (BoardCycles() - from < 2ull * kLaserTimeoutMs * 96'000) {
              std::this_thread::sleep_for(std::chrono::milliseconds(5));
            }
            std::string error;
            usb_->WithBoardLocked([&] { replug_ok_ = board_.Reenumerate(&error); });
            replug_error_ = error;
            usb_->Replug();
          });
        }
      }
      if (std::chrono::steady_clock::now() - last_ping > std::chrono::milliseconds(20)) {
        auto ping = client_->Ping();
        EXPECT_TRUE(ping.ok()) << ping.status().ToString();
        last_ping = std::chrono::steady_clock::now();
      }
      if (client_->stats().reconnects > reconnects_handled || resume) {
        reconnects_handled = client_->stats().reconnects;
        resume = false;
        auto resumed = client_->ResumeProgram();
        EXPECT_TRUE(resumed.ok()) << resumed.status().ToString();
        if (resumed.ok() && resumed->has_value()) resumed_at_ = *resumed;
      }
      auto event = client_->NextEvent(20'000);
      if (!event.ok()) {
        ADD_FAILURE() << event.status().ToString() << " / " << board_.error();
        break;
      }
      if (!event->has_value()) continue;
      if (const auto* t = std::get_if<TriggerEvent>(&**event)) {
        ++*triggers_seen;
        EXPECT_TRUE(t->step_index.has_value());
        auto& slot = shots[{t->step_index.value_or(0), t->shot}];
        if (slot.run <= t->run) slot = *t;
      } else if (const auto* s = std::get_if<BoardStatus>(&**event)) {
        if (s->cause == StatusCause::kSafety) safety_seen_ = resume = true;
        if (s->cause == StatusCause::kProgramDone) break;
      }
    }
    if (replug_.joinable()) replug_.join();
    return shots;
  }

  void CheckAgainstEdges(const std::map<std::pair<uint32_t, uint8_t>, TriggerEvent>& shots) {
    const ScanProgram program = Program();
    ASSERT_EQ(shots.size(), kSteps * program.shots.size());
    struct Truth {
      uint32_t tim2;
      uint8_t lasers;
      int32_t position;
    };
    std::vector<Truth> edges;
    int step_pulses = 0;
    usb_->WithBoardLocked([&] {
      fw_emu::F411Emu& emu = board_.emu();
      const uint32_t boot_counter = emu.Peek(emu.image().Symbol("g_tb"));  // device time 0 in TIM2 counts
      uint8_t lasers = 0;
      int32_t position = 0, dir = 1;
      for (const fw_emu::PinEdge& e : emu.edges()) {
        if (e.port == fw_emu::kPortB && e.pin == 13) lasers = uint8_t((lasers & ~1u) | (e.level ? 1u : 0u));
        if (e.port == fw_emu::kPortB && e.pin == 14) lasers = uint8_t((lasers & ~2u) | (e.level ? 2u : 0u));
        if (e.port == fw_emu::kPortB && e.pin == 5) dir = e.level ? 1 : -1;
        if (e.port == fw_emu::kPortB && e.pin == 4 && e.level) position += dir, ++step_pulses;
        if (e.port == fw_emu::kPortA && e.pin == 15 && e.level) {
          edges.push_back({e.tim2 - boot_counter, lasers, position});
        }
      }
    });
    EXPECT_EQ(step_pulses, int((kSteps - 1) * kStepsPerMove)) << "a step lost or taken twice";
    // Each event to the edge at its time: a shot aborted by the laser timeout between its edge and the end of
    // its exposure made an edge but no event (and no trigger_seq), so the sequence numbers are not indices
    // into the edges once the program has been stopped.
    std::map<uint32_t, size_t> edge_at;
    for (size_t i = 0; i < edges.size(); ++i) edge_at[edges[i].tim2] = i;
    EXPECT_LE(edges.size(), size_t(*triggers_seen_) + (safety_seen_ ? 2u : 0u))
        << "trigger edges without events";
    for (const auto& [key, t] : shots) {
      const auto [step, shot] = key;
      const auto found = edge_at.find(uint32_t(t.time_us));
      ASSERT_NE(found, edge_at.end())
          << "step " << step << " shot " << int(shot) << ": no trigger edge at TIM2 count " << t.time_us
          << " (less device time 0)";
      const Truth& truth = edges[found->second];
      if (!safety_seen_) {
        EXPECT_EQ(found->second, t.trigger_seq) << "step " << step << " shot " << int(shot);
      }
      EXPECT_EQ(t.laser_mask, program.shots[shot].laser_mask) << "step " << step << " shot " << int(shot);
      EXPECT_EQ(truth.lasers, program.shots[shot].laser_mask) << "step " << step << " shot " << int(shot);
      EXPECT_EQ(t.position, static_cast<int32_t>(step) * kStepsPerMove);
      EXPECT_EQ(truth.position, t.position);
    }
  }

  EmuBoard board_;
  std::unique_ptr<MockUsbBoard> usb_;
  std::unique_ptr<Client> client_;
  std::thread replug_;
  bool safety_seen_ = false;
  const int* triggers_seen_ = nullptr;
  bool replug_ok_ = false;
  std::string replug_error_;
  std::optional<uint32_t> resumed_at_;
};

TEST_F(HilEmuTest, EnumerateClaimAndGetInfo) {
  const DeviceInfo& info = client_->info();
  EXPECT_EQ(info.protocol_major, PROTO_VERSION_MAJOR);
  EXPECT_FALSE(info.simulated);
  auto fit = client_->SyncClock(5);
  ASSERT_TRUE(fit.ok()) << fit.status().ToString();
  EXPECT_EQ(board_.error(), "");
}

TEST_F(HilEmuTest, ScanOf16StepsEveryTriggerArrivesRight) {
  int triggers = 0;
  auto shots = RunScan(/*with_faults=*/false, &triggers);
  if (!safety_seen_) {
    EXPECT_EQ(triggers, static_cast<int>(kSteps * 4));
  }
  EXPECT_EQ(client_->stats().lost_events, 0);
  CheckAgainstEdges(shots);
  EXPECT_EQ(board_.error(), "");
}

TEST_F(HilEmuTest, ScanSurvivesLostCorruptedDuplicatedPacketsAndAnUnplug) {
  int triggers = 0;
  auto shots = RunScan(/*with_faults=*/true, &triggers);
  const MockUsbBoard::Counters faults = usb_->counters();
  EXPECT_EQ(faults.dropped, 1);
  EXPECT_EQ(faults.corrupted, 1);
  EXPECT_EQ(faults.duplicated, 1);
  EXPECT_EQ(faults.unplugs, 1);
  EXPECT_TRUE(replug_ok_) << replug_error_;
  EXPECT_GE(client_->stats().retransmits, 1);  // which frames the faults hit depends on timing
  EXPECT_EQ(client_->stats().reconnects, 1);
  EXPECT_EQ(client_->stats().lost_events, 0);
  EXPECT_TRUE(safety_seen_);
  ASSERT_TRUE(resumed_at_.has_value()) << "the program should have been stopped by the laser timeout";
  CheckAgainstEdges(shots);
  EXPECT_EQ(board_.error(), "");
}

}  // namespace
}  // namespace rotoscan::device

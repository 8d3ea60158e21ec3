// Hardware in the loop, the promised test: the host's real libusb transport and client, through umockdev's
// emulated usbdevfs, talk to the real firmware core built for the host (port/sim, virtual time). A 200-step
// scan program runs on the board; every TRIGGER_EVENT is checked against the simulator's own log of pin
// edges (the trigger edge's time, the laser pins' levels at it, the STEP pulses before it), and faults are
// injected on the mocked endpoint: a lost packet, a corrupted byte, a duplicated command, an unplug and
// re-plug in the middle of the scan (the laser-safety timeout stops the program meanwhile; the host resumes
// it, and the shots of the interrupted step are replaced, so no step is lost or taken twice).
#include <chrono>
#include <map>
#include <thread>
#include <utility>
#include <vector>

#include <gtest/gtest.h>

#include "mock_usb_board.h"
#include "rotoscan/device/client.h"
#include "rotoscan_protocol.h"
#include "sim_board.h"

namespace rotoscan::device {
namespace {

using testing::MockUsbBoard;
using testing::SimBoard;

constexpr uint32_t kSteps = 200;
constexpr int32_t kStepsPerMove = 16;

ScanProgram Program() {
  ScanProgram p;
  p.step_count = kSteps;
  p.steps_per_move = kStepsPerMove;
  p.settle_us = 500;
  p.laser_lead_us = 200;
  p.shots = {{kLaserLeft, 1000}, {kLaserRight, 1000}, {0, 1000}, {0, 4000}};  // left, right, off, natural
  return p;
}

MotionConfig Config(uint32_t laser_timeout_ms) {
  MotionConfig c;
  c.start_rate_hz = 1000;
  c.max_rate_hz = 20000;
  c.accel_hz_per_s = 2'000'000;
  c.trigger_pulse_us = 50;
  c.laser_timeout_ms = laser_timeout_ms;
  return c;
}

// What the pin edge log says about one trigger edge.
struct EdgeTruth {
  uint64_t time_us;
  uint8_t lasers;
  int32_t position;
};

std::vector<EdgeTruth> TriggerEdges(int* step_pulses) {
  std::vector<EdgeTruth> truth;
  uint8_t lasers = 0;
  int dir = 1;
  int32_t position = 0;
  *step_pulses = 0;
  const sim_edge_t* edges = sim_edges();
  for (size_t i = 0; i < sim_edge_count(); ++i) {
    const sim_edge_t& e = edges[i];
    switch (e.pin) {
      case SIM_PIN_LASER_LEFT: lasers = static_cast<uint8_t>((lasers & ~1u) | (e.level ? 1u : 0u)); break;
      case SIM_PIN_LASER_RIGHT: lasers = static_cast<uint8_t>((lasers & ~2u) | (e.level ? 2u : 0u)); break;
      case SIM_PIN_DIR: dir = e.level ? 1 : -1; break;
      case SIM_PIN_STEP:
        if (e.level) {
          position += dir;
          ++*step_pulses;
        }
        break;
      case SIM_PIN_TRIGGER:
        if (e.level) truth.push_back({e.time_us, lasers, position});
        break;
      default: break;
    }
  }
  return truth;
}

class HilSimTest : public ::testing::Test {
 protected:
  void SetUp() override {
    ASSERT_TRUE(MockUsbBoard::InMockEnvironment()) << "run this test under umockdev-wrapper (ctest does)";
    usb_ = std::make_unique<MockUsbBoard>(&board_);
    ClientOptions options;
    options.ack_timeout_us = 200'000;
    auto transport = MakeLibusbTransport();
    ASSERT_TRUE(transport.ok()) << transport.status().ToString();
    auto client = Client::Connect(std::move(transport).value(), options);
    ASSERT_TRUE(client.ok()) << client.status().ToString();
    client_ = std::move(client).value();
  }

  // Runs the program to the end: pings every 20 ms (the board's laser-safety keep-alive), injects the
  // faults at the given trigger counts, resumes after a re-plug. Returns the accepted shot of every
  // (step, shot): the one from the latest run.
  std::map<std::pair<uint32_t, uint8_t>, TriggerEvent> RunScan(bool with_faults, int* triggers_seen) {
    std::map<std::pair<uint32_t, uint8_t>, TriggerEvent> shots;
    *triggers_seen = 0;
    EXPECT_TRUE(client_->SetConfig(Config(/*laser_timeout_ms=*/1000)).ok());
    EXPECT_TRUE(client_->EnableMotor(true).ok());
    EXPECT_TRUE(client_->LoadProgram(Program()).ok());
    EXPECT_TRUE(client_->Start(0).ok());
    auto last_ping = std::chrono::steady_clock::now();
    int reconnects_handled = 0;
    bool unplugged = false;
    bool resume = false;
    // Wall-clock limit only against a hang; the scan takes about a second.
    const auto give_up = std::chrono::steady_clock::now() + std::chrono::seconds(60);
    while (std::chrono::steady_clock::now() < give_up) {
      if (with_faults) {
        if (*triggers_seen >= 100 && usb_->counters().dropped == 0) usb_->DropNextOut();
        if (*triggers_seen >= 200 && usb_->counters().corrupted == 0) usb_->CorruptNextOut();
        if (*triggers_seen >= 300 && usb_->counters().duplicated == 0) usb_->DuplicateNextOut();
        if (*triggers_seen >= 450 && !unplugged) {
          unplugged = true;
          usb_->Unplug();
          // Re-plugged after 400 ms (2 s of board time): longer than the board's laser timeout.
          replug_ = std::thread([this] {
            std::this_thread::sleep_for(std::chrono::milliseconds(400));
            usb_->Replug();
          });
        }
      }
      if (std::chrono::steady_clock::now() - last_ping > std::chrono::milliseconds(20)) {
        auto ping = client_->Ping();
        EXPECT_TRUE(ping.ok()) << ping.status().ToString();
        last_ping = std::chrono::steady_clock::now();
      }
      // After a re-plug, or when the board says its laser timeout stopped the program (a host stalled by a
      // loaded machine can miss its keep-alive too), carry on at the step the board says comes next.
      if (client_->stats().reconnects > reconnects_handled || resume) {
        reconnects_handled = client_->stats().reconnects;
        resume = false;
        auto resumed = client_->ResumeProgram();
        EXPECT_TRUE(resumed.ok()) << resumed.status().ToString();
        if (resumed.ok() && resumed->has_value()) resumed_at_ = *resumed;
      }
      auto event = client_->NextEvent(20'000);
      if (!event.ok()) {
        ADD_FAILURE() << event.status().ToString();
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
    ASSERT_EQ(shots.size(), kSteps * program.shots.size());  // no (step, shot) lost
    int step_pulses = 0;
    std::vector<EdgeTruth> edges;
    usb_->WithBoardLocked([&] { edges = TriggerEdges(&step_pulses); });
    // Every motor step pulse was needed: the table went from step 0 to step 199 exactly once.
    EXPECT_EQ(step_pulses, static_cast<int>((kSteps - 1) * kStepsPerMove));
    for (const auto& [key, t] : shots) {
      const auto [step, shot] = key;
      ASSERT_LT(t.trigger_seq, edges.size());
      const EdgeTruth& truth = edges[t.trigger_seq];
      EXPECT_EQ(t.time_us, truth.time_us) << "step " << step << " shot " << int(shot);
      EXPECT_EQ(t.laser_mask, program.shots[shot].laser_mask) << "step " << step << " shot " << int(shot);
      EXPECT_EQ(truth.lasers, program.shots[shot].laser_mask) << "step " << step << " shot " << int(shot);
      EXPECT_EQ(t.position, static_cast<int32_t>(step) * kStepsPerMove);
      EXPECT_EQ(truth.position, t.position);
    }
  }

  void TearDown() override {
    if (replug_.joinable()) replug_.join();
    client_.reset();
    usb_.reset();
  }

  SimBoard board_;
  std::unique_ptr<MockUsbBoard> usb_;
  std::unique_ptr<Client> client_;
  std::thread replug_;
  bool safety_seen_ = false;
  std::optional<uint32_t> resumed_at_;
};

TEST_F(HilSimTest, EnumerateClaimAndGetInfo) {
  const DeviceInfo& info = client_->info();
  EXPECT_EQ(info.protocol_major, PROTO_VERSION_MAJOR);
  EXPECT_TRUE(info.simulated);
  EXPECT_EQ(info.max_shots, PROTO_MAX_SHOTS);
  auto fit = client_->SyncClock(10);
  ASSERT_TRUE(fit.ok()) << fit.status().ToString();
}

TEST_F(HilSimTest, ScanOf200StepsEveryTriggerArrivesRight) {
  int triggers = 0;
  auto shots = RunScan(/*with_faults=*/false, &triggers);
  // A machine loaded enough to starve the keep-alive makes the board stop and the host resume (retaking
  // the interrupted step's shots); without that, exactly one trigger per shot.
  if (!safety_seen_) {
    EXPECT_EQ(triggers, static_cast<int>(kSteps * 4));
  }
  EXPECT_EQ(client_->stats().lost_events, 0);
  CheckAgainstEdges(shots);
}

TEST_F(HilSimTest, ScanSurvivesLostCorruptedDuplicatedPacketsAndAnUnplug) {
  int triggers = 0;
  auto shots = RunScan(/*with_faults=*/true, &triggers);
  const MockUsbBoard::Counters faults = usb_->counters();
  EXPECT_EQ(faults.dropped, 1);
  EXPECT_EQ(faults.corrupted, 1);
  EXPECT_EQ(faults.duplicated, 1);
  EXPECT_EQ(faults.unplugs, 1);
  EXPECT_GE(client_->stats().retransmits, 2);  // the lost and the corrupted command
  EXPECT_EQ(client_->stats().reconnects, 1);
  EXPECT_EQ(client_->stats().lost_events, 0);
  EXPECT_TRUE(safety_seen_);
  ASSERT_TRUE(resumed_at_.has_value()) << "the program should have been stopped by the laser timeout";
  CheckAgainstEdges(shots);
}

}  // namespace
}  // namespace rotoscan::device

// Client unit tests over the in-process transport and a scripted fake board (virtual time: deterministic,
// no wall-clock waits).
#include "rotoscan/device/client.h"

#include <gtest/gtest.h>

#include "fake_board.h"

namespace rotoscan::device {
namespace {

using testing::FakeBoard;

Result<std::unique_ptr<Client>> ConnectTo(FakeBoard* board, ClientOptions options = {}) {
  return Client::Connect(MakeInProcessTransport(board), options);
}

TEST(ClientTest, ConnectReadsInfo) {
  FakeBoard board;
  auto client = ConnectTo(&board);
  ASSERT_TRUE(client.ok()) << client.status().ToString();
  const DeviceInfo& info = (*client)->info();
  EXPECT_EQ(info.protocol_major, PROTO_VERSION_MAJOR);
  EXPECT_EQ(info.protocol_minor, 3);
  EXPECT_EQ(info.firmware_version, "0.4.2");
  EXPECT_EQ(info.max_shots, PROTO_MAX_SHOTS);
  EXPECT_TRUE(info.simulated);
  EXPECT_EQ(info.uid, "a0a1a2a3a4a5a6a7a8a9aaab");
}

TEST(ClientTest, RefusesAnotherProtocolMajorWithAClearMessage) {
  FakeBoard board;
  board.proto_major = PROTO_VERSION_MAJOR + 1;
  auto client = ConnectTo(&board);
  ASSERT_FALSE(client.ok());
  EXPECT_EQ(client.status().code(), StatusCode::kFailedPrecondition);
  EXPECT_NE(client.status().message().find("protocol " + std::to_string(PROTO_VERSION_MAJOR + 1) + ".3"),
            std::string::npos)
      << client.status().message();
  EXPECT_NE(client.status().message().find("update the host software"), std::string::npos);
}

TEST(ClientTest, RetransmitsTheSameSeqOnTimeoutAndTheBoardRunsItOnce) {
  FakeBoard board;
  auto client = ConnectTo(&board);
  ASSERT_TRUE(client.ok());
  board.drop_commands = 2;
  ASSERT_TRUE((*client)->SetLasers(kLaserLeft).ok());
  EXPECT_EQ((*client)->stats().retransmits, 2);
  ASSERT_EQ(board.received.size(), 2u);  // GET_INFO, then the one SET_LASERS frame that got through
  const uint16_t seq = board.received.back().first;
  EXPECT_EQ(board.received.back().second, PROTO_SET_LASERS);
  EXPECT_EQ(board.executed[seq], 1);
}

TEST(ClientTest, DuplicatedCommandIsNotExecutedTwice) {
  FakeBoard board;
  board.reply_delay_us = 150'000;  // slower than the ack timeout: the client sends the command again
  ClientOptions options;
  options.ack_timeout_us = 100'000;
  auto client = ConnectTo(&board, options);
  ASSERT_TRUE(client.ok());
  ASSERT_TRUE((*client)->Move(100).ok());
  EXPECT_GE((*client)->stats().retransmits, 2);
  const uint16_t seq = board.received.back().first;
  EXPECT_EQ(board.executed[seq], 1);
  // The late answers to the earlier copies are stale and must not be taken for the next command's answer.
  ASSERT_TRUE((*client)->SetLasers(0).ok());
  EXPECT_GE((*client)->stats().stale_answers, 1);
}

TEST(ClientTest, GivesUpAfterTheRetriesWithTimeout) {
  FakeBoard board;
  ClientOptions options;
  options.retries = 3;
  auto client = ConnectTo(&board, options);
  ASSERT_TRUE(client.ok());
  board.drop_commands = 1000;
  const Status status = (*client)->EnableMotor(true);
  EXPECT_EQ(status.code(), StatusCode::kTimeout);
  EXPECT_NE(status.message().find("MOTOR_ENABLE"), std::string::npos) << status.message();
  EXPECT_EQ((*client)->stats().retransmits, 3);
}

TEST(ClientTest, DamagedCommandIsSentAgainAtOnce) {
  FakeBoard board;
  auto client = ConnectTo(&board);
  ASSERT_TRUE(client.ok());
  board.corrupt_commands = 1;
  ASSERT_TRUE((*client)->Abort().ok());
  EXPECT_EQ((*client)->stats().retransmits, 1);
}

TEST(ClientTest, DuplicateAnswersAreIgnored) {
  FakeBoard board;
  auto client = ConnectTo(&board);
  ASSERT_TRUE(client.ok());
  board.duplicate_answers = 1;
  ASSERT_TRUE((*client)->SetLasers(kLaserRight).ok());
  ASSERT_TRUE((*client)->SetLasers(0).ok());
  EXPECT_EQ((*client)->stats().stale_answers, 1);
  EXPECT_EQ((*client)->stats().retransmits, 0);
}

TEST(ClientTest, RefusalNamesTheCommandAndTheField) {
  FakeBoard board;
  auto client = ConnectTo(&board);
  ASSERT_TRUE(client.ok());
  board.refuse_with_bad_value = true;
  const Status status = (*client)->SetConfig(MotionConfig{});
  EXPECT_EQ(status.code(), StatusCode::kDeviceError);
  EXPECT_NE(status.message().find("SET_CONFIG"), std::string::npos) << status.message();
  EXPECT_NE(status.message().find("field 2"), std::string::npos) << status.message();
}

TEST(ClientTest, BadProgramIsRefusedBeforeSending) {
  FakeBoard board;
  auto client = ConnectTo(&board);
  ASSERT_TRUE(client.ok());
  ScanProgram program;
  program.step_count = 10;
  EXPECT_EQ((*client)->LoadProgram(program).code(), StatusCode::kInvalidArgument);  // no shots
  program.shots.push_back({0x4, 1000});
  EXPECT_EQ((*client)->LoadProgram(program).code(), StatusCode::kInvalidArgument);  // unknown laser bit
  EXPECT_EQ(board.received.size(), 1u);                                             // only GET_INFO went out
}

proto_msg_t TriggerEventMsg(uint32_t trigger_seq) {
  proto_msg_t m;
  proto_msg_init(&m, PROTO_TRIGGER_EVENT, static_cast<uint16_t>(trigger_seq));
  m.body.trigger_event.trigger_seq = trigger_seq;
  m.body.trigger_event.time_us = 1000 + trigger_seq;
  m.body.trigger_event.position = static_cast<int32_t>(10 * trigger_seq);
  m.body.trigger_event.laser_mask = PROTO_LASER_LEFT;
  m.body.trigger_event.step_index = trigger_seq / 2;
  m.body.trigger_event.flags = PROTO_TRIG_IN_PROGRAM;
  return m;
}

TEST(ClientTest, EventsArrivingDuringACommandAreKeptInOrderAndGapsCounted) {
  FakeBoard board;
  auto client = ConnectTo(&board);
  ASSERT_TRUE(client.ok());
  for (uint32_t seq : {0u, 1u, 2u, 5u, 6u}) board.SendEvent(TriggerEventMsg(seq));  // 3 and 4 lost
  ASSERT_TRUE((*client)->SetLasers(0).ok());
  std::vector<uint32_t> seen;
  while (true) {
    auto event = (*client)->NextEvent(10'000);
    ASSERT_TRUE(event.ok());
    if (!event->has_value()) break;
    const auto* trigger = std::get_if<TriggerEvent>(&**event);
    ASSERT_NE(trigger, nullptr);
    EXPECT_EQ(trigger->position, static_cast<int32_t>(10 * trigger->trigger_seq));
    ASSERT_TRUE(trigger->step_index.has_value());
    EXPECT_EQ(*trigger->step_index, trigger->trigger_seq / 2);
    seen.push_back(trigger->trigger_seq);
  }
  EXPECT_EQ(seen, (std::vector<uint32_t>{0, 1, 2, 5, 6}));
  EXPECT_EQ((*client)->stats().lost_events, 2);
}

TEST(ClientTest, ClockSyncRecoversOffsetAndDriftOfADriftingBoard) {
  FakeBoard board(/*seed=*/7);
  board.clock_offset_us = 5'000'000.0;
  board.clock_drift = 80e-6;  // 80 ppm fast
  board.reply_delay_us = 100;
  board.reply_jitter_us = 3000;  // most round trips are much slower than the fastest
  auto client = ConnectTo(&board);
  ASSERT_TRUE(client.ok());
  // Spread the pings over 20 s of virtual time so the drift is observable.
  std::vector<PingSample> samples;
  for (int i = 0; i < 200; ++i) {
    auto sample = (*client)->Ping();
    ASSERT_TRUE(sample.ok()) << sample.status().ToString();
    samples.push_back(*sample);
    auto idle = (*client)->NextEvent(100'000);
    ASSERT_TRUE(idle.ok());
  }
  auto fit = FitClock(samples);
  ASSERT_TRUE(fit.ok()) << fit.status().ToString();
  // Tolerances: the kept samples have round trips within ~0.1 ms of the fastest, so the midpoint error is
  // tens of microseconds; over 20 s that bounds the drift error to a few ppm.
  EXPECT_NEAR(fit->drift, 80e-6, 3e-6);
  EXPECT_NEAR(fit->DeviceFromHost(10e6), board.clock_offset_us + (1 + 80e-6) * 10e6, 150.0);
  EXPECT_EQ(fit->samples_used, 50);
}

}  // namespace
}  // namespace rotoscan::device

// The firmware core on the simulated board (port/sim): laser state at every trigger edge, step timing,
// timebase wrap, laser safety, malformed input, duplicate commands, resume after an interruption.
#include <gtest/gtest.h>

#include <cmath>
#include <cstring>
#include <random>
#include <set>
#include <string>
#include <vector>

#include "fw.h"
#include "rotoscan_protocol.h"
#include "sim_device.h"
#include "sim_port.h"
#include "sim_test_util.h"

namespace rotoscan::firmware_test {
namespace {

proto_msg_t EnableMotor() {
  proto_msg_t m = SimDevice::Make(PROTO_MOTOR_ENABLE);
  m.body.motor_enable.enable = 1;
  return m;
}

proto_msg_t Move(int32_t steps) {
  proto_msg_t m = SimDevice::Make(PROTO_MOVE);
  m.body.move.steps = steps;
  return m;
}

proto_msg_t Config(uint32_t start, uint32_t max, uint32_t accel, uint32_t timeout_ms = 2000) {
  proto_msg_t m = SimDevice::Make(PROTO_SET_CONFIG);
  m.body.config.start_rate_hz = start;
  m.body.config.max_rate_hz = max;
  m.body.config.accel_hz_per_s = accel;
  m.body.config.trigger_pulse_us = 100;
  m.body.config.laser_timeout_ms = timeout_ms;
  return m;
}

// The rig's usual program: left laser, right laser, lasers off (short exposures), natural image (long).
proto_msg_t ScanProgram(uint32_t steps, int32_t steps_per_move, uint32_t settle_us = 2000) {
  proto_msg_t m = SimDevice::Make(PROTO_LOAD_PROGRAM);
  proto_program_t& p = m.body.program;
  p.step_count = steps;
  p.steps_per_move = steps_per_move;
  p.settle_us = settle_us;
  p.laser_lead_us = 300;
  p.shot_count = 4;
  p.shots[0] = {PROTO_LASER_LEFT, 1000};
  p.shots[1] = {PROTO_LASER_RIGHT, 1000};
  p.shots[2] = {0, 1000};
  p.shots[3] = {0, 4000};
  return m;
}

proto_msg_t Start(uint32_t first_step) {
  proto_msg_t m = SimDevice::Make(PROTO_START);
  m.body.start.first_step = first_step;
  return m;
}

void ExpectAck(const proto_msg_t& answer, uint8_t type) {
  EXPECT_EQ(answer.type, PROTO_ACK) << proto_type_name(type) << " answered with status "
                                    << proto_status_name(answer.body.ack.status);
  EXPECT_EQ(answer.body.ack.acked_type, type);
  EXPECT_EQ(answer.body.ack.status, PROTO_ST_OK);
}

void ExpectNack(const proto_msg_t& answer, uint8_t status) {
  EXPECT_EQ(answer.type, PROTO_NACK);
  EXPECT_EQ(answer.body.ack.status, status) << "got " << proto_status_name(answer.body.ack.status);
}

bool ProgramDone(const SimDevice& dev) {
  for (const proto_msg_t& m : dev.EventsOfType(PROTO_STATUS)) {
    if (m.body.status.cause == PROTO_CAUSE_PROGRAM_DONE) return true;
  }
  return false;
}

// ---- scan program ----

TEST(FirmwareProgram, LaserMaskAtEveryTriggerEdgeEqualsTheProgram) {
  SimDevice dev;
  ExpectAck(dev.Command(EnableMotor()), PROTO_MOTOR_ENABLE);
  const proto_msg_t program = ScanProgram(20, 16);
  ExpectAck(dev.Command(program), PROTO_LOAD_PROGRAM);
  ExpectAck(dev.Command(Start(0)), PROTO_START);
  for (int i = 0; i < 100 && !ProgramDone(dev); ++i) dev.Advance(20000);
  ASSERT_TRUE(ProgramDone(dev));
  ASSERT_EQ(sim_edges_dropped(), 0u);

  const proto_program_t& p = program.body.program;
  const std::vector<uint64_t> triggers = EdgeTimes(SIM_PIN_TRIGGER, 1);
  ASSERT_EQ(triggers.size(), 20u * 4u);
  const std::vector<proto_msg_t> events = dev.EventsOfType(PROTO_TRIGGER_EVENT);
  ASSERT_EQ(events.size(), triggers.size());
  for (size_t k = 0; k < triggers.size(); ++k) {
    const uint32_t step = static_cast<uint32_t>(k / 4);
    const uint8_t shot = static_cast<uint8_t>(k % 4);
    SCOPED_TRACE("trigger " + std::to_string(k));
    // The pins at the edge, from the log.
    EXPECT_EQ(LaserMaskAt(triggers[k]), p.shots[shot].laser_mask);
    // The lasers switched laser_lead_us before the edge (or earlier, when the mask did not change).
    EXPECT_EQ(LaserMaskAt(triggers[k] - p.laser_lead_us), p.shots[shot].laser_mask);
    // What the device reported.
    const proto_trigger_event_t& e = events[k].body.trigger_event;
    EXPECT_EQ(e.trigger_seq, k);
    EXPECT_EQ(e.time_us, triggers[k]);
    EXPECT_EQ(e.laser_mask, p.shots[shot].laser_mask);
    EXPECT_EQ(e.step_index, step);
    EXPECT_EQ(e.shot, shot);
    EXPECT_EQ(e.position, static_cast<int32_t>(step) * 16);
    EXPECT_EQ(e.flags, PROTO_TRIG_IN_PROGRAM | PROTO_TRIG_EXPOSURE_SEEN);
    EXPECT_EQ(e.exposure_seen_us, triggers[k] + 10u);  // the simulated camera's delay
    if (k > 0) {
      // The next shot waits for the previous exposure.
      EXPECT_GE(triggers[k] - triggers[k - 1], p.shots[(k - 1) % 4].exposure_us);
    }
  }
  // Lasers are off whenever the table moves, and at the end.
  for (uint64_t t : EdgeTimes(SIM_PIN_STEP, 1)) EXPECT_EQ(LaserMaskAt(t), 0) << "step at " << t;
  EXPECT_EQ(sim_pin_level(SIM_PIN_LASER_LEFT), 0);
  EXPECT_EQ(sim_pin_level(SIM_PIN_LASER_RIGHT), 0);
  EXPECT_EQ(EdgeTimes(SIM_PIN_STEP, 1).size(), 19u * 16u);
  EXPECT_EQ(dev.decode_errors(), 0);
}

TEST(FirmwareProgram, SingleTriggerRestoresTheLasers) {
  SimDevice dev;
  proto_msg_t lasers = SimDevice::Make(PROTO_SET_LASERS);
  lasers.body.set_lasers.mask = PROTO_LASER_RIGHT;
  ExpectAck(dev.Command(lasers), PROTO_SET_LASERS);
  proto_msg_t trig = SimDevice::Make(PROTO_TRIGGER);
  trig.body.trigger = {PROTO_LASER_LEFT, 200, 3000};
  ExpectAck(dev.Command(trig), PROTO_TRIGGER);
  ASSERT_TRUE(dev.AdvanceUntil(PROTO_TRIGGER_EVENT, 100000));
  const std::vector<uint64_t> triggers = EdgeTimes(SIM_PIN_TRIGGER, 1);
  ASSERT_EQ(triggers.size(), 1u);
  EXPECT_EQ(LaserMaskAt(triggers[0]), PROTO_LASER_LEFT);
  const proto_trigger_event_t e = dev.EventsOfType(PROTO_TRIGGER_EVENT)[0].body.trigger_event;
  EXPECT_EQ(e.step_index, 0xFFFFFFFFu);
  EXPECT_EQ(e.flags, PROTO_TRIG_EXPOSURE_SEEN);
  EXPECT_EQ(e.laser_mask, PROTO_LASER_LEFT);
  EXPECT_EQ(e.time_us, triggers[0]);
  EXPECT_EQ(sim_pin_level(SIM_PIN_LASER_RIGHT), 1);
  EXPECT_EQ(sim_pin_level(SIM_PIN_LASER_LEFT), 0);
}

TEST(FirmwareProgram, NoEventIsLostWhenTheHostReadsLate) {
  SimDevice dev;
  ExpectAck(dev.Command(Config(200, 2000, 8000, 600000)), PROTO_SET_CONFIG);
  ExpectAck(dev.Command(EnableMotor()), PROTO_MOTOR_ENABLE);
  ExpectAck(dev.Command(ScanProgram(40, 4, 500)), PROTO_LOAD_PROGRAM);
  ExpectAck(dev.Command(Start(0)), PROTO_START);
  sim_advance_us(3000000);  // the host reads nothing for 3 s: far more events than the queue holds
  dev.Drain();
  const size_t early = dev.EventsOfType(PROTO_TRIGGER_EVENT).size();
  EXPECT_LT(early, 160u);  // the sequencer held back instead of dropping
  for (int i = 0; i < 200 && !ProgramDone(dev); ++i) dev.Advance(10000);
  ASSERT_TRUE(ProgramDone(dev));
  const std::vector<proto_msg_t> events = dev.EventsOfType(PROTO_TRIGGER_EVENT);
  ASSERT_EQ(events.size(), 160u);
  for (size_t k = 0; k < events.size(); ++k) EXPECT_EQ(events[k].body.trigger_event.trigger_seq, k);
  const proto_msg_t status = dev.Command(SimDevice::Make(PROTO_GET_STATUS));
  EXPECT_EQ(status.body.status.events_dropped, 0u);
  EXPECT_EQ(status.body.status.trigger_count, 160u);
}

// ---- stepper ----

// The profile of stepper.c, in double precision: the interval from step i to step i+1.
std::vector<double> ReferenceIntervals(double v0, double vmax, double a, uint32_t n) {
  const uint32_t ramp_full = static_cast<uint32_t>(std::floor((vmax * vmax - v0 * v0) / (2 * a)));
  const uint32_t m = std::min(ramp_full, n / 2);
  auto v = [&](uint32_t k) { return std::sqrt(v0 * v0 + 2 * a * k); };
  std::vector<double> d(n);
  for (uint32_t i = 0; i < n; ++i) {
    if (i < m) {
      d[i] = 2e6 / (v(i) + v(i + 1));
    } else if (i >= n - m) {
      const uint32_t k = n - 1 - i;
      d[i] = 2e6 / (v(k) + v(k + 1));
    } else {
      d[i] = 1e6 / v(m);
    }
  }
  return d;
}

void CheckMoveFollowsProfile(uint32_t start, uint32_t max, uint32_t accel, int32_t steps) {
  SimDevice dev;
  ExpectAck(dev.Command(Config(start, max, accel)), PROTO_SET_CONFIG);
  ExpectAck(dev.Command(EnableMotor()), PROTO_MOTOR_ENABLE);
  sim_edges_clear();
  ExpectAck(dev.Command(Move(steps)), PROTO_MOVE);
  ASSERT_TRUE(dev.AdvanceUntil(PROTO_MOVE_DONE, 60000000, 10000));
  const uint32_t n = static_cast<uint32_t>(std::abs(steps));
  const std::vector<uint64_t> edges = EdgeTimes(SIM_PIN_STEP, 1);
  ASSERT_EQ(edges.size(), n);
  const std::vector<double> d = ReferenceIntervals(start, max, accel, n);
  double exact = static_cast<double>(edges[0]);
  double worst = 0;
  for (uint32_t i = 1; i < n; ++i) {
    exact += d[i - 1];
    // Each edge within 1 us of the exact profile (rounding to the 1 us tick, carried forward), so the
    // intervals are within 2 us of it, and the speed ramps monotonically.
    worst = std::max(worst, std::abs(static_cast<double>(edges[i]) - exact));
    ASSERT_NEAR(static_cast<double>(edges[i]), exact, 1.0) << "edge " << i;
  }
  const proto_move_done_t done = dev.EventsOfType(PROTO_MOVE_DONE).back().body.move_done;
  EXPECT_EQ(done.status, PROTO_ST_OK);
  EXPECT_EQ(done.position, steps);
  EXPECT_NEAR(static_cast<double>(done.time_us), exact + d[n - 1], 1.0);
  // DIR was set before the first edge and held.
  EXPECT_EQ(LevelAt(SIM_PIN_DIR, edges[0]), steps > 0 ? 1 : 0);
  EXPECT_LT(EdgeTimes(SIM_PIN_DIR, steps > 0 ? 1 : 0).size(), 2u);
  std::printf("move %d steps: worst edge error %.3f us over %.1f ms\n", steps, worst,
              (exact - edges[0]) / 1e3);
}

TEST(FirmwareStepper, TrapezoidWithCruiseFollowsTheProfile) {
  CheckMoveFollowsProfile(500, 5000, 20000, 3000);
}
TEST(FirmwareStepper, TriangleFollowsTheProfile) {
  CheckMoveFollowsProfile(200, 2000, 8000, 101);
}
TEST(FirmwareStepper, ConstantSpeedBackwardsFollowsTheProfile) {
  CheckMoveFollowsProfile(1000, 1000, 1, -50);
}

TEST(FirmwareStepper, StepIntervalsRampUpCruiseAndRampDown) {
  SimDevice dev;
  ExpectAck(dev.Command(Config(500, 5000, 20000)), PROTO_SET_CONFIG);
  ExpectAck(dev.Command(EnableMotor()), PROTO_MOTOR_ENABLE);
  ExpectAck(dev.Command(Move(2000)), PROTO_MOVE);
  ASSERT_TRUE(dev.AdvanceUntil(PROTO_MOVE_DONE, 10000000, 10000));
  const std::vector<uint64_t> e = EdgeTimes(SIM_PIN_STEP, 1);
  ASSERT_EQ(e.size(), 2000u);
  // v = sqrt(v0^2 + 2ak): 618 steps to reach 5000 steps/s; cruise interval 1e6 / v(618) ~ 200 us.
  EXPECT_NEAR(static_cast<double>(e[1] - e[0]), 2e6 / (500 + std::sqrt(500.0 * 500 + 40000)), 1.0);
  EXPECT_NEAR(static_cast<double>(e[1000] - e[999]), 1e6 / std::sqrt(500.0 * 500 + 40000.0 * 618), 1.0);
  for (size_t i = 2; i < 600; ++i) EXPECT_LE(e[i] - e[i - 1], e[i - 1] - e[i - 2] + 1) << i;
  for (size_t i = 1402; i < 2000; ++i) EXPECT_GE(e[i] - e[i - 1] + 1, e[i - 1] - e[i - 2]) << i;
}

TEST(FirmwareStepper, AbortStopsAtOnceAndCountsTheStepsMade) {
  SimDevice dev;
  ExpectAck(dev.Command(EnableMotor()), PROTO_MOTOR_ENABLE);
  ExpectAck(dev.Command(Move(5000)), PROTO_MOVE);
  dev.Advance(200000);
  ExpectAck(dev.Command(SimDevice::Make(PROTO_ABORT)), PROTO_ABORT);
  dev.Advance(100000);
  const size_t made = EdgeTimes(SIM_PIN_STEP, 1).size();
  EXPECT_GT(made, 0u);
  EXPECT_LT(made, 5000u);
  const std::vector<proto_msg_t> done = dev.EventsOfType(PROTO_MOVE_DONE);
  ASSERT_EQ(done.size(), 1u);
  EXPECT_EQ(done[0].body.move_done.status, PROTO_MOVE_ABORTED);
  EXPECT_EQ(done[0].body.move_done.position, static_cast<int32_t>(made));
  const std::vector<proto_msg_t> status = dev.EventsOfType(PROTO_STATUS);
  ASSERT_FALSE(status.empty());
  EXPECT_EQ(status.back().body.status.cause, PROTO_CAUSE_ABORTED);
}

// ---- timebase ----

TEST(FirmwareTimebase, SurvivesThe32BitWrapDuringAScan) {
  // The 32-bit timer wraps 30 ms after power-on, in the middle of the program.
  SimDevice dev(0xFFFFFFFFu - 30000u);
  ExpectAck(dev.Command(EnableMotor()), PROTO_MOTOR_ENABLE);
  ExpectAck(dev.Command(ScanProgram(10, 8)), PROTO_LOAD_PROGRAM);
  ExpectAck(dev.Command(Start(0)), PROTO_START);
  for (int i = 0; i < 100 && !ProgramDone(dev); ++i) dev.Advance(10000);
  ASSERT_TRUE(ProgramDone(dev));
  EXPECT_LT(sim_timer_counter(), 0x80000000u);  // it did wrap
  const std::vector<uint64_t> triggers = EdgeTimes(SIM_PIN_TRIGGER, 1);
  const std::vector<proto_msg_t> events = dev.EventsOfType(PROTO_TRIGGER_EVENT);
  ASSERT_EQ(events.size(), triggers.size());
  ASSERT_EQ(events.size(), 40u);
  bool before = false;
  bool after = false;
  for (size_t k = 0; k < events.size(); ++k) {
    EXPECT_EQ(events[k].body.trigger_event.time_us, triggers[k]);  // device time = virtual time, exactly
    before |= triggers[k] < 30000u;
    after |= triggers[k] > 30001u;
  }
  EXPECT_TRUE(before && after);
  proto_msg_t ping = SimDevice::Make(PROTO_PING);
  ping.body.ping.host_time_us = 77;
  const proto_msg_t pong = dev.Command(ping);
  EXPECT_EQ(pong.body.pong.device_time_us, sim_now_us());
  EXPECT_EQ(pong.body.pong.host_time_us, 77u);
}

TEST(FirmwareTimebase, CountsPastTwoToThe32Microseconds) {
  SimDevice dev;
  const uint64_t span = (uint64_t{1} << 32) + 123456789u;  // 73.6 minutes idle
  sim_advance_us(span);
  dev.Drain();
  const proto_msg_t pong = dev.Command(SimDevice::Make(PROTO_PING));
  ASSERT_EQ(pong.type, PROTO_PONG);
  EXPECT_EQ(pong.body.pong.device_time_us, span);
  EXPECT_EQ(sim_now_us(), span);
}

// ---- GET_DIAG (protocol 1.1) ----

TEST(FirmwareDiag, TheSimulationAdvertisesAndAnswersGetDiag) {
  SimDevice dev;
  const proto_msg_t info = dev.Command(SimDevice::Make(PROTO_GET_INFO));
  ASSERT_EQ(info.type, PROTO_INFO);
  EXPECT_EQ(info.body.info.proto_minor, 1);
  EXPECT_TRUE(info.body.info.capabilities & PROTO_CAP_DIAG);
  const proto_msg_t diag = dev.Command(SimDevice::Make(PROTO_GET_DIAG));
  ASSERT_EQ(diag.type, PROTO_DIAG);
  // The simulation counts no CPU cycles and records no fault: it says so rather than sending zeros as data.
  EXPECT_EQ(diag.body.diag.flags, 0);
  EXPECT_EQ(diag.body.diag.step_isr_cycles_max, 0u);
  EXPECT_EQ(diag.body.diag.fault_count, 0u);
}

// ---- laser safety ----

TEST(FirmwareSafety, LasersGoOffWhenTheHostIsSilent) {
  SimDevice dev;
  proto_msg_t lasers = SimDevice::Make(PROTO_SET_LASERS);
  lasers.body.set_lasers.mask = PROTO_LASER_ALL;
  ExpectAck(dev.Command(lasers), PROTO_SET_LASERS);
  const uint64_t last_heard = sim_now_us();
  dev.Advance(1999000);
  EXPECT_EQ(sim_pin_level(SIM_PIN_LASER_LEFT), 1);
  EXPECT_EQ(sim_pin_level(SIM_PIN_LASER_RIGHT), 1);
  dev.Advance(2000);
  EXPECT_EQ(sim_pin_level(SIM_PIN_LASER_LEFT), 0);
  EXPECT_EQ(sim_pin_level(SIM_PIN_LASER_RIGHT), 0);
  const std::vector<uint64_t> off = EdgeTimes(SIM_PIN_LASER_LEFT, 0);
  ASSERT_EQ(off.size(), 1u);
  EXPECT_NEAR(static_cast<double>(off[0] - last_heard), 2000000.0, 2.0);
  const std::vector<proto_msg_t> status = dev.EventsOfType(PROTO_STATUS);
  ASSERT_EQ(status.size(), 1u);
  EXPECT_EQ(status[0].body.status.cause, PROTO_CAUSE_SAFETY);
  EXPECT_EQ(dev.EventsOfType(PROTO_LOG).size(), 1u);
  const proto_msg_t reply = dev.Command(SimDevice::Make(PROTO_GET_STATUS));
  EXPECT_TRUE(reply.body.status.flags & PROTO_FLAG_SAFETY_TRIPPED);
  EXPECT_EQ(reply.body.status.lasers, 0);
  const proto_msg_t again = dev.Command(SimDevice::Make(PROTO_GET_STATUS));
  EXPECT_FALSE(again.body.status.flags & PROTO_FLAG_SAFETY_TRIPPED);
}

TEST(FirmwareSafety, PingsKeepTheLasersOn) {
  SimDevice dev;
  proto_msg_t lasers = SimDevice::Make(PROTO_SET_LASERS);
  lasers.body.set_lasers.mask = PROTO_LASER_LEFT;
  ExpectAck(dev.Command(lasers), PROTO_SET_LASERS);
  for (int i = 0; i < 10; ++i) {
    dev.Advance(1500000);
    ASSERT_EQ(dev.Command(SimDevice::Make(PROTO_PING)).type, PROTO_PONG);
  }
  EXPECT_EQ(sim_pin_level(SIM_PIN_LASER_LEFT), 1);
  EXPECT_TRUE(dev.EventsOfType(PROTO_STATUS).empty());
}

TEST(FirmwareSafety, ScanStoppedBySafetyResumesWithNoStepLostOrRepeated) {
  SimDevice dev;
  ExpectAck(dev.Command(EnableMotor()), PROTO_MOTOR_ENABLE);
  const uint32_t kSteps = 40;
  const int32_t kPerMove = 10;
  ExpectAck(dev.Command(ScanProgram(kSteps, kPerMove, 50000)), PROTO_LOAD_PROGRAM);
  ExpectAck(dev.Command(Start(0)), PROTO_START);
  // The host goes silent (unplugged) for 3 s: the program stops at the safety timeout.
  dev.Advance(3000000);
  const std::vector<proto_msg_t> status = dev.EventsOfType(PROTO_STATUS);
  ASSERT_EQ(status.size(), 1u);
  EXPECT_EQ(status[0].body.status.cause, PROTO_CAUSE_SAFETY);
  const uint32_t resume = status[0].body.status.program_next_step;
  ASSERT_GT(resume, 0u);
  ASSERT_LT(resume, kSteps);
  EXPECT_EQ(sim_pin_level(SIM_PIN_LASER_LEFT) + sim_pin_level(SIM_PIN_LASER_RIGHT), 0);
  // Back: resume where it stopped, pinging as a host does.
  ExpectAck(dev.Command(Start(resume)), PROTO_START);
  for (int i = 0; i < 40 && !ProgramDone(dev); ++i) {
    dev.Advance(250000);
    ASSERT_EQ(dev.Command(SimDevice::Make(PROTO_PING)).type, PROTO_PONG);
  }
  ASSERT_TRUE(ProgramDone(dev));
  // Every step has one complete set of shots at its own position; only the interrupted step has an extra,
  // incomplete set from before the interruption (which a host discards).
  std::vector<std::vector<uint8_t>> shots(kSteps);
  for (const proto_msg_t& m : dev.EventsOfType(PROTO_TRIGGER_EVENT)) {
    const proto_trigger_event_t& e = m.body.trigger_event;
    ASSERT_LT(e.step_index, kSteps);
    EXPECT_EQ(e.position, static_cast<int32_t>(e.step_index) * kPerMove);
    shots[e.step_index].push_back(e.shot);
  }
  for (uint32_t s = 0; s < kSteps; ++s) {
    if (s == resume) {
      ASSERT_GE(shots[s].size(), 4u);
      EXPECT_LT(shots[s].size(), 8u);
      const std::vector<uint8_t> tail(shots[s].end() - 4, shots[s].end());
      EXPECT_EQ(tail, (std::vector<uint8_t>{0, 1, 2, 3}));
    } else {
      EXPECT_EQ(shots[s], (std::vector<uint8_t>{0, 1, 2, 3})) << "step " << s;
    }
  }
  // The table never moved more than the program asks: (steps - 1) moves of kPerMove.
  EXPECT_EQ(EdgeTimes(SIM_PIN_STEP, 1).size(), (kSteps - 1) * kPerMove);
}

// ---- bad input, duplicates, refusals ----

std::vector<uint8_t> Wire(const std::vector<uint8_t>& raw_without_crc) {
  std::vector<uint8_t> raw = raw_without_crc;
  const uint32_t crc = proto_crc32(0, raw.data(), raw.size());
  for (int i = 0; i < 4; ++i) raw.push_back(static_cast<uint8_t>(crc >> (8 * i)));
  std::vector<uint8_t> wire(PROTO_COBS_MAX_ENCODED(raw.size()) + 1);
  const int n = proto_cobs_encode(raw.data(), raw.size(), wire.data(), wire.size());
  EXPECT_GT(n, 0);
  wire.resize(static_cast<size_t>(n));
  wire.push_back(0);
  return wire;
}

proto_msg_t OnlyAnswer(SimDevice& dev) {
  dev.Drain();
  EXPECT_EQ(dev.answers().size(), 1u);
  proto_msg_t m;
  proto_msg_init(&m, 0, 0);
  if (!dev.answers().empty()) m = dev.answers().back();
  dev.answers().clear();
  return m;
}

TEST(FirmwareDispatch, MalformedAndUnknownCommandsGetANack) {
  SimDevice dev;
  // Unknown type with a good CRC: NACK naming its seq.
  dev.SendBytes(Wire({PROTO_VERSION_MAJOR, 0x30, 0x34, 0x12}));
  proto_msg_t a = OnlyAnswer(dev);
  ExpectNack(a, PROTO_ST_UNKNOWN_TYPE);
  EXPECT_EQ(a.seq, 0x1234);
  EXPECT_EQ(a.body.ack.acked_seq, 0x1234);
  EXPECT_EQ(a.body.ack.acked_type, 0x30);
  // A device-to-host type sent to the device.
  dev.SendBytes(Wire({PROTO_VERSION_MAJOR, PROTO_ACK, 5, 0, 5, 0, PROTO_MOVE, 0, 0}));
  ExpectNack(OnlyAnswer(dev), PROTO_ST_UNKNOWN_TYPE);
  // MOVE with a 2-byte payload.
  dev.SendBytes(Wire({PROTO_VERSION_MAJOR, PROTO_MOVE, 6, 0, 1, 2}));
  ExpectNack(OnlyAnswer(dev), PROTO_ST_BAD_LENGTH);
  // Another major version.
  dev.SendBytes(Wire({PROTO_VERSION_MAJOR + 1, PROTO_PING, 7, 0, 1, 2, 3, 4, 5, 6, 7, 8}));
  ExpectNack(OnlyAnswer(dev), PROTO_ST_VERSION);
  // ... but GET_INFO works across majors, so the host can say which version the device speaks.
  dev.SendBytes(Wire({PROTO_VERSION_MAJOR + 1, PROTO_GET_INFO, 8, 0}));
  EXPECT_EQ(OnlyAnswer(dev).type, PROTO_INFO);
  // A flipped bit: bad CRC.
  std::vector<uint8_t> w = Wire({PROTO_VERSION_MAJOR, PROTO_PING, 9, 0, 1, 2, 3, 4, 5, 6, 7, 8});
  w[6] ^= 0x04;
  dev.SendBytes(w);
  ExpectNack(OnlyAnswer(dev), PROTO_ST_BAD_CRC);
  // Too short to hold a CRC, and a COBS code running past the end.
  dev.SendBytes({0x03, 0x01, 0x02, 0x00});
  ExpectNack(OnlyAnswer(dev), PROTO_ST_BAD_FRAME);
  dev.SendBytes({0x09, 0x01, 0x02, 0x00});
  ExpectNack(OnlyAnswer(dev), PROTO_ST_BAD_FRAME);
  // Longer than any frame.
  dev.SendBytes(std::vector<uint8_t>(300, 0x55));
  dev.SendBytes({0x00});
  ExpectNack(OnlyAnswer(dev), PROTO_ST_OVERFLOW);
  // Empty frames are ignored (a host may send 0x00 to resynchronise).
  dev.SendBytes({0x00, 0x00, 0x00});
  dev.Drain();
  EXPECT_TRUE(dev.answers().empty());
  // Values out of range name the field.
  proto_msg_t lasers = SimDevice::Make(PROTO_SET_LASERS);
  lasers.body.set_lasers.mask = 0x04;
  a = dev.Command(lasers);
  ExpectNack(a, PROTO_ST_BAD_VALUE);
  EXPECT_EQ(a.body.ack.detail, 1);
  a = dev.Command(Config(100, 50, 1000));
  ExpectNack(a, PROTO_ST_BAD_VALUE);
  EXPECT_EQ(a.body.ack.detail, 1);
  proto_msg_t bad_program = ScanProgram(10, 4);
  bad_program.body.program.shots[2].exposure_us = 0;
  a = dev.Command(bad_program);
  ExpectNack(a, PROTO_ST_BAD_VALUE);
  EXPECT_EQ(a.body.ack.detail, 8);
  // The device still works and counted the errors.
  const proto_msg_t status = dev.Command(SimDevice::Make(PROTO_GET_STATUS));
  EXPECT_EQ(status.type, PROTO_STATUS);
  EXPECT_EQ(status.body.status.rx_errors, 8u);  // the eight malformed frames above
}

TEST(FirmwareDispatch, RandomBytesNeverCrashTheDevice) {
  SimDevice dev;
  std::mt19937 rng(20261122);
  std::uniform_int_distribution<int> byte(0, 255);
  std::uniform_int_distribution<int> length(0, 200);
  for (int i = 0; i < 2000; ++i) {
    std::vector<uint8_t> junk(static_cast<size_t>(length(rng)));
    for (uint8_t& b : junk) b = static_cast<uint8_t>(byte(rng));
    if (i % 3 == 0) {  // a frame with a valid CRC and a random type and payload
      junk.resize(std::min<size_t>(junk.size(), 100));
      junk.insert(junk.begin(), {PROTO_VERSION_MAJOR, static_cast<uint8_t>(byte(rng) % 16), 1, 0});
      if (junk[1] == PROTO_ABORT || junk[1] == PROTO_START) junk[1] = PROTO_GET_STATUS;
      dev.SendBytes(Wire(junk));
    } else {
      junk.push_back(0);
      dev.SendBytes(junk);
    }
    dev.Advance(1000);
    dev.answers().clear();
  }
  EXPECT_EQ(dev.decode_errors(), 0);  // whatever came in, what went out decodes
  const proto_msg_t info = dev.Command(SimDevice::Make(PROTO_GET_INFO));
  EXPECT_EQ(info.type, PROTO_INFO);
}

TEST(FirmwareDispatch, ARetransmittedCommandIsAnsweredAgainButNotExecutedAgain) {
  SimDevice dev;
  ExpectAck(dev.Command(EnableMotor()), PROTO_MOTOR_ENABLE);
  dev.answers().clear();
  dev.Send(Move(100), 42);
  dev.Advance(1000);
  dev.Send(Move(100), 42);  // the host lost the ACK and sends the same frame again
  ASSERT_TRUE(dev.AdvanceUntil(PROTO_MOVE_DONE, 5000000));
  dev.Advance(1000000);
  ASSERT_EQ(dev.answers().size(), 2u);
  for (const proto_msg_t& a : dev.answers()) {
    ExpectAck(a, PROTO_MOVE);
    EXPECT_EQ(a.body.ack.acked_seq, 42);
  }
  EXPECT_EQ(EdgeTimes(SIM_PIN_STEP, 1).size(), 100u);
  EXPECT_EQ(dev.EventsOfType(PROTO_MOVE_DONE).size(), 1u);
  // A PING retransmission gets the very same PONG.
  dev.answers().clear();
  proto_msg_t ping = SimDevice::Make(PROTO_PING);
  dev.Send(ping, 43);
  dev.Advance(500);
  dev.Send(ping, 43);
  dev.Drain();
  ASSERT_EQ(dev.answers().size(), 2u);
  EXPECT_EQ(dev.answers()[0].body.pong.device_time_us, dev.answers()[1].body.pong.device_time_us);
  // The same seq with other contents is a new command.
  dev.answers().clear();
  dev.Send(Move(10), 42);
  dev.Drain();
  ASSERT_EQ(dev.answers().size(), 1u);
  ExpectAck(dev.answers()[0], PROTO_MOVE);
  ASSERT_TRUE(dev.AdvanceUntil(PROTO_MOVE_DONE, 5000000));
  EXPECT_EQ(EdgeTimes(SIM_PIN_STEP, 1).size(), 110u);
}

TEST(FirmwareDispatch, RefusesWhatTheStateDoesNotAllow) {
  SimDevice dev;
  ExpectNack(dev.Command(Move(10)), PROTO_ST_MOTOR_DISABLED);
  ExpectNack(dev.Command(Start(0)), PROTO_ST_NO_PROGRAM);
  ExpectAck(dev.Command(EnableMotor()), PROTO_MOTOR_ENABLE);
  ExpectAck(dev.Command(ScanProgram(5, 10)), PROTO_LOAD_PROGRAM);
  const proto_msg_t a = dev.Command(Start(5));
  ExpectNack(a, PROTO_ST_BAD_VALUE);
  EXPECT_EQ(a.body.ack.detail, 1);
  ExpectAck(dev.Command(Move(1000)), PROTO_MOVE);
  ExpectNack(dev.Command(Move(10)), PROTO_ST_BUSY);
  ExpectNack(dev.Command(Start(0)), PROTO_ST_BUSY);
  ExpectNack(dev.Command(Config(100, 1000, 1000)), PROTO_ST_BUSY);
  ExpectNack(dev.Command(ScanProgram(5, 10)), PROTO_ST_BUSY);
  proto_msg_t off = SimDevice::Make(PROTO_MOTOR_ENABLE);
  ExpectNack(dev.Command(off), PROTO_ST_BUSY);
  ASSERT_TRUE(dev.AdvanceUntil(PROTO_MOVE_DONE, 10000000, 10000));
  ExpectAck(dev.Command(off), PROTO_MOTOR_ENABLE);
  EXPECT_EQ(sim_pin_level(SIM_PIN_MOTOR_ENABLE), 0);
}

TEST(FirmwareDispatch, InfoDescribesTheDevice) {
  SimDevice dev;
  const proto_msg_t info = dev.Command(SimDevice::Make(PROTO_GET_INFO));
  ASSERT_EQ(info.type, PROTO_INFO);
  EXPECT_EQ(info.body.info.proto_major, PROTO_VERSION_MAJOR);
  EXPECT_EQ(info.body.info.proto_minor, PROTO_VERSION_MINOR);
  EXPECT_TRUE(info.body.info.capabilities & PROTO_CAP_SIMULATED);
  EXPECT_TRUE(info.body.info.capabilities & PROTO_CAP_EXPOSURE_IN);
  EXPECT_EQ(info.body.info.max_payload, PROTO_MAX_PAYLOAD);
  EXPECT_EQ(info.body.info.max_shots, PROTO_MAX_SHOTS);
  EXPECT_EQ(std::memcmp(info.body.info.uid, "ROTOSCANSIM1", 12), 0);
}

TEST(FirmwareDispatch, BootSendsAStatusEvent) {
  sim_reset();
  uint8_t buf[256];
  const size_t n = sim_usb_transmit(buf, sizeof(buf));
  ASSERT_GT(n, 0u);
  proto_msg_t m;
  ASSERT_EQ(proto_decode_frame(buf, n, &m), 0);
  EXPECT_EQ(m.type, PROTO_STATUS);
  EXPECT_EQ(m.body.status.cause, PROTO_CAUSE_BOOT);
  EXPECT_EQ(m.body.status.status_seq, 0u);
}

}  // namespace
}  // namespace rotoscan::firmware_test

namespace rotoscan::firmware_test {
namespace {

// fw_report: what a port has to say after boot (the STM32F411 port: a fault recorded before the reset) as a
// LOG event, the two values in hexadecimal, cut to the LOG's 64 characters.
TEST(FirmwareReport, PortMessagesBecomeLogEventsWithHexValues) {
  SimDevice dev;
  fw_report(FW_REPORT_ERROR, "fault before reset: vector, pc", 3u, 0x080012A4u);
  const std::string long_text = "a message long enough that the two values no longer fit in the LOG line";
  ASSERT_GT(long_text.size(), size_t{PROTO_MAX_LOG_TEXT});
  fw_report(FW_REPORT_WARNING, long_text.c_str(), 1u, 2u);
  dev.Drain();
  const std::vector<proto_msg_t> logs = dev.EventsOfType(PROTO_LOG);
  ASSERT_EQ(logs.size(), 2u);
  EXPECT_EQ(logs[0].body.log.level, PROTO_LOG_ERROR);
  EXPECT_EQ(std::string(logs[0].body.log.text, logs[0].body.log.length),
            "fault before reset: vector, pc 0x00000003 0x080012a4");
  EXPECT_EQ(logs[1].body.log.level, PROTO_LOG_WARNING);
  EXPECT_EQ(logs[1].body.log.length, PROTO_MAX_LOG_TEXT);
  EXPECT_EQ(std::string(logs[1].body.log.text, logs[1].body.log.length), long_text.substr(0, PROTO_MAX_LOG_TEXT));
}

}  // namespace
}  // namespace rotoscan::firmware_test

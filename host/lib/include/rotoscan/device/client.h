// The host side of the board protocol (protocol/include/rotoscan_protocol.h) over any Transport.
//
//  * Connect(): opens the transport, asks GET_INFO and refuses a board whose protocol major differs from
//    the host's, with a message saying which side to update.
//  * Commands are acknowledged. A command not answered within `ack_timeout_us` is sent again with the same
//    seq (the board answers a duplicate without executing it twice), up to `retries` times; a NACK saying
//    the frame arrived damaged (BAD_CRC, BAD_FRAME) is retransmitted at once. Answers to older seqs (from
//    retransmissions) are ignored.
//  * Events (TRIGGER_EVENT, MOVE_DONE, STATUS, LOG) read while waiting for an answer are queued, never
//    dropped; NextEvent() hands them out in order. Gaps in the board's own counters (trigger_seq, move_seq,
//    status_seq) are counted in stats() as lost events.
//  * Unplug: when the transport reports the board gone, the client re-opens it for up to
//    `reconnect_timeout_us` and carries on with the command it was sending (same seq). The board keeps its
//    state across a USB re-plug; a scan program stopped by the laser-safety timeout in the meantime is
//    resumed with ResumeProgram() (GET_STATUS says the next step, START(first_step) takes it).
//  * Clock: Ping() gives one round-trip sample, SyncClock() a fit of offset and drift (clock_sync.h).
//
// Not thread-safe: one thread owns a Client.
#pragma once

#include <cstdint>
#include <deque>
#include <memory>
#include <optional>
#include <string>
#include <variant>
#include <vector>

#include "rotoscan/core/status.h"
#include "rotoscan/device/clock_sync.h"
#include "rotoscan/device/transport.h"

namespace rotoscan::device {

struct ClientOptions {
  int64_t ack_timeout_us = 100'000;          // answer wait before the same seq is sent again
  int retries = 5;                           // retransmissions before a command fails with Timeout
  int64_t reconnect_timeout_us = 5'000'000;  // how long to try re-opening a board that went away
  int64_t reconnect_interval_us = 20'000;
  Status Check() const;
};

struct DeviceInfo {
  int protocol_major = 0;
  int protocol_minor = 0;
  uint32_t capabilities = 0;     // PROTO_CAP_* bits
  std::string firmware_version;  // "1.2.3"
  int max_payload = 0;
  int max_shots = 0;
  std::string uid;         // the MCU's unique id, hex
  bool simulated = false;  // the host-built firmware, not a board
};

struct MotionConfig {
  uint32_t start_rate_hz = 200;
  uint32_t max_rate_hz = 2000;
  uint32_t accel_hz_per_s = 20000;
  uint32_t trigger_pulse_us = 100;
  uint32_t laser_timeout_ms = 2000;  // lasers off and program stopped after this much host silence
  bool invert_direction = false;
};

struct Shot {
  uint8_t laser_mask = 0;  // kLaserLeft | kLaserRight
  uint32_t exposure_us = 10'000;
};

inline constexpr uint8_t kLaserLeft = 1u << 0;
inline constexpr uint8_t kLaserRight = 1u << 1;

// A scan program: the board takes `step_count` table steps of `steps_per_move` motor steps, and at each
// the listed shots, with no host round trip per frame.
struct ScanProgram {
  uint32_t step_count = 1;
  int32_t steps_per_move = 1;
  uint32_t settle_us = 0;
  uint32_t laser_lead_us = 0;
  std::vector<Shot> shots;
  Status Check() const;
};

struct TriggerEvent {
  uint32_t trigger_seq = 0;
  uint64_t time_us = 0;  // board clock at the trigger edge
  std::optional<uint64_t> exposure_seen_us;
  int32_t position = 0;                // motor steps at the edge
  std::optional<uint32_t> step_index;  // in a program
  uint8_t laser_mask = 0;
  uint8_t shot = 0;
  int64_t host_receive_us = 0;
  // Which START of this client produced it (1 for the first): a resumed program retakes the step it was
  // stopped in, and the shots of the later run replace those of the earlier one.
  uint32_t run = 0;
};

struct MoveDoneEvent {
  uint32_t move_seq = 0;
  uint64_t time_us = 0;
  int32_t position = 0;
  bool aborted = false;
};

enum class BoardState { kIdle, kMoving, kRunning, kTrigger };
enum class StatusCause { kReply, kProgramDone, kAborted, kSafety, kBoot };

struct BoardStatus {
  uint32_t status_seq = 0;
  uint64_t time_us = 0;
  StatusCause cause = StatusCause::kReply;
  BoardState state = BoardState::kIdle;
  bool motor_enabled = false;
  bool program_loaded = false;
  bool safety_tripped = false;
  uint8_t lasers = 0;
  int32_t position = 0;
  uint32_t program_next_step = 0;
  uint32_t program_steps = 0;
  uint32_t trigger_count = 0;
  uint32_t rx_errors = 0;
  uint32_t events_dropped = 0;
};

// GET_DIAG (protocol 1.1): what the board measures about itself.
struct BoardDiag {
  // The step interrupt's cost in CPU cycles (DWT on the STM32F411), when the board counts them.
  std::optional<uint32_t> cpu_hz;
  std::optional<uint32_t> step_isr_cycles_max;
  std::optional<uint32_t> step_isr_cycles_last;
  // The fault recorded before the last reset, if there was one (HardFault or an interrupt without handler).
  struct Fault {
    uint32_t count = 0;
    uint32_t vector = 0;  // 3 = HardFault, 16 + n = interrupt n
    uint32_t pc = 0, lr = 0, psr = 0, cfsr = 0, hfsr = 0;
  };
  std::optional<Fault> fault;
};

struct LogEvent {
  int level = 0;
  std::string text;
};

using Event = std::variant<TriggerEvent, MoveDoneEvent, BoardStatus, LogEvent>;

struct ClientStats {
  int commands = 0;
  int retransmits = 0;
  int reconnects = 0;
  int frames_dropped = 0;  // received frames that did not decode (CRC, COBS, length)
  int stale_answers = 0;   // answers to a seq already answered (duplicates) or not ours
  int lost_events = 0;     // from gaps in the board's event counters
};

class Client {
 public:
  static Result<std::unique_ptr<Client>> Connect(std::unique_ptr<Transport> transport,
                                                 const ClientOptions& options = {});
  ~Client();
  Client(const Client&) = delete;
  Client& operator=(const Client&) = delete;

  const DeviceInfo& info() const { return info_; }
  const ClientStats& stats() const { return stats_; }
  Transport& transport() { return *transport_; }

  Result<PingSample> Ping();
  // `pings` round trips, then FitClock(). pings >= options.min_samples.
  Result<ClockFit> SyncClock(int pings, const ClockFitOptions& options = {});

  Status SetConfig(const MotionConfig& config);
  Status EnableMotor(bool enable);
  Status Move(int32_t steps);  // acknowledged at once; a MoveDoneEvent follows
  // Move and wait for its MoveDoneEvent (other events meanwhile stay queued).
  Result<MoveDoneEvent> MoveAndWait(int32_t steps, int64_t timeout_us);
  Status SetLasers(uint8_t mask);
  Status Trigger(uint8_t laser_mask, uint32_t laser_lead_us, uint32_t exposure_us);
  Status LoadProgram(const ScanProgram& program);
  Status Start(uint32_t first_step = 0);
  Status Abort();
  Result<BoardStatus> GetStatus();
  // Unimplemented on a board without PROTO_CAP_DIAG (protocol 1.0).
  Result<BoardDiag> GetDiag();
  // After an interruption: GET_STATUS, and START at the step the board says comes next, if the program
  // did not finish. Returns the step it resumed at, or nullopt when nothing was left to do.
  Result<std::optional<uint32_t>> ResumeProgram();

  // The next event, waiting up to `timeout_us`; nullopt on timeout.
  Result<std::optional<Event>> NextEvent(int64_t timeout_us);

 private:
  Client(std::unique_ptr<Transport> transport, const ClientOptions& options);
  struct Message;  // a decoded proto_msg_t, kept out of this header
  Status Command(const Message& request, Message* answer);
  Status Send(const std::vector<uint8_t>& frame);
  Status ReadSome(int64_t timeout_us);
  Status Reconnect();
  void Dispatch(const Message& message);

  std::unique_ptr<Transport> transport_;
  ClientOptions options_;
  DeviceInfo info_;
  ClientStats stats_;
  uint16_t next_seq_ = 1;
  std::vector<uint8_t> rx_frame_;  // stuffed bytes of the frame being received
  bool rx_overflow_ = false;
  uint64_t rx_bytes_ = 0;                         // bytes received in all
  std::deque<std::unique_ptr<Message>> answers_;  // replies not yet matched to a command
  std::deque<Event> events_;
  std::optional<uint32_t> last_trigger_seq_, last_move_seq_, last_status_seq_;
  uint32_t run_ = 0;                        // STARTs acknowledged so far
  std::optional<uint16_t> last_start_seq_;  // seq of the last START counted in run_
};

}  // namespace rotoscan::device

// Client for the board protocol; see client.h for the behaviour.
//
// Design notes:
//  * Receiving: bytes from the transport go through a COBS deframer (split on 0x00) and
//    proto_decode_frame(). A frame that does not decode is counted and dropped; the stream resynchronises
//    at the next 0x00 by construction. Replies (ACK, NACK, INFO, PONG, STATUS with cause REPLY) go to
//    `answers_`, everything else is an event and goes to `events_`.
//  * Command(): one seq per command; the encoded frame is kept and re-sent unchanged on timeout, on a NACK
//    for a damaged frame, and after a reconnect. An answer is accepted only if its seq is the command's and
//    its type fits the command (an ACK/NACK must also name the command's type); anything else is stale.
//  * Time comes from the transport (NowUs), so the in-process transport gives virtual, repeatable timing.
#include "rotoscan/device/client.h"

#include <chrono>
#include <cstdio>
#include <thread>
#include <utility>

#include "rotoscan/core/check.h"
#include "rotoscan/core/logging.h"
#include "rotoscan_protocol.h"

namespace rotoscan::device {

struct Client::Message {
  proto_msg_t msg;
};

namespace {

bool IsReply(const proto_msg_t& m) {
  return m.type == PROTO_ACK || m.type == PROTO_NACK || m.type == PROTO_INFO || m.type == PROTO_PONG ||
         m.type == PROTO_DIAG || (m.type == PROTO_STATUS && m.body.status.cause == PROTO_CAUSE_REPLY);
}

// Whether `answer` answers `request` (same seq is checked by the caller).
bool Answers(const proto_msg_t& request, const proto_msg_t& answer) {
  switch (answer.type) {
    case PROTO_ACK:
    case PROTO_NACK: return answer.body.ack.acked_type == request.type || answer.body.ack.acked_type == 0;
    case PROTO_INFO: return request.type == PROTO_GET_INFO;
    case PROTO_PONG: return request.type == PROTO_PING;
    case PROTO_STATUS: return request.type == PROTO_GET_STATUS;
    case PROTO_DIAG: return request.type == PROTO_GET_DIAG;
    default: return false;
  }
}

BoardStatus ToBoardStatus(const proto_status_t& s) {
  BoardStatus b;
  b.status_seq = s.status_seq;
  b.time_us = s.time_us;
  switch (s.cause) {
    case PROTO_CAUSE_PROGRAM_DONE: b.cause = StatusCause::kProgramDone; break;
    case PROTO_CAUSE_ABORTED: b.cause = StatusCause::kAborted; break;
    case PROTO_CAUSE_SAFETY: b.cause = StatusCause::kSafety; break;
    case PROTO_CAUSE_BOOT: b.cause = StatusCause::kBoot; break;
    default: b.cause = StatusCause::kReply; break;
  }
  switch (s.state) {
    case PROTO_STATE_MOVING: b.state = BoardState::kMoving; break;
    case PROTO_STATE_RUNNING: b.state = BoardState::kRunning; break;
    case PROTO_STATE_TRIGGER: b.state = BoardState::kTrigger; break;
    default: b.state = BoardState::kIdle; break;
  }
  b.motor_enabled = (s.flags & PROTO_FLAG_MOTOR_ENABLED) != 0;
  b.program_loaded = (s.flags & PROTO_FLAG_PROGRAM_LOADED) != 0;
  b.safety_tripped = (s.flags & PROTO_FLAG_SAFETY_TRIPPED) != 0;
  b.lasers = s.lasers;
  b.position = s.position;
  b.program_next_step = s.program_next_step;
  b.program_steps = s.program_steps;
  b.trigger_count = s.trigger_count;
  b.rx_errors = s.rx_errors;
  b.events_dropped = s.events_dropped;
  return b;
}

// Counts the events missing between `last` and `now` of a wrapping 32-bit counter, and remembers `now`.
int CounterGap(std::optional<uint32_t>* last, uint32_t now) {
  int gap = 0;
  if (*last) {
    const uint32_t delta = now - **last;
    if (delta != 0 && delta < 0x80000000u) gap = static_cast<int>(delta - 1);
  }
  *last = now;
  return gap;
}

}  // namespace

Status ClientOptions::Check() const {
  if (ack_timeout_us <= 0) return InvalidArgumentError("device client: ack_timeout_us must be > 0");
  if (retries < 0) return InvalidArgumentError("device client: retries must be >= 0");
  if (reconnect_timeout_us < 0)
    return InvalidArgumentError("device client: reconnect_timeout_us must be >= 0");
  if (reconnect_interval_us <= 0)
    return InvalidArgumentError("device client: reconnect_interval_us must be > 0");
  return Status::Ok();
}

Status ScanProgram::Check() const {
  if (step_count < 1 || step_count > PROTO_MAX_PROGRAM_STEPS) {
    return InvalidArgumentError("scan program: step_count must be in 1.." +
                                std::to_string(PROTO_MAX_PROGRAM_STEPS));
  }
  if (steps_per_move > PROTO_MAX_MOVE_STEPS || steps_per_move < -PROTO_MAX_MOVE_STEPS) {
    return InvalidArgumentError("scan program: |steps_per_move| must be <= " +
                                std::to_string(PROTO_MAX_MOVE_STEPS));
  }
  if (shots.empty() || shots.size() > PROTO_MAX_SHOTS) {
    return InvalidArgumentError("scan program: 1.." + std::to_string(PROTO_MAX_SHOTS) + " shots per step");
  }
  for (size_t i = 0; i < shots.size(); ++i) {
    if ((shots[i].laser_mask & ~PROTO_LASER_ALL) != 0) {
      return InvalidArgumentError("scan program: shot " + std::to_string(i) + " has an unknown laser bit");
    }
    if (shots[i].exposure_us < 1 || shots[i].exposure_us > 10'000'000) {
      return InvalidArgumentError("scan program: shot " + std::to_string(i) +
                                  " exposure_us must be in 1..1e7");
    }
  }
  if (settle_us > 10'000'000) return InvalidArgumentError("scan program: settle_us must be <= 1e7");
  if (laser_lead_us > 1'000'000) return InvalidArgumentError("scan program: laser_lead_us must be <= 1e6");
  return Status::Ok();
}

Client::Client(std::unique_ptr<Transport> transport, const ClientOptions& options)
    : transport_(std::move(transport)), options_(options) {}

Client::~Client() = default;

Result<std::unique_ptr<Client>> Client::Connect(std::unique_ptr<Transport> transport,
                                                const ClientOptions& options) {
  ROTOSCAN_CHECK(transport != nullptr);
  ROTOSCAN_RETURN_IF_ERROR(options.Check());
  std::unique_ptr<Client> client(new Client(std::move(transport), options));
  if (!client->transport_->IsOpen()) ROTOSCAN_RETURN_IF_ERROR(client->transport_->Open());
  Message request;
  proto_msg_init(&request.msg, PROTO_GET_INFO, 0);
  Message answer;
  ROTOSCAN_RETURN_IF_ERROR(client->Command(request, &answer).WithContext("GET_INFO"));
  const proto_info_t& info = answer.msg.body.info;
  if (info.proto_major != PROTO_VERSION_MAJOR) {
    return FailedPreconditionError(
        "the board speaks protocol " + std::to_string(info.proto_major) + "." +
        std::to_string(info.proto_minor) + " but this host speaks " + std::to_string(PROTO_VERSION_MAJOR) +
        "." + std::to_string(PROTO_VERSION_MINOR) +
        (info.proto_major > PROTO_VERSION_MAJOR ? ": update the host software"
                                                : ": update the board's firmware") +
        " (refusing to talk to it)");
  }
  DeviceInfo& out = client->info_;
  out.protocol_major = info.proto_major;
  out.protocol_minor = info.proto_minor;
  out.capabilities = info.capabilities;
  out.firmware_version = std::to_string(info.fw_major) + "." + std::to_string(info.fw_minor) + "." +
                         std::to_string(info.fw_patch);
  out.max_payload = info.max_payload;
  out.max_shots = info.max_shots;
  out.simulated = (info.capabilities & PROTO_CAP_SIMULATED) != 0;
  for (uint8_t byte : info.uid) {
    char hex[3];
    std::snprintf(hex, sizeof(hex), "%02x", byte);
    out.uid += hex;
  }
  return client;
}

Status Client::Send(const std::vector<uint8_t>& frame) {
  Status status = transport_->Write(frame);
  if (status.code() == StatusCode::kDeviceError) {
    ROTOSCAN_RETURN_IF_ERROR(Reconnect());
    status = transport_->Write(frame);
  }
  return status;
}

Status Client::Reconnect() {
  const int64_t deadline = transport_->NowUs() + options_.reconnect_timeout_us;
  ROTOSCAN_LOG(kWarning) << transport_->Description() << ": board gone, re-opening";
  // Keep what arrived before the board went: the transport drops unread bytes when it closes. A frame cut
  // in half stays in rx_frame_: a board that kept its state goes on with the rest of it after the re-plug.
  for (int i = 0; i < 1000; ++i) {
    const size_t before = rx_bytes_;
    if (!ReadSome(0).ok() || rx_bytes_ == before) break;
  }
  Status last;
  while (true) {
    transport_->Close();
    last = transport_->Open();
    if (last.ok()) {
      ++stats_.reconnects;
      ROTOSCAN_LOG(kInfo) << transport_->Description() << ": board back";
      return Status::Ok();
    }
    if (transport_->NowUs() >= deadline) break;
    std::this_thread::sleep_for(std::chrono::microseconds(options_.reconnect_interval_us));
  }
  return DeviceError("the board went away and did not come back within " +
                     std::to_string(options_.reconnect_timeout_us / 1000) + " ms: " + last.message());
}

Status Client::ReadSome(int64_t timeout_us) {
  std::vector<uint8_t> bytes;
  Status status = transport_->Read(&bytes, timeout_us);
  const int64_t now = transport_->NowUs();
  rx_bytes_ += bytes.size();
  for (uint8_t byte : bytes) {
    if (byte != 0) {
      if (rx_frame_.size() < PROTO_MAX_WIRE_FRAME) {
        rx_frame_.push_back(byte);
      } else {
        rx_overflow_ = true;
      }
      continue;
    }
    if (rx_frame_.empty() && !rx_overflow_) continue;  // an empty frame: resynchronisation
    Message m;
    const int result =
        rx_overflow_ ? -EMSGSIZE : proto_decode_frame(rx_frame_.data(), rx_frame_.size(), &m.msg);
    rx_frame_.clear();
    rx_overflow_ = false;
    if (result != 0) {
      ++stats_.frames_dropped;
      ROTOSCAN_LOG(kDebug) << "dropped a frame from the board (error " << result << ")";
      continue;
    }
    if (m.msg.type == PROTO_TRIGGER_EVENT) {
      const proto_trigger_event_t& t = m.msg.body.trigger_event;
      TriggerEvent e;
      e.trigger_seq = t.trigger_seq;
      e.time_us = t.time_us;
      if (t.flags & PROTO_TRIG_EXPOSURE_SEEN) e.exposure_seen_us = t.exposure_seen_us;
      e.position = t.position;
      if (t.flags & PROTO_TRIG_IN_PROGRAM) e.step_index = t.step_index;
      e.laser_mask = t.laser_mask;
      e.shot = t.shot;
      e.host_receive_us = now;
      e.run = run_;
      stats_.lost_events += CounterGap(&last_trigger_seq_, t.trigger_seq);
      events_.emplace_back(e);
    } else if (m.msg.type == PROTO_MOVE_DONE) {
      const proto_move_done_t& d = m.msg.body.move_done;
      stats_.lost_events += CounterGap(&last_move_seq_, d.move_seq);
      events_.emplace_back(
          MoveDoneEvent{d.move_seq, d.time_us, d.position, (d.status & PROTO_MOVE_ABORTED) != 0});
    } else if (IsReply(m.msg)) {
      // Events after a START's ACK in the stream belong to the run it started (count each START once).
      if (m.msg.type == PROTO_ACK && m.msg.body.ack.acked_type == PROTO_START &&
          last_start_seq_ != m.msg.seq) {
        last_start_seq_ = m.msg.seq;
        ++run_;
      }
      if (m.msg.type == PROTO_STATUS)
        stats_.lost_events += CounterGap(&last_status_seq_, m.msg.body.status.status_seq);
      answers_.push_back(std::make_unique<Message>(m));
    } else if (m.msg.type == PROTO_STATUS) {
      stats_.lost_events += CounterGap(&last_status_seq_, m.msg.body.status.status_seq);
      events_.emplace_back(ToBoardStatus(m.msg.body.status));
    } else if (m.msg.type == PROTO_LOG) {
      events_.emplace_back(LogEvent{m.msg.body.log.level, std::string(m.msg.body.log.text)});
    } else {
      ++stats_.stale_answers;
    }
  }
  return status;
}

Status Client::Command(const Message& request_in, Message* answer) {
  Message request = request_in;
  request.msg.seq = next_seq_++;
  if (next_seq_ == 0) next_seq_ = 1;
  std::vector<uint8_t> frame(PROTO_MAX_WIRE_FRAME);
  const int size = proto_encode_frame(&request.msg, frame.data(), frame.size());
  ROTOSCAN_CHECK(size > 0) << "encoding " << proto_type_name(request.msg.type) << ": error " << size;
  frame.resize(static_cast<size_t>(size));
  ++stats_.commands;
  const char* name = proto_type_name(request.msg.type);
  for (int attempt = 0; attempt <= options_.retries; ++attempt) {
    if (attempt > 0) ++stats_.retransmits;
    ROTOSCAN_RETURN_IF_ERROR(Send(frame).WithContext(name));
    const int64_t deadline = transport_->NowUs() + options_.ack_timeout_us;
    bool resend = false;
    while (!resend) {
      while (!answers_.empty()) {
        std::unique_ptr<Message> a = std::move(answers_.front());
        answers_.pop_front();
        if (a->msg.seq != request.msg.seq || !Answers(request.msg, a->msg)) {
          // A damaged-frame NACK may carry a damaged seq: it can only be about the frame in flight.
          if (a->msg.type == PROTO_NACK &&
              (a->msg.body.ack.status == PROTO_ST_BAD_CRC || a->msg.body.ack.status == PROTO_ST_BAD_FRAME)) {
            resend = true;
            break;
          }
          ++stats_.stale_answers;
          continue;
        }
        if (a->msg.type == PROTO_NACK) {
          const proto_ack_t& nack = a->msg.body.ack;
          if (nack.status == PROTO_ST_BAD_CRC || nack.status == PROTO_ST_BAD_FRAME ||
              nack.status == PROTO_ST_OVERFLOW) {
            resend = true;
            break;
          }
          std::string message =
              std::string(name) + " refused by the board: " + proto_status_name(nack.status);
          if (nack.status == PROTO_ST_BAD_VALUE) message += " (field " + std::to_string(nack.detail) + ")";
          return DeviceError(message);
        }
        *answer = *a;
        return Status::Ok();
      }
      if (resend) break;
      const int64_t now = transport_->NowUs();
      if (now >= deadline) break;
      Status status = ReadSome(deadline - now);
      if (status.code() == StatusCode::kDeviceError) {
        ROTOSCAN_RETURN_IF_ERROR(Reconnect().WithContext(name));
        break;  // send the same frame again on the re-opened board
      }
      ROTOSCAN_RETURN_IF_ERROR(status);
    }
  }
  return TimeoutError(std::string(name) + ": no answer from the board after " +
                      std::to_string(options_.retries + 1) + " tries of " +
                      std::to_string(options_.ack_timeout_us / 1000) + " ms");
}

Result<std::optional<Event>> Client::NextEvent(int64_t timeout_us) {
  const int64_t deadline = transport_->NowUs() + timeout_us;
  while (events_.empty()) {
    const int64_t now = transport_->NowUs();
    if (now >= deadline) return std::optional<Event>();
    Status status = ReadSome(deadline - now);
    if (status.code() == StatusCode::kDeviceError) {
      ROTOSCAN_RETURN_IF_ERROR(Reconnect());
      continue;
    }
    ROTOSCAN_RETURN_IF_ERROR(status);
    answers_.clear();  // replies nobody waits for are stale
  }
  Event e = std::move(events_.front());
  events_.pop_front();
  return std::optional<Event>(std::move(e));
}

Result<PingSample> Client::Ping() {
  Message request, answer;
  proto_msg_init(&request.msg, PROTO_PING, 0);
  PingSample sample;
  sample.host_send_us = transport_->NowUs();
  request.msg.body.ping.host_time_us = static_cast<uint64_t>(sample.host_send_us);
  ROTOSCAN_RETURN_IF_ERROR(Command(request, &answer));
  sample.host_receive_us = transport_->NowUs();
  // A retransmitted PING is answered with the echo of the first one: its round trip is not measured right.
  if (answer.msg.body.pong.host_time_us != static_cast<uint64_t>(sample.host_send_us)) {
    return DeviceError("PONG echoed another host time than the PING sent");
  }
  sample.device_us = answer.msg.body.pong.device_time_us;
  return sample;
}

Result<ClockFit> Client::SyncClock(int pings, const ClockFitOptions& options) {
  ROTOSCAN_RETURN_IF_ERROR(options.Check());
  if (pings < options.min_samples) {
    return InvalidArgumentError("clock sync: " + std::to_string(pings) + " pings, need at least " +
                                std::to_string(options.min_samples));
  }
  std::vector<PingSample> samples;
  for (int i = 0; i < pings; ++i) {
    Result<PingSample> sample = Ping();
    if (!sample.ok()) return sample.status().WithContext("clock sync, ping " + std::to_string(i));
    samples.push_back(*sample);
  }
  return FitClock(samples, options);
}

Status Client::SetConfig(const MotionConfig& config) {
  Message request, answer;
  proto_msg_init(&request.msg, PROTO_SET_CONFIG, 0);
  proto_config_t& c = request.msg.body.config;
  c.start_rate_hz = config.start_rate_hz;
  c.max_rate_hz = config.max_rate_hz;
  c.accel_hz_per_s = config.accel_hz_per_s;
  c.trigger_pulse_us = config.trigger_pulse_us;
  c.laser_timeout_ms = config.laser_timeout_ms;
  c.flags = config.invert_direction ? PROTO_CONFIG_INVERT_DIR : 0;
  return Command(request, &answer);
}

Status Client::EnableMotor(bool enable) {
  Message request, answer;
  proto_msg_init(&request.msg, PROTO_MOTOR_ENABLE, 0);
  request.msg.body.motor_enable.enable = enable ? 1 : 0;
  return Command(request, &answer);
}

Status Client::Move(int32_t steps) {
  if (steps > PROTO_MAX_MOVE_STEPS || steps < -PROTO_MAX_MOVE_STEPS) {
    return InvalidArgumentError("move: |steps| must be <= " + std::to_string(PROTO_MAX_MOVE_STEPS));
  }
  Message request, answer;
  proto_msg_init(&request.msg, PROTO_MOVE, 0);
  request.msg.body.move.steps = steps;
  return Command(request, &answer);
}

Result<MoveDoneEvent> Client::MoveAndWait(int32_t steps, int64_t timeout_us) {
  const size_t queued_before = events_.size();
  ROTOSCAN_RETURN_IF_ERROR(Move(steps));
  const int64_t deadline = transport_->NowUs() + timeout_us;
  size_t checked = queued_before;  // MOVE_DONEs queued before belong to earlier moves
  while (true) {
    for (; checked < events_.size(); ++checked) {
      if (const auto* done = std::get_if<MoveDoneEvent>(&events_[checked])) {
        MoveDoneEvent result = *done;
        events_.erase(events_.begin() + static_cast<std::ptrdiff_t>(checked));
        if (result.aborted) return DeviceError("move aborted at position " + std::to_string(result.position));
        return result;
      }
    }
    const int64_t now = transport_->NowUs();
    if (now >= deadline)
      return TimeoutError("move of " + std::to_string(steps) + " steps did not end in time");
    Status status = ReadSome(deadline - now);
    if (status.code() == StatusCode::kDeviceError) {
      ROTOSCAN_RETURN_IF_ERROR(Reconnect());
      continue;
    }
    ROTOSCAN_RETURN_IF_ERROR(status);
    answers_.clear();
  }
}

Status Client::SetLasers(uint8_t mask) {
  if ((mask & ~PROTO_LASER_ALL) != 0) return InvalidArgumentError("lasers: unknown bit in mask");
  Message request, answer;
  proto_msg_init(&request.msg, PROTO_SET_LASERS, 0);
  request.msg.body.set_lasers.mask = mask;
  return Command(request, &answer);
}

Status Client::Trigger(uint8_t laser_mask, uint32_t laser_lead_us, uint32_t exposure_us) {
  Message request, answer;
  proto_msg_init(&request.msg, PROTO_TRIGGER, 0);
  request.msg.body.trigger.laser_mask = laser_mask;
  request.msg.body.trigger.laser_lead_us = laser_lead_us;
  request.msg.body.trigger.exposure_us = exposure_us;
  return Command(request, &answer);
}

Status Client::LoadProgram(const ScanProgram& program) {
  ROTOSCAN_RETURN_IF_ERROR(program.Check());
  Message request, answer;
  proto_msg_init(&request.msg, PROTO_LOAD_PROGRAM, 0);
  proto_program_t& p = request.msg.body.program;
  p.step_count = program.step_count;
  p.steps_per_move = program.steps_per_move;
  p.settle_us = program.settle_us;
  p.laser_lead_us = program.laser_lead_us;
  p.shot_count = static_cast<uint8_t>(program.shots.size());
  for (size_t i = 0; i < program.shots.size(); ++i) {
    p.shots[i].laser_mask = program.shots[i].laser_mask;
    p.shots[i].exposure_us = program.shots[i].exposure_us;
  }
  return Command(request, &answer);
}

Status Client::Start(uint32_t first_step) {
  Message request, answer;
  proto_msg_init(&request.msg, PROTO_START, 0);
  request.msg.body.start.first_step = first_step;
  return Command(request, &answer);
}

Status Client::Abort() {
  Message request, answer;
  proto_msg_init(&request.msg, PROTO_ABORT, 0);
  return Command(request, &answer);
}

Result<BoardStatus> Client::GetStatus() {
  Message request, answer;
  proto_msg_init(&request.msg, PROTO_GET_STATUS, 0);
  ROTOSCAN_RETURN_IF_ERROR(Command(request, &answer));
  return ToBoardStatus(answer.msg.body.status);
}

Result<BoardDiag> Client::GetDiag() {
  if (!(info_.capabilities & PROTO_CAP_DIAG)) {
    return FailedPreconditionError(
        "the board does not answer GET_DIAG (protocol " + std::to_string(info_.protocol_major) + "." +
        std::to_string(info_.protocol_minor) + ", capability 'diag' not advertised)");
  }
  Message request, answer;
  proto_msg_init(&request.msg, PROTO_GET_DIAG, 0);
  ROTOSCAN_RETURN_IF_ERROR(Command(request, &answer));
  const proto_diag_t& d = answer.msg.body.diag;
  BoardDiag out;
  if (d.flags & PROTO_DIAG_CYCLES_VALID) {
    out.cpu_hz = d.cpu_hz;
    out.step_isr_cycles_max = d.step_isr_cycles_max;
    out.step_isr_cycles_last = d.step_isr_cycles_last;
  }
  if (d.flags & PROTO_DIAG_FAULT_VALID) {
    BoardDiag::Fault f;
    f.count = d.fault_count;
    f.vector = d.fault_vector;
    f.pc = d.fault_pc;
    f.lr = d.fault_lr;
    f.psr = d.fault_psr;
    f.cfsr = d.fault_cfsr;
    f.hfsr = d.fault_hfsr;
    out.fault = f;
  }
  return out;
}

Result<std::optional<uint32_t>> Client::ResumeProgram() {
  Result<BoardStatus> status = GetStatus();
  if (!status.ok()) return status.status();
  if (status->state == BoardState::kRunning) return std::optional<uint32_t>();
  if (!status->program_loaded) return FailedPreconditionError("resume: the board has no program loaded");
  if (status->program_next_step >= status->program_steps) return std::optional<uint32_t>();
  ROTOSCAN_RETURN_IF_ERROR(Start(status->program_next_step));
  return std::optional<uint32_t>(status->program_next_step);
}

}  // namespace rotoscan::device

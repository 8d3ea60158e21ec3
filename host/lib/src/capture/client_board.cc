#include "client_board.h"

#include <algorithm>
#include <cmath>

#include "rotoscan/core/logging.h"

namespace rotoscan::capture::internal {

namespace {
constexpr double kPi = 3.14159265358979323846;
constexpr int64_t kMoveTimeoutUs = 30'000'000;
constexpr int64_t kStaleMarginUs = 5'000;
}  // namespace

Result<std::unique_ptr<ClientBoard>> ClientBoard::Create(std::unique_ptr<device::Client> client,
                                                         std::shared_ptr<Clock> clock, BoardInfo info,
                                                         const ClientBoardOptions& options) {
  if (options.steps_per_rev <= 0) return InvalidArgumentError("board: steps_per_rev must be positive");
  std::unique_ptr<ClientBoard> board(new ClientBoard(std::move(client), std::move(clock), std::move(info), options));
  device::Client& c = *board->client_;
  ROTOSCAN_RETURN_IF_ERROR(c.SetConfig(options.motion));
  if (options.clock_pings < options.clock_fit.min_samples) {
    return InvalidArgumentError("board: clock_pings must be at least clock_fit.min_samples");
  }
  for (int i = 0; i < options.clock_pings; ++i) {
    auto sample = c.Ping();
    if (!sample.ok()) return sample.status().WithContext("clock sync, ping " + std::to_string(i));
    board->samples_.push_back(*sample);
  }
  device::ClockFitOptions offset_only = options.clock_fit;
  offset_only.fit_drift = false;
  ROTOSCAN_ASSIGN_OR_RETURN(board->fit_, device::FitClock(board->samples_, offset_only));
  ROTOSCAN_ASSIGN_OR_RETURN(const device::BoardStatus status, c.GetStatus());
  board->position_ = status.position;
  board->lasers_ = status.lasers;
  board->capabilities_.trigger_output = true;
  board->capabilities_.exposure_input = true;
  board->capabilities_.device_clock = true;
  board->capabilities_.degrees_per_step = 360.0 / options.steps_per_rev;
  board->capabilities_.lasers = 2;
  return board;
}

ClientBoard::ClientBoard(std::unique_ptr<device::Client> client, std::shared_ptr<Clock> clock, BoardInfo info,
                         const ClientBoardOptions& options)
    : client_(std::move(client)),
      clock_(std::move(clock)),
      info_(std::move(info)),
      options_(options),
      radians_per_step_(2.0 * kPi / options.steps_per_rev) {}

ClientBoard::~ClientBoard() { (void)Shutdown(); }

std::string ClientBoard::Description() const { return info_.name + " (" + client_->transport().Description() + ")"; }

int64_t ClientBoard::HostFromDevice(uint64_t device_us) const {
  return static_cast<int64_t>(std::llround(fit_.HostFromDevice(static_cast<double>(device_us))));
}

Status ClientBoard::EnableMotor(bool enable) { return client_->EnableMotor(enable); }

double ClientBoard::table_angle_rad() const { return position_ * radians_per_step_; }

Result<BoardChange> ClientBoard::MoveTo(double angle_rad) {
  // From where the board says the table is: events that arrive late (a program's last edges, a status of
  // an earlier program) must not shift a relative move.
  ROTOSCAN_ASSIGN_OR_RETURN(const device::BoardStatus status, client_->GetStatus());
  position_ = status.position;
  return MoveBy(angle_rad - table_angle_rad());
}

Result<BoardChange> ClientBoard::MoveBy(double delta_rad) {
  const auto steps = static_cast<int32_t>(std::lround(delta_rad / radians_per_step_));
  BoardChange change;
  change.earliest_us = clock_->NowUs();
  change.moved = true;
  change.lasers = lasers_;
  if (steps != 0) {
    ROTOSCAN_ASSIGN_OR_RETURN(const device::MoveDoneEvent done, client_->MoveAndWait(steps, kMoveTimeoutUs));
    if (done.aborted) return DeviceError(Description() + ": the move was aborted");
    position_ = done.position;
    // The end of the move on the host clock, with the fit's error as margin (never before the send).
    const int64_t margin = fit_.min_round_trip_us + 1;
    change.latest_us = std::max(change.earliest_us, HostFromDevice(done.time_us) + margin);
  } else {
    change.latest_us = change.earliest_us;
  }
  change.table_angle_rad = table_angle_rad();
  return change;
}

Result<BoardChange> ClientBoard::SetLasers(uint8_t mask) {
  BoardChange change;
  change.earliest_us = clock_->NowUs();
  ROTOSCAN_RETURN_IF_ERROR(client_->SetLasers(mask));
  change.latest_us = clock_->NowUs();  // the board switched on receipt, before acknowledging
  lasers_ = mask;
  change.lasers = mask;
  change.table_angle_rad = table_angle_rad();
  return change;
}

Status ClientBoard::Shutdown() {
  if (unreachable_) return DeviceError(Description() + ": unreachable; its laser safety turns the lasers off");
  // A board that is gone (an unplug beyond the client's reconnect window) fails each command only after that
  // window: stop at the first such failure. Its laser safety (MotionConfig::laser_timeout_ms) stops the
  // program and turns the lasers off after that much silence.
  auto gone = [this](const Status& s) {
    if (s.code() == StatusCode::kDeviceError || s.code() == StatusCode::kTimeout) unreachable_ = true;
    return unreachable_;
  };
  Status first;
  if (program_running_) {
    first = client_->Abort();
    program_running_ = false;
    if (gone(first)) return first;
  }
  Status s = client_->SetLasers(0);
  if (s.ok()) lasers_ = 0;
  if (first.ok()) first = s;
  if (gone(s)) return first;
  s = client_->EnableMotor(false);
  if (first.ok()) first = s;
  gone(s);
  return first;
}

Status ClientBoard::LoadProgram(const device::ScanProgram& program) {
  ROTOSCAN_RETURN_IF_ERROR(client_->LoadProgram(program));
  program_origin_ = position_;
  program_steps_per_move_ = program.steps_per_move;
  return Status::Ok();
}

Status ClientBoard::StartProgram(uint32_t first_step) {
  // Statuses stamped before this (less the fit's error) are of an earlier program: one the board stopped
  // while the host could not hear it (an unplug), reported once it could.
  program_start_device_us_ = fit_.DeviceFromHost(static_cast<double>(clock_->NowUs())) -
                             static_cast<double>(fit_.min_round_trip_us + kStaleMarginUs);
  ROTOSCAN_RETURN_IF_ERROR(client_->Start(first_step));
  program_running_ = true;
  started_host_us_ = clock_->NowUs();
  return Status::Ok();
}

Status ClientBoard::AbortProgram() {
  program_running_ = false;
  Status s = client_->Abort();
  lasers_ = 0;
  return s;
}

Result<std::optional<TriggerEdge>> ClientBoard::NextTrigger(int64_t timeout_us, bool* program_done) {
  if (program_done != nullptr) *program_done = false;
  const int64_t deadline = clock_->NowUs() + timeout_us;
  bool polled = false;  // a zero timeout still reads what has arrived (on a real clock time has moved on)
  while (true) {
    const int64_t left = deadline - clock_->NowUs();
    if (left < 0 && polled) return std::optional<TriggerEdge>();
    polled = true;
    // At least 1 us: the client reads the transport only when it has time to wait.
    ROTOSCAN_ASSIGN_OR_RETURN(auto event, client_->NextEvent(std::max<int64_t>(left, 1)));
    if (!event) return std::optional<TriggerEdge>();
    if (const auto* trigger = std::get_if<device::TriggerEvent>(&*event)) {
      TriggerEdge edge;
      edge.event = *trigger;
      last_trigger_seq_ = trigger->trigger_seq;
      edge.host_us = HostFromDevice(trigger->time_us);
      position_ = trigger->position;
      edge.table_angle_rad = trigger->position * radians_per_step_;
      lasers_ = trigger->laser_mask;
      return std::optional<TriggerEdge>(edge);
    }
    if (const auto* done = std::get_if<device::MoveDoneEvent>(&*event)) {
      position_ = done->position;
      continue;
    }
    if (const auto* status = std::get_if<device::BoardStatus>(&*event)) {
      if (status->cause != device::StatusCause::kReply &&
          (!program_running_ || static_cast<double>(status->time_us) < program_start_device_us_)) {
        ROTOSCAN_LOG(kDebug) << Description() << ": status of an earlier program ignored";
        continue;
      }
      position_ = status->position;
      if (status->cause == device::StatusCause::kProgramDone) {
        program_running_ = false;
        lasers_ = 0;
        if (program_done != nullptr) *program_done = true;
        return std::optional<TriggerEdge>();
      }
      if (status->cause == device::StatusCause::kSafety || status->cause == device::StatusCause::kAborted) {
        const std::string stop =
            std::string(status->cause == device::StatusCause::kSafety ? "laser safety" : "abort") +
            " at step " + std::to_string(status->program_next_step);
        last_stop_ = stop + ", " + std::to_string((clock_->NowUs() - started_host_us_) / 1000) + " ms after the start";
        ROTOSCAN_LOG(kWarning) << Description() << ": program stopped by the board (" << stop << "), resuming";
        // ResumeProgram() here, not the client's: the scan may have resumed it already (a quiet spell),
        // and a program running again is not a finished one.
        ROTOSCAN_ASSIGN_OR_RETURN(auto resumed, ResumeProgram());
        if (!resumed) {
          program_running_ = false;
          if (program_done != nullptr) *program_done = true;
          return std::optional<TriggerEdge>();
        }
      }
      continue;
    }
  }
}

Result<std::optional<uint32_t>> ClientBoard::ResumeProgram() {
  // A program still running (a long move to its next step) is not finished: its next step, left alone.
  ROTOSCAN_ASSIGN_OR_RETURN(const device::BoardStatus status, client_->GetStatus());
  if (status.state == device::BoardState::kRunning) return std::optional<uint32_t>(status.program_next_step);
  return client_->ResumeProgram();
}

std::string ClientBoard::ProgramDiagnosis() {
  auto status = client_->GetStatus();
  std::string out;
  if (!status.ok()) {
    out = "board status unavailable (" + status.status().message() + ")";
  } else {
    const char* state = "idle";
    switch (status->state) {
      case device::BoardState::kIdle: state = "idle"; break;
      case device::BoardState::kMoving: state = "moving"; break;
      case device::BoardState::kRunning: state = "running"; break;
      case device::BoardState::kTrigger: state = "in a single trigger"; break;
    }
    // The flag is the board's until its next command answered: this GET_STATUS is the first since the stop.
    if (status->safety_tripped) out = "the board stopped the program: laser safety timeout (the host was silent); ";
    out += std::string("board ") + state + ", program " +
          (status->program_loaded ? "at step " + std::to_string(status->program_next_step) + " of " +
                                        std::to_string(status->program_steps)
                                  : std::string("not loaded")) +
          ", trigger count " + std::to_string(status->trigger_count) + " (last heard: " +
          (last_trigger_seq_ ? "seq " + std::to_string(*last_trigger_seq_) : std::string("none")) + ")" +
          ", lasers " + std::to_string(status->lasers) +
          ", events dropped " + std::to_string(status->events_dropped);
  }
  out += ", last stop reported: " + (last_stop_.empty() ? std::string("none") : last_stop_);
  out += ", program started " + std::to_string((clock_->NowUs() - started_host_us_) / 1000) + " ms ago";
  return out;
}

Status ClientBoard::KeepAlive() {
  ROTOSCAN_ASSIGN_OR_RETURN(const device::PingSample sample, client_->Ping());
  samples_.push_back(sample);
  if (samples_.size() > options_.max_samples) samples_.erase(samples_.begin());
  // The drift once the pings the fit keeps (the fastest) span drift_after_us: on a loaded host those can all
  // be the back-to-back pings taken at open, though the samples span minutes (issue 13).
  device::ClockFitOptions fit_options = options_.clock_fit;
  fit_options.min_drift_span_us = options_.drift_after_us;
  auto fit = device::FitClock(samples_, fit_options);
  if (fit.ok()) {
    fit_ = *fit;
  } else {
    ROTOSCAN_LOG(kDebug) << Description() << ": clock refit refused (" << fit.status().message() << "), kept the last fit";
  }
  return Status::Ok();
}

}  // namespace rotoscan::capture::internal

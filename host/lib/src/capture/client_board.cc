#include "client_board.h"

#include <cmath>

#include "rotoscan/core/logging.h"

namespace rotoscan::capture::internal {

namespace {
constexpr double kPi = 3.14159265358979323846;
constexpr int64_t kMoveTimeoutUs = 30'000'000;
}  // namespace

Result<std::unique_ptr<ClientBoard>> ClientBoard::Create(std::unique_ptr<device::Client> client,
                                                         std::shared_ptr<Clock> clock, BoardInfo info,
                                                         const ClientBoardOptions& options) {
  if (options.steps_per_rev <= 0) return InvalidArgumentError("board: steps_per_rev must be positive");
  std::unique_ptr<ClientBoard> board(new ClientBoard(std::move(client), std::move(clock), std::move(info), options));
  device::Client& c = *board->client_;
  ROTOSCAN_RETURN_IF_ERROR(c.SetConfig(options.motion));
  ROTOSCAN_ASSIGN_OR_RETURN(board->fit_, c.SyncClock(options.clock_pings));
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
  Status first;
  if (program_running_) {
    first = client_->Abort();
    program_running_ = false;
  }
  Status s = client_->SetLasers(0);
  if (s.ok()) lasers_ = 0;
  if (first.ok()) first = s;
  s = client_->EnableMotor(false);
  if (first.ok()) first = s;
  return first;
}

Status ClientBoard::LoadProgram(const device::ScanProgram& program) {
  ROTOSCAN_RETURN_IF_ERROR(client_->LoadProgram(program));
  program_origin_ = position_;
  program_steps_per_move_ = program.steps_per_move;
  return Status::Ok();
}

Status ClientBoard::StartProgram(uint32_t first_step) {
  ROTOSCAN_RETURN_IF_ERROR(client_->Start(first_step));
  program_running_ = true;
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
  while (true) {
    const int64_t left = deadline - clock_->NowUs();
    if (left < 0) return std::optional<TriggerEdge>();
    ROTOSCAN_ASSIGN_OR_RETURN(auto event, client_->NextEvent(left));
    if (!event) return std::optional<TriggerEdge>();
    if (const auto* trigger = std::get_if<device::TriggerEvent>(&*event)) {
      TriggerEdge edge;
      edge.event = *trigger;
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
      position_ = status->position;
      if (status->cause == device::StatusCause::kProgramDone) {
        program_running_ = false;
        lasers_ = 0;
        if (program_done != nullptr) *program_done = true;
        return std::optional<TriggerEdge>();
      }
      if (status->cause == device::StatusCause::kSafety || status->cause == device::StatusCause::kAborted) {
        ROTOSCAN_LOG(kWarning) << Description() << ": program stopped by the board ("
                               << (status->cause == device::StatusCause::kSafety ? "laser safety" : "abort")
                               << "), resuming";
        ROTOSCAN_ASSIGN_OR_RETURN(auto resumed, client_->ResumeProgram());
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

Result<std::optional<uint32_t>> ClientBoard::ResumeProgram() { return client_->ResumeProgram(); }

}  // namespace rotoscan::capture::internal

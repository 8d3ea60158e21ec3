// Board backend `ciclop`: the bq Ciclop's ZUM board running horus-fw, through device::CiclopClient
// (device/ciclop_client.h: the dialect, its timing and its fault handling).
//
//   spec: "ciclop:/dev/ttyUSB0" (or a /dev/serial/by-id/ link, which survives a re-plug on another port);
//   options ("key=value"): feed=<deg/s> (table speed, default 180, horus-fw's max), ok_timeout_ms=<ms>,
//   reconnect_ms=<ms>.
//
// Change intervals (board.h): a laser change took effect inside [the first line's send, the last "ok"]
// (horus-fw switches a laser as it executes the line, before answering); a move from its line's send to
// the first "Idle at target" status report. After a re-connection inside a call the interval starts at the
// client's last contact with the board before it went away: the lasers and table are unknown from then,
// so free-running capture drops every frame exposed in that range.
//
// Lasers: horus-fw's laser 1 is the left one, laser 2 the right one (as bq Horus numbers them).
#include <cmath>
#include <memory>
#include <string>

#include "backend_options.h"
#include "rotoscan/capture/factory.h"
#include "rotoscan/core/logging.h"
#include "rotoscan/device/ciclop_client.h"
#include "rotoscan/device/serial_port.h"

namespace rotoscan::capture {

namespace {

constexpr double kDegPerRad = 180.0 / M_PI;

class CiclopBoard final : public Board {
 public:
  explicit CiclopBoard(const device::CiclopOptions& options) : client_(options) {
    info_.name = "bq Ciclop (horus-fw)";
    info_.serial = options.port;
  }
  ~CiclopBoard() override { (void)Shutdown(); }

  Status Connect() {
    ROTOSCAN_RETURN_IF_ERROR(client_.Connect());
    info_.firmware_version = client_.banner();
    capabilities_.degrees_per_step = 1.0 / client_.steps_per_deg();
    capabilities_.lasers = 2;
    return Status::Ok();
  }

  const BoardCapabilities& capabilities() const override { return capabilities_; }
  const BoardInfo& info() const override { return info_; }
  std::string Description() const override { return "bq Ciclop board (horus-fw) on " + info_.serial; }

  Status EnableMotor(bool enable) override { return client_.SetMotor(enable).status(); }

  Result<BoardChange> MoveTo(double angle_rad) override {
    const size_t reconnections = client_.reconnections().size();
    ROTOSCAN_ASSIGN_OR_RETURN(device::MoveAck move, client_.MoveTo(angle_rad * kDegPerRad, /*wait=*/true));
    BoardChange change;
    change.earliest_us = Earliest(move.ack.sent_us, reconnections);
    change.latest_us = move.idle_us.value_or(move.predicted_end_us);
    change.lasers = lasers();
    change.table_angle_rad = client_.angle_deg() / kDegPerRad;
    change.moved = true;
    return change;
  }

  Result<BoardChange> MoveBy(double delta_rad) override { return MoveTo(table_angle_rad() + delta_rad); }

  Result<BoardChange> SetLasers(uint8_t mask) override {
    const size_t reconnections = client_.reconnections().size();
    std::optional<int64_t> first_sent;
    int64_t last_ok = 0;
    for (int n = 1; n <= 2; ++n) {
      const bool on = (mask & (n == 1 ? kLaserLeft : kLaserRight)) != 0;
      if (client_.laser(n) == on && client_.reconnections().size() == reconnections) continue;
      ROTOSCAN_ASSIGN_OR_RETURN(device::Ack ack, client_.SetLaser(n, on));
      if (!first_sent) first_sent = ack.sent_us;
      last_ok = ack.ok_us;
    }
    BoardChange change;
    if (!first_sent) {  // nothing to change: a zero-length interval now
      change.earliest_us = change.latest_us = device::MonotonicNowUs();
    } else {
      change.earliest_us = Earliest(*first_sent, reconnections);
      change.latest_us = last_ok;
    }
    // A re-connection in the second command switched the first laser off again: set it once more.
    if (client_.reconnections().size() != reconnections && lasers() != mask) {
      ROTOSCAN_ASSIGN_OR_RETURN(BoardChange again, SetLasers(mask));
      change.latest_us = again.latest_us;
    }
    change.lasers = lasers();
    change.table_angle_rad = table_angle_rad();
    return change;
  }

  double table_angle_rad() const override { return client_.angle_deg() / kDegPerRad; }
  uint8_t lasers() const override {
    return static_cast<uint8_t>((client_.laser(1) ? kLaserLeft : 0) | (client_.laser(2) ? kLaserRight : 0));
  }

  Status Shutdown() override {
    if (!client_.connected()) return Status::Ok();
    Status status;
    for (int n = 1; n <= 2; ++n) {
      Status s = client_.SetLaser(n, false).status();
      if (!s.ok() && status.ok()) status = s;
    }
    Status motor = client_.SetMotor(false).status();
    if (!motor.ok() && status.ok()) status = motor;
    client_.Close();
    return status;
  }

  device::CiclopClient& client() { return client_; }

 private:
  // The start of a change interval: the first send, or the last contact before a re-connection that
  // happened during the call (the outputs were unknown from then).
  int64_t Earliest(int64_t sent_us, size_t reconnections_before) const {
    const auto& r = client_.reconnections();
    int64_t earliest = sent_us;
    for (size_t i = reconnections_before; i < r.size(); ++i) earliest = std::min(earliest, r[i].last_contact_us);
    return earliest;
  }

  device::CiclopClient client_;
  BoardCapabilities capabilities_;
  BoardInfo info_;
};

Status ParseOptions(const std::vector<std::string>& entries, device::CiclopOptions* out) {
  ROTOSCAN_ASSIGN_OR_RETURN(const auto options, internal::BackendOptions::Parse(
                                                    entries, "ciclop", {"feed", "ok_timeout_ms", "reconnect_ms"}));
  ROTOSCAN_ASSIGN_OR_RETURN(out->feed_deg_per_s, options.Number("feed", out->feed_deg_per_s));
  ROTOSCAN_ASSIGN_OR_RETURN(const double ok_ms, options.Number("ok_timeout_ms", out->ok_timeout_us / 1000.0));
  ROTOSCAN_ASSIGN_OR_RETURN(const double reconnect_ms,
                            options.Number("reconnect_ms", out->reconnect_timeout_us / 1000.0));
  out->ok_timeout_us = static_cast<int64_t>(ok_ms * 1000);
  out->reconnect_timeout_us = static_cast<int64_t>(reconnect_ms * 1000);
  return out->Check().WithContext("ciclop options");
}

Result<std::unique_ptr<Board>> OpenCiclop(const std::string& argument, OpenContext* context) {
  if (argument.empty()) {
    return InvalidArgumentError("board 'ciclop' needs its serial port: ciclop:/dev/ttyUSB0");
  }
  if (context->clock != nullptr && context->clock->is_virtual()) {
    return InvalidArgumentError("board 'ciclop' is real hardware: it runs on the real clock, not a virtual one");
  }
  if (context->clock == nullptr) context->clock = MakeRealClock();
  device::CiclopOptions options;
  options.port = argument;
  ROTOSCAN_RETURN_IF_ERROR(ParseOptions(context->options, &options));
  auto board = std::make_unique<CiclopBoard>(options);
  ROTOSCAN_RETURN_IF_ERROR(board->Connect());
  return std::unique_ptr<Board>(std::move(board));
}

Result<std::vector<DeviceListing>> ListCiclops() {
  std::vector<DeviceListing> found;
  for (const device::SerialPortInfo& port : device::ListSerialPorts()) {
    DeviceListing listing;
    listing.spec = "ciclop:" + (port.by_id.empty() ? port.path : port.by_id);
    listing.description = "serial port " + port.path +
                          " (may be a bq Ciclop board; not opened: opening resets an Arduino-type board)";
    found.push_back(listing);
  }
  return found;
}

}  // namespace

void RegisterCaptureBackend_ciclop(BackendRegistry* registry) {
  BoardBackend backend;
  backend.name = "ciclop";
  backend.description = "bq Ciclop ZUM board with horus-fw (G-code over a serial port, 115200 baud)";
  backend.open = OpenCiclop;
  backend.list = ListCiclops;
  registry->AddBoard(std::move(backend));
}

}  // namespace rotoscan::capture

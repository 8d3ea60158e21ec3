// A Board over the device client (device/client.h): what the `usb` and `sim` backends share. Times of
// changes: a laser switch takes effect on the board when SET_LASERS arrives, so between the command's
// send time and its acknowledgement; a move from its send time to its MOVE_DONE event's device time
// through the clock fit (plus the fit's error); trigger edges at their device time through the fit.
//
// The clock fit: at open, from `clock_pings` back-to-back PINGs, offset only (over a few milliseconds a
// crystal's drift is unobservable: fitting it there would turn ping jitter into a drift of percents). Every
// KeepAlive() PING of a scan adds a sample, and the fit is redone from all of them; once the samples the fit
// keeps (the fastest) span `drift_after_us`, with the drift too (when clock_fit.fit_drift), so a long scan's
// edges stay on time.
#pragma once

#include <memory>
#include <optional>
#include <string>
#include <vector>

#include "rotoscan/capture/board.h"
#include "rotoscan/capture/clock.h"
#include "rotoscan/device/client.h"

namespace rotoscan::capture::internal {

struct ClientBoardOptions {
  int steps_per_rev = 19200;  // motor steps per table turn (microsteps and gearing included)
  device::MotionConfig motion;
  int clock_pings = 16;
  device::ClockFitOptions clock_fit;
  int64_t drift_after_us = 10'000'000;  // fit the drift once the samples used span this long
  size_t max_samples = 4096;           // the oldest keep-alive samples are dropped beyond this
};

class ClientBoard : public Board {
 public:
  // `client` is connected; its transport's NowUs() is `clock`'s time.
  static Result<std::unique_ptr<ClientBoard>> Create(std::unique_ptr<device::Client> client,
                                                     std::shared_ptr<Clock> clock, BoardInfo info,
                                                     const ClientBoardOptions& options);
  ~ClientBoard() override;

  const BoardCapabilities& capabilities() const override { return capabilities_; }
  const BoardInfo& info() const override { return info_; }
  std::string Description() const override;
  Status EnableMotor(bool enable) override;
  Result<BoardChange> MoveTo(double angle_rad) override;
  Result<BoardChange> MoveBy(double delta_rad) override;
  Result<BoardChange> SetLasers(uint8_t mask) override;
  double table_angle_rad() const override;
  uint8_t lasers() const override { return lasers_; }
  Status Shutdown() override;
  Status LoadProgram(const device::ScanProgram& program) override;
  Status StartProgram(uint32_t first_step) override;
  Status AbortProgram() override;
  Result<std::optional<TriggerEdge>> NextTrigger(int64_t timeout_us, bool* program_done) override;
  Result<std::optional<uint32_t>> ResumeProgram() override;
  Status KeepAlive() override;
  int lost_events() const override { return client_->stats().lost_events; }
  std::string ProgramDiagnosis() override;

  device::Client& client() { return *client_; }
  const device::ClockFit& clock_fit() const { return fit_; }
  double radians_per_step() const { return radians_per_step_; }

 private:
  ClientBoard(std::unique_ptr<device::Client> client, std::shared_ptr<Clock> clock, BoardInfo info,
              const ClientBoardOptions& options);
  int64_t HostFromDevice(uint64_t device_us) const;

  std::unique_ptr<device::Client> client_;
  std::shared_ptr<Clock> clock_;
  BoardInfo info_;
  ClientBoardOptions options_;
  BoardCapabilities capabilities_;
  device::ClockFit fit_;
  std::vector<device::PingSample> samples_;
  double radians_per_step_ = 0.0;
  int32_t position_ = 0;  // motor steps from where the board was opened
  int32_t program_origin_ = 0;
  int32_t program_steps_per_move_ = 0;
  uint8_t lasers_ = 0;
  bool program_running_ = false;
  double program_start_device_us_ = 0.0;  // device time of StartProgram, less a margin
  int64_t started_host_us_ = 0;             // host clock when the host last started a program
  std::optional<uint32_t> last_trigger_seq_;  // the last TRIGGER_EVENT heard
  std::string last_stop_;                     // the last program stop the board reported (laser safety, abort)
  bool unreachable_ = false;  // Shutdown() found the board gone: later ones return at once
};

}  // namespace rotoscan::capture::internal

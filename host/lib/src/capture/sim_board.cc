// Backend `sim`: the firmware core built for the host (firmware/port/sim) behind the device client, in the
// virtual time of the scan's VirtualClock: each time the clock moves, the simulated board runs forward by
// as much (timers, step pulses, laser compares, its main loop). The firmware simulator is one global
// board, so one sim board may be open at a time.
//
// The board's own pin-edge log is the rig's truth (virtual_rig.h) for the virtual camera: laser levels,
// step pulses and trigger edges at their exact times (device time + the fixed offset from the clock).
//
// Faults for tests, as backend options: unplug_at_ms / unplug_for_ms (the USB cable pulled at a virtual
// time), lose_in_every (drop every n-th chunk the board sends: a lost IN packet). pins_file=PATH writes the
// laser pins' levels ("left 0\nright 0\n") when the board is let go, for a test that runs `rotoscan scan`
// as another process (Ctrl-C leaves the lasers off).
#include <algorithm>
#include <atomic>
#include <cmath>
#include <mutex>

#include "backend_options.h"
#include "rotoscan/core/file.h"
#include "rotoscan/core/logging.h"
#include "client_board.h"
#include "rotoscan/capture/factory.h"
#include "rotoscan/capture/virtual_rig.h"
#include "rotoscan/device/transport.h"
#include "sim_port.h"
#include "sim_rig_truth.h"

namespace rotoscan::capture {
namespace {

std::atomic<bool> g_sim_open{false};

struct SimFaults {
  int64_t unplug_at_us = -1;
  int64_t unplug_for_us = 0;
  int lose_in_every = 0;
};

// The bytes of the simulated board's USB endpoints; reading waits in virtual time.
class SimTransport : public device::Transport {
 public:
  SimTransport(std::shared_ptr<VirtualClock> clock, const SimFaults& faults) : clock_(std::move(clock)), faults_(faults) {}
  Status Open() override {
    if (Unplugged()) {
      clock_->Advance(1000);  // the time a re-open attempt takes
      return NotFoundError("simulated board unplugged");
    }
    open_ = true;
    return Status::Ok();
  }
  void Close() override { open_ = false; }
  bool IsOpen() const override { return open_; }
  Status Write(const std::vector<uint8_t>& bytes) override {
    if (!open_) return FailedPreconditionError("simulated board closed");
    if (Unplugged()) {
      open_ = false;
      return DeviceError("simulated board unplugged");
    }
    sim_usb_receive(bytes.data(), bytes.size());
    return Status::Ok();
  }
  Status Read(std::vector<uint8_t>* bytes, int64_t timeout_us) override {
    const int64_t deadline = clock_->NowUs() + std::max<int64_t>(timeout_us, 0);
    while (true) {
      if (Unplugged()) {
        open_ = false;
        return DeviceError("simulated board unplugged");
      }
      uint8_t buffer[512];
      const size_t n = sim_usb_transmit(buffer, sizeof buffer);
      if (n > 0) {
        ++chunks_;
        if (faults_.lose_in_every > 0 && chunks_ % faults_.lose_in_every == 0) continue;  // lost packet
        bytes->insert(bytes->end(), buffer, buffer + n);
        return Status::Ok();
      }
      const int64_t now = clock_->NowUs();
      if (now >= deadline) return Status::Ok();
      clock_->WaitUntilUs(std::min(deadline, now + kTickUs));
    }
  }
  int64_t NowUs() const override { return clock_->NowUs(); }
  std::string Description() const override { return "simulated board"; }

 private:
  static constexpr int64_t kTickUs = 50;
  bool Unplugged() const {
    const int64_t now = clock_->NowUs();
    return faults_.unplug_at_us >= 0 && now >= faults_.unplug_at_us &&
           now < faults_.unplug_at_us + faults_.unplug_for_us;
  }
  std::shared_ptr<VirtualClock> clock_;
  SimFaults faults_;
  bool open_ = false;
  long long chunks_ = 0;
};

// The client board, plus what the simulator owns: the clock listener, the truth and the global flag.
class SimBoardHolder : public Board {
 public:
  SimBoardHolder(std::unique_ptr<internal::ClientBoard> board, std::shared_ptr<VirtualClock> clock, int listener,
                 std::unique_ptr<internal::SimRigTruth> truth, std::string pins_file)
      : board_(std::move(board)),
        clock_(std::move(clock)),
        listener_(listener),
        truth_(std::move(truth)),
        pins_file_(std::move(pins_file)) {}
  ~SimBoardHolder() override {
    board_.reset();
    if (!pins_file_.empty()) {
      // The simulated pins as the board is let go (option pins_file): what a process that ended (Ctrl-C
      // included) left the lasers at, for a test outside that process.
      const int64_t now = clock_->NowUs();
      const std::string text = "left " + std::to_string(truth_->LaserAt(0, now) ? 1 : 0) + "\nright " +
                               std::to_string(truth_->LaserAt(1, now) ? 1 : 0) + "\n";
      const Status written = WriteFileAtomically(pins_file_, text);
      if (!written.ok()) {
        ROTOSCAN_LOG(kWarning) << "sim: " << written.message();
      }
    }
    clock_->RemoveListener(listener_);
    g_sim_open = false;
  }
  const BoardCapabilities& capabilities() const override { return board_->capabilities(); }
  const BoardInfo& info() const override { return board_->info(); }
  std::string Description() const override { return board_->Description(); }
  Status EnableMotor(bool enable) override { return board_->EnableMotor(enable); }
  Result<BoardChange> MoveTo(double a) override { return board_->MoveTo(a); }
  Result<BoardChange> MoveBy(double d) override { return board_->MoveBy(d); }
  Result<BoardChange> SetLasers(uint8_t mask) override { return board_->SetLasers(mask); }
  double table_angle_rad() const override { return board_->table_angle_rad(); }
  uint8_t lasers() const override { return board_->lasers(); }
  Status Shutdown() override { return board_->Shutdown(); }
  Status LoadProgram(const device::ScanProgram& p) override { return board_->LoadProgram(p); }
  Status StartProgram(uint32_t first) override { return board_->StartProgram(first); }
  Status AbortProgram() override { return board_->AbortProgram(); }
  Result<std::optional<TriggerEdge>> NextTrigger(int64_t timeout_us, bool* done) override {
    return board_->NextTrigger(timeout_us, done);
  }
  Result<std::optional<uint32_t>> ResumeProgram() override { return board_->ResumeProgram(); }
  int lost_events() const override { return board_->lost_events(); }
  Status KeepAlive() override { return board_->KeepAlive(); }
  std::string ProgramDiagnosis() override { return board_->ProgramDiagnosis(); }
  RigTruth* truth() override { return truth_.get(); }

 private:
  std::unique_ptr<internal::ClientBoard> board_;
  std::shared_ptr<VirtualClock> clock_;
  int listener_;
  std::unique_ptr<internal::SimRigTruth> truth_;
  std::string pins_file_;
};

Result<std::unique_ptr<Board>> OpenSimBoard(const std::string& argument, OpenContext* context) {
  if (!argument.empty()) return InvalidArgumentError("board 'sim' takes no argument (got '" + argument + "')");
  ROTOSCAN_ASSIGN_OR_RETURN(const auto options,
                            internal::BackendOptions::Parse(context->options, "sim",
                                                            {"steps_per_rev", "unplug_at_ms", "unplug_for_ms",
                                                             "lose_in_every", "camera_delay_us", "pins_file"}));
  ROTOSCAN_ASSIGN_OR_RETURN(const double steps_per_rev, options.Number("steps_per_rev", 19200));
  ROTOSCAN_ASSIGN_OR_RETURN(const double unplug_at_ms, options.Number("unplug_at_ms", -1));
  ROTOSCAN_ASSIGN_OR_RETURN(const double unplug_for_ms, options.Number("unplug_for_ms", 0));
  ROTOSCAN_ASSIGN_OR_RETURN(const double lose_in_every, options.Number("lose_in_every", 0));
  if (!(steps_per_rev >= 1 && steps_per_rev <= 1e7)) return InvalidArgumentError("sim: steps_per_rev out of range");
  if (g_sim_open.exchange(true)) {
    return FailedPreconditionError("a simulated board is already open in this process (there is one simulator)");
  }
  struct Release {
    bool armed = true;
    ~Release() {
      if (armed) g_sim_open = false;
    }
  } release;

  auto clock = std::dynamic_pointer_cast<VirtualClock>(context->clock);
  if (!clock) {
    clock = std::make_shared<VirtualClock>();
    context->clock = clock;
  }
  sim_reset();
  const int64_t offset = clock->NowUs();  // device time 0 is this host time
  auto last = std::make_shared<int64_t>(offset);
  const int listener = clock->AddListener([last](int64_t now) {
    if (now > *last) sim_advance_us(static_cast<uint64_t>(now - *last));
    *last = now;
  });

  SimFaults faults;
  if (unplug_at_ms >= 0) {
    faults.unplug_at_us = offset + static_cast<int64_t>(unplug_at_ms * 1000);
    faults.unplug_for_us = static_cast<int64_t>(unplug_for_ms * 1000);
  }
  faults.lose_in_every = static_cast<int>(lose_in_every);
  device::ClientOptions client_options;
  client_options.reconnect_interval_us = 1000;
  auto connected = device::Client::Connect(std::make_unique<SimTransport>(clock, faults), client_options);
  if (!connected.ok()) {
    clock->RemoveListener(listener);
    return connected.status();
  }
  internal::ClientBoardOptions board_options;
  board_options.steps_per_rev = static_cast<int>(steps_per_rev);
  board_options.motion.start_rate_hz = 2000;
  board_options.motion.max_rate_hz = 40000;
  board_options.motion.accel_hz_per_s = 4'000'000;
  board_options.motion.trigger_pulse_us = 50;
  board_options.clock_fit.fit_drift = false;  // one clock: the board's runs from the host's
  BoardInfo info;
  info.name = "simulated rotoscan board";
  info.serial = "sim";
  info.firmware_version = connected.value()->info().firmware_version;
  auto board = internal::ClientBoard::Create(std::move(connected).value(), clock, info, board_options);
  if (!board.ok()) {
    clock->RemoveListener(listener);
    return board.status();
  }
  release.armed = false;
  auto truth = std::make_unique<internal::SimRigTruth>(offset, 2.0 * 3.14159265358979323846 / steps_per_rev);
  return std::unique_ptr<Board>(
      std::make_unique<SimBoardHolder>(std::move(board).value(), clock, listener, std::move(truth),
                                       options.Text("pins_file", "")));
}

}  // namespace

void RegisterCaptureBackend_sim(BackendRegistry* registry) {
  registry->AddBoard({"sim", "the firmware core simulated on the host, in virtual time", OpenSimBoard,
                      []() -> Result<std::vector<DeviceListing>> {
                        return std::vector<DeviceListing>{{"sim", "simulated rotoscan board (always there)"}};
                      }});
}

}  // namespace rotoscan::capture

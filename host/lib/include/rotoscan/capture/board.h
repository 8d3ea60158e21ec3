// A scanner board behind one interface (STYLE.md 8): it turns the table and switches the lasers. Backends:
// `usb` (our STM32F411 board, device::Client over libusb), `sim` (the firmware core built for the host,
// in virtual time), `ciclop` (the bq Ciclop's ZUM board running horus-fw, G-code on a serial port).
// Open one with OpenBoard() (factory.h).
//
// Times are microseconds on the scan's host clock (clock.h). Every change the board makes (lasers, table
// angle) is reported as a BoardChange with the interval in which it took effect: for our board the
// device's event time through the clock fit (tight); for a G-code board from the command's send time to
// its `ok` plus a measured latency bound (loose). Free-running capture keeps only frames whose whole
// exposure lies outside those intervals (timing.h).
//
// Our board does more: it triggers the camera in hardware from a loaded scan program (capabilities
// `trigger_output`), reporting each trigger edge with its seq, device time, lasers and table position.
// Those calls fail with kUnimplemented on boards without it.
#pragma once

#include <cstdint>
#include <optional>
#include <string>

#include "rotoscan/core/status.h"
#include "rotoscan/device/client.h"
#include "rotoscan/device/clock_sync.h"

namespace rotoscan::capture {

class RigTruth;  // virtual_rig.h

inline constexpr uint8_t kLaserLeft = device::kLaserLeft;
inline constexpr uint8_t kLaserRight = device::kLaserRight;

struct BoardCapabilities {
  bool trigger_output = false;   // runs scan programs that fire the camera's trigger line (our board)
  bool exposure_input = false;   // records the camera's exposure-active line
  bool device_clock = false;     // changes are timed on the board's clock (tight intervals)
  double degrees_per_step = 0.0;  // table degrees per motor step (the smallest move)
  int lasers = 2;
};

// A change of the board's outputs, and when it took effect: somewhere in [earliest_us, latest_us] on the
// host clock. latest_us - earliest_us is the latency bound.
struct BoardChange {
  int64_t earliest_us = 0;
  int64_t latest_us = 0;
  uint8_t lasers = 0;            // kLaserLeft | kLaserRight after the change
  double table_angle_rad = 0.0;  // table angle after the change (for a move: where it stopped)
  bool moved = false;            // a table move (the angle changed over [earliest_us, latest_us])
};

// A hardware trigger edge of a scan program, converted to the host clock.
struct TriggerEdge {
  device::TriggerEvent event;  // seq, device time, lasers, position, step, shot, run
  int64_t host_us = 0;         // the edge on the host clock (through the clock fit)
  double table_angle_rad = 0.0;
};

struct BoardInfo {
  std::string name;  // "rotoscan board", "simulated rotoscan board", "bq Ciclop (horus-fw)"
  std::string serial;
  std::string firmware_version;
};

class Board {
 public:
  virtual ~Board() = default;

  virtual const BoardCapabilities& capabilities() const = 0;
  virtual const BoardInfo& info() const = 0;
  virtual std::string Description() const = 0;

  virtual Status EnableMotor(bool enable) = 0;
  // Turns the table to an absolute angle (radians, from where the board was opened or last homed) or by a
  // relative one, and waits until it stands still. Returns the change (moved = true).
  virtual Result<BoardChange> MoveTo(double angle_rad) = 0;
  virtual Result<BoardChange> MoveBy(double delta_rad) = 0;
  // Sets both lasers at once (kLaserLeft | kLaserRight) and returns once the board confirmed it.
  virtual Result<BoardChange> SetLasers(uint8_t mask) = 0;
  // The table angle and lasers as last commanded and confirmed.
  virtual double table_angle_rad() const = 0;
  virtual uint8_t lasers() const = 0;
  // Lasers off and motor disabled, as best it can (also called on errors and Ctrl-C). Never throws.
  virtual Status Shutdown() = 0;

  // ---- hardware-triggered scan programs (capabilities().trigger_output) ----
  // Loads a program (device::ScanProgram: steps, motor steps per move, shots with lasers and exposure).
  virtual Status LoadProgram(const device::ScanProgram& program);
  // Starts it at `first_step`; trigger edges follow (NextTrigger).
  virtual Status StartProgram(uint32_t first_step);
  // Stops a running program; lasers go off.
  virtual Status AbortProgram();
  // The next trigger edge, waiting up to `timeout_us`; nullopt on timeout, and also nullopt with
  // *program_done set once the program finished (when non-null).
  virtual Result<std::optional<TriggerEdge>> NextTrigger(int64_t timeout_us, bool* program_done);
  // After an unplug or a safety stop: restarts the program where the board says it stopped (nullopt when
  // it had finished; the next step, untouched, when it is still running).
  virtual Result<std::optional<uint32_t>> ResumeProgram();
  // Tells the board the host is alive, during a long program with no other command (our board stops a
  // program and turns the lasers off after a silence: laser safety). Call it at least every 0.5 s.
  virtual Status KeepAlive() { return Status::Ok(); }
  // Lost trigger events seen so far (gaps in the board's counter).
  virtual int lost_events() const { return 0; }
  // What the board says about its program, for an error when a triggered scan hears nothing: its state,
  // next step, trigger count, laser safety, and the last stop it reported. Empty where it cannot say.
  virtual std::string ProgramDiagnosis() { return {}; }

  // The simulated rig's truth (sim board only; null for real boards): what a virtual camera renders.
  virtual RigTruth* truth() { return nullptr; }
};

}  // namespace rotoscan::capture

// The bq Ciclop's ZUM board running horus-fw (a GRBL 0.9 derivative), over a serial port at 115200 baud.
//
// The dialect, as horus-fw implements it (bqlabs/horus-fw gcode.c, protocol.c, report.c, system.c):
//   Ctrl-X (0x18)   soft reset: motion stops, lasers off; answers "\r\nHorus 0.1 ['$' for help]\r\n"
//   G1F<v>          feed rate in degrees per second (horus-fw multiplies F by 60 into its deg/min planner)
//   G1X<a>          move the table to the absolute angle a (degrees); "error: Undefined feed rate" before F
//   M71T<n> M70T<n> laser n (1 or 2) on / off; executed at once, not queued behind moves
//   M17 M18         stepper driver on / off
//   $G              parser state "[G1 G54 T0 F12000.]" then "ok": processed in line order
//   ?               real-time status "<Idle,MPos:x,y,z,WPos:x,y,z>" (or <Run, <Queue, ...), no "ok"
// Every line is answered by "ok" or "error: <text>" once it has been executed. An empty line gets no
// answer in horus-fw (GRBL answers "ok"), so lines are sent with a single "\n".
//
// Timing (what free-running capture needs): the board executes a line after its last byte arrives and
// before its "ok" leaves, so a laser switch happened inside [sent_us, ok_us] of its Ack (host monotonic
// time, serial_port.h). A move's "ok" comes when the move is queued, as in GRBL (mc_line returns once the
// block is in the planner), NOT when it ends: the table starts turning inside [sent_us, ok_us] and stops
// about `MoveDurationUs()` later (trapezoid from the feed rate and the $120 acceleration); WaitIdle() polls
// "?" and gives the first host time at which the board said Idle at the target, an upper bound on the end.
//
// Faults:
//  * An error line makes the command fail with DeviceError quoting the line and the board's message.
//  * A lost "ok" (nothing within `ok_timeout_us`): the client sends "$G" and waits for its "[G..." and
//    "ok". An "ok" arriving before the "[" is the late answer to the pending line (it ran). If none came,
//    the line may not have run: a laser, motor or feed line is sent again (it is idempotent); a move is
//    sent again only after "?" shows the board Idle at the previous angle (it did not run), never blindly.
//    The Ack's window then covers both tries. A board that answers neither: Timeout, with the line named.
//  * Garbage (bytes that make no known line) is counted and skipped.
//  * Unplug (read/write error, hang-up, end of file, device gone): the client re-opens the same path for up
//    to `reconnect_timeout_us`, resets the board, and restores its state: feed rate, lasers off, motor as it
//    was, and the absolute angle (the re-opened board counts from 0 where the table stands, so the client
//    keeps an offset). If a move was under way the angle is unknown: the command fails with DeviceError
//    and MoveTo() keeps failing until SetAngle() says where the table is. An unexpected banner (the board
//    reset itself) is handled the same way. Each re-connection is counted and its time range recorded.
//
// Not thread-safe: one thread owns a CiclopClient.
#pragma once

#include <cstdint>
#include <memory>
#include <optional>
#include <string>
#include <vector>

#include "rotoscan/core/status.h"
#include "rotoscan/device/serial_port.h"

namespace rotoscan::device {

struct CiclopOptions {
  std::string port = "/dev/ttyUSB0";
  int baud = 115200;
  int64_t banner_timeout_us = 2'500'000;  // an Arduino boots through its bootloader in about 1-2 s
  int reset_attempts = 3;                 // Ctrl-X sent this many times before giving up on the banner
  int64_t ok_timeout_us = 500'000;        // a line's "ok"
  int retries = 2;                        // re-sends of a line whose "ok" was lost
  int64_t reconnect_timeout_us = 5'000'000;
  int64_t reconnect_interval_us = 20'000;
  int64_t status_poll_interval_us = 5'000;  // "?" while waiting for a move to end
  double feed_deg_per_s = 180.0;            // G1F sent at connect (horus-fw caps it at its $110)
  // Used to predict move durations when the board's "$$" cannot be read.
  double acceleration_deg_per_s2 = 180.0;  // horus-fw default $120
  double max_rate_deg_per_s = 180.0;       // horus-fw default $110
  double steps_per_deg = 176.0;            // horus-fw default $100 (16 microsteps x 11)
  Status Check() const;
};

// One acknowledged line. The board acted on it at a time inside [sent_us, ok_us] (host monotonic clock).
struct Ack {
  int64_t sent_us = 0;  // just before the line's first byte was written (of the first try)
  int64_t ok_us = 0;    // when the "ok" line was read
  int tries = 1;
  int64_t latency_us() const { return ok_us - sent_us; }
};

struct MoveAck {
  Ack ack;                          // the table started turning inside [ack.sent_us, ack.ok_us]
  double from_deg = 0.0;            // table angles (the client's frame)
  double to_deg = 0.0;
  int64_t predicted_end_us = 0;     // ack.ok_us + MoveDurationUs()
  std::optional<int64_t> idle_us;   // set by MoveTo(..., wait=true): first "Idle at target" report
};

struct CiclopStatus {
  std::string state;        // "Idle", "Run", "Queue", "Hold", "Alarm", ...
  double board_x_deg = 0.0;  // MPos x: the board's own angle (0 at its last boot)
  int64_t time_us = 0;       // when the report was read
};

struct LatencyStats {
  int count = 0;
  int64_t max_us = 0;   // the largest [sent, ok] window seen: a measured bound on the command latency
  int64_t mean_us = 0;
  int64_t min_us = 0;
};

// The board's lasers and table are unknown from `last_contact_us` (the last line read from it before it
// went away) to `restored_us`; frames taken in between must not be used.
struct Reconnection {
  int64_t last_contact_us = 0;
  int64_t lost_us = 0;      // when the client saw the board gone (or reset)
  int64_t restored_us = 0;  // when its state was restored (lasers off, motor, angle)
};

class CiclopClient {
 public:
  explicit CiclopClient(CiclopOptions options);
  ~CiclopClient();
  CiclopClient(const CiclopClient&) = delete;
  CiclopClient& operator=(const CiclopClient&) = delete;

  // Opens the port, resets the board (Ctrl-X), checks the banner ("Horus <version> ['$' for help]"),
  // reads "$$" for the motion settings, sets the feed rate and switches both lasers off. The table's
  // current position becomes angle 0.
  Status Connect();
  // Lasers off, motor off (best effort), port closed. Safe to call twice.
  void Close();
  bool connected() const { return port_ != nullptr; }

  // laser: 1 or 2 (M71T<n> / M70T<n>).
  Result<Ack> SetLaser(int laser, bool on);
  Result<Ack> SetMotor(bool on);
  Result<Ack> SetFeed(double deg_per_s);
  // Table to the absolute angle (degrees, the client's frame). With `wait`, also waits until the board
  // reports Idle at the target.
  Result<MoveAck> MoveTo(double angle_deg, bool wait = true);
  // Polls "?" until the board is Idle (at the last target). Returns the host time of that report.
  Result<int64_t> WaitIdle(int64_t timeout_us);
  Result<CiclopStatus> QueryStatus();
  // Declares the table's current angle (after an unplug during a move left it unknown).
  Status SetAngle(double angle_deg);
  // Sends one raw line and waits for its "ok" (the same recovery as the commands above).
  Result<Ack> Command(const std::string& line);

  // Looks without waiting whether the board is still there; false if the port is gone (the next command
  // re-connects).
  bool CheckAlive();

  // Trapezoid duration of a move of `distance_deg` at the current feed rate and the board's acceleration.
  int64_t MoveDurationUs(double distance_deg) const;

  const std::string& banner() const { return banner_; }
  bool laser(int n) const { return lasers_[n == 2 ? 1 : 0]; }
  bool motor() const { return motor_; }
  double angle_deg() const { return angle_deg_; }
  bool angle_known() const { return angle_known_; }
  LatencyStats latency() const;
  const std::vector<Reconnection>& reconnections() const { return reconnections_; }
  int garbage_lines() const { return garbage_lines_; }
  int lost_oks() const { return lost_oks_; }
  double acceleration_deg_per_s2() const { return accel_; }
  double max_rate_deg_per_s() const { return max_rate_; }
  double steps_per_deg() const { return steps_per_deg_; }

 private:
  enum class Kind { kIdempotent, kMove };
  Status OpenAndReset();
  Status ResetBoard();
  Status ReadSettings();
  Status Restore();
  Status Reconnect(int64_t lost_us);
  Result<Ack> Send(const std::string& line, Kind kind, double move_board_from = 0, double move_board_to = 0);
  // One try: writes the line, waits for ok. nullopt = no ok in time.
  Result<std::optional<Ack>> TryOnce(const std::string& line, int64_t sent_us, Kind kind);
  // "$G" fence: returns the time of a late "ok" seen before "[", if any.
  Result<std::optional<int64_t>> Fence();
  Result<CiclopStatus> QueryStatusOnce();
  // Handles one line that is not the awaited answer. Returns an error for a reset banner or an alarm.
  Status HandleStray(const SerialLine& line);
  void RecordLatency(const Ack& ack);
  Result<std::optional<SerialLine>> ReadBoardLine(int64_t deadline_us);

  CiclopOptions options_;
  std::unique_ptr<SerialPort> port_;
  std::string banner_;
  double feed_ = 0.0;
  double accel_ = 0.0;
  double max_rate_ = 0.0;
  double steps_per_deg_ = 0.0;
  bool lasers_[2] = {false, false};
  bool motor_ = false;
  double angle_deg_ = 0.0;      // last commanded table angle (client frame)
  double offset_deg_ = 0.0;     // table angle = board x + offset
  bool angle_known_ = true;
  bool move_pending_ = false;   // a move was sent and not yet seen Idle
  bool in_restore_ = false;
  bool move_not_sent_ = false;  // Send() re-connected before a move line left: MoveTo() builds it again
  std::vector<int64_t> latencies_;
  std::vector<Reconnection> reconnections_;
  int64_t last_contact_us_ = 0;
  int garbage_lines_ = 0;
  int lost_oks_ = 0;
};

}  // namespace rotoscan::device

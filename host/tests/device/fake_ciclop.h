// A fake bq Ciclop ZUM board running horus-fw, on a pseudo-terminal (openpty), for the tests of the serial
// port, the Ciclop client and the capture Board built on them. It runs on its own thread in real time
// (CLOCK_MONOTONIC, the clock of the client's time stamps) and speaks the dialect of ciclop_client.h the
// way horus-fw does (checked against bqlabs/horus-fw: gcode.c, protocol.c, report.c, system.c):
//
//  * Lines end at '\r' or '\n'; spaces and control characters are dropped, letters upper-cased; an empty
//    line gets no answer. '?' and Ctrl-X are real-time: picked out of the stream wherever they are.
//  * Timing: each byte takes 86.8 us on the wire at 115200 baud (both ways); a line runs `exec_delay_us`
//    after its last byte, in order; its "ok" leaves after a USB-serial latency drawn uniformly from
//    [reply_latency_min_us, reply_latency_max_us] (an FTDI adapter's latency timer is up to 16 ms), never
//    overtaking an earlier answer.
//  * G1X<a> is queued and answered at once, as GRBL does (the "ok" does not wait for the move). The table
//    turns with a trapezoid profile (feed capped at the max rate, `acceleration_deg_per_s2`), one block
//    after the other, each from rest to rest; positions are whole motor steps. Without a feed rate:
//    "error: Undefined feed rate".
//  * M71T<n> / M70T<n> switch laser n at once (not queued behind moves), M17 / M18 the driver.
//  * Ctrl-X: motion stops where it is, lasers off, feed rate forgotten, banner. Unplug + Replug = the
//    board re-opened after a USB re-plug: an Arduino-type board is reset by DTR, so it boots with position
//    0 where the table stands, lasers off, no feed rate, and prints its banner after `boot_us`.
//
// Faults: Reboot() (the board resets by itself and prints its banner), LoseOks(n) (the next n "ok" lines are never sent), SendGarbage(bytes), Unplug() (the pty is
// closed and the link removed: the client sees a hang-up) and Replug() (a new pty behind the same link, as
// a re-plugged adapter comes back at the same /dev/serial/by-id/ name), SetSilent() (reads, never answers).
//
// Ground truth, in host monotonic microseconds: when each laser really switched, and the physical table
// angle at any time (continuous across reboots: degrees from where the table stood at the fake's start).
#pragma once

#include <cstdint>
#include <condition_variable>
#include <functional>
#include <map>
#include <mutex>
#include <random>
#include <string>
#include <thread>
#include <vector>

namespace rotoscan::device::testing {

struct FakeCiclopOptions {
  std::string link_path;  // the path the client opens (a symlink to the pty's slave)
  std::string banner = "Horus 0.1 ['$' for help]";
  double steps_per_deg = 176.0;            // horus-fw defaults ($100, $110, $120)
  double max_rate_deg_per_s = 180.0;
  double acceleration_deg_per_s2 = 180.0;
  int64_t exec_delay_us = 300;
  int64_t reply_latency_min_us = 500;
  int64_t reply_latency_max_us = 2'000;
  int64_t boot_us = 20'000;   // re-plug to banner (a real ZUM board: ~1.5 s through its bootloader)
  uint32_t seed = 1;
};

struct FakeLaserEvent {
  int64_t time_us = 0;
  int laser = 0;  // 1 or 2
  bool on = false;
};

// One block of motion, physical degrees.
struct FakeMove {
  int64_t start_us = 0;
  int64_t end_us = 0;
  double from_deg = 0.0;
  double to_deg = 0.0;
  double rate = 0.0;   // cruise rate, deg/s
  double accel = 0.0;  // deg/s^2
  int64_t stopped_us = -1;  // >= 0 when a reset cut it short
};

class FakeCiclop {
 public:
  explicit FakeCiclop(FakeCiclopOptions options);
  ~FakeCiclop();
  FakeCiclop(const FakeCiclop&) = delete;
  FakeCiclop& operator=(const FakeCiclop&) = delete;

  // Creates the pty and the link and starts the board's thread; false (with a message in error()) if the
  // system has no pseudo-terminals.
  bool Start();
  const std::string& error() const { return error_; }

  // Faults.
  void LoseOks(int n);
  void SendGarbage(const std::string& bytes);
  void Unplug();
  void Replug();
  void SetSilent(bool silent);
  // The board resets by itself (a brown-out, a watchdog): position 0, lasers off, banner, same pty.
  void Reboot();

  // Truth.
  std::vector<FakeLaserEvent> laser_events() const;
  bool LaserAt(int laser, int64_t time_us) const;
  double TableAngleAt(int64_t time_us) const;  // physical degrees, whole steps
  std::vector<FakeMove> moves() const;
  std::vector<std::string> lines() const;  // every line executed, in order (after clean-up)
  int boots() const;  // power-ups and re-plugs (not Ctrl-X)
  bool motor() const;

 private:
  void Run();
  void OpenPty();   // mutex held
  void ClosePty();  // mutex held
  void Boot(int64_t now_us, bool hard);  // mutex held; hard = power-up or DTR, else Ctrl-X
  void OnBytes(const char* data, size_t n, int64_t now_us);
  void Execute(const std::string& line, int64_t now_us);
  void Reply(const std::string& text, int64_t ready_us, bool is_ok);
  void WriteNow(const std::string& text);
  void StopMotion(int64_t now_us);
  double PhysicalAt(int64_t t) const;  // mutex held
  std::string StatusReport(int64_t now_us) const;
  void Wake();

  FakeCiclopOptions options_;
  std::string error_;
  mutable std::mutex mutex_;
  std::thread thread_;
  bool stop_ = false;
  bool unplug_requested_ = false;
  std::condition_variable unplugged_;
  int wake_fd_ = -1;
  int master_ = -1;
  int keeper_ = -1;  // the fake's own slave fd: the pty stays up between the client's opens
  bool plugged_ = false;
  bool silent_ = false;
  int lose_oks_ = 0;
  std::mt19937 rng_;

  // Serial timing.
  int64_t rx_wire_free_us_ = 0;  // when the host->board wire is next free
  int64_t exec_free_us_ = 0;     // when the board's main loop is next free
  int64_t tx_free_us_ = 0;       // when the board->host side is next free
  std::string partial_;
  std::multimap<int64_t, std::function<void(int64_t)>> agenda_;  // due time -> action(now)

  // Board state.
  bool lasers_[2] = {false, false};
  bool motor_ = false;
  double feed_ = 0.0;              // deg/s, 0 = undefined
  double origin_deg_ = 0.0;        // physical angle of the board's position 0
  double board_target_deg_ = 0.0;  // where the last queued block ends, board frame
  int boots_ = 0;

  // Truth.
  std::vector<FakeLaserEvent> laser_events_;
  std::vector<FakeMove> moves_;
  std::vector<std::string> lines_;
};

}  // namespace rotoscan::device::testing

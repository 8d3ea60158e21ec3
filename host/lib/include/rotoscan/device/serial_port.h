// A serial port (a USB-serial adapter such as the bq Ciclop's ZUM board, or a pseudo-terminal in tests)
// through termios: raw, 8 data bits, no parity, one stop bit, no flow control, at a set baud rate.
//
//  * Nothing blocks forever: every read takes a deadline (host monotonic time) and uses poll().
//  * Unplug: a USB-serial adapter that goes away makes poll() report POLLHUP/POLLERR and read() fail (EIO,
//    ENXIO, ENODEV) or return 0 (end of file). The port is then marked gone: Write() and ReadLine() return
//    DeviceError, and the owner re-opens the path (a re-plugged adapter comes back at the same path or
//    /dev/serial/by-id/ link).
//  * Lines: the G-code boards answer in lines ended by "\r\n". ReadLine() hands out one line at a time,
//    without its terminator, with the host monotonic time at which its last byte was read; empty lines are
//    skipped. Bytes that are neither printable ASCII nor tab are kept (the caller decides what garbage is).
//  * The port is locked with flock(LOCK_EX | LOCK_NB) so two programs never talk to one board.
//
// Not thread-safe: one thread owns a SerialPort.
#pragma once

#include <cstdint>
#include <memory>
#include <optional>
#include <string>
#include <string_view>
#include <vector>

#include "rotoscan/core/status.h"

namespace rotoscan::device {

// CLOCK_MONOTONIC in microseconds: the clock of every time stamp of the serial boards (and of
// std::chrono::steady_clock on Linux).
int64_t MonotonicNowUs();

struct SerialLine {
  std::string text;  // without "\r\n"
  int64_t time_us = 0;  // MonotonicNowUs() when its terminator was read
};

class SerialPort {
 public:
  // Opens `path` (a tty) at `baud` (9600, 19200, 38400, 57600, 115200 or 230400), 8N1 raw. NotFound if
  // the path does not exist, DeviceError if it is not a tty or is in use by another program.
  static Result<std::unique_ptr<SerialPort>> Open(const std::string& path, int baud = 115200);

  ~SerialPort();
  SerialPort(const SerialPort&) = delete;
  SerialPort& operator=(const SerialPort&) = delete;

  // Writes all bytes (waits up to `timeout_us` for room in the output buffer). DeviceError when the port
  // is gone, Timeout when the bytes do not leave.
  Status Write(std::string_view bytes, int64_t timeout_us = 1'000'000);

  // The next line, or nullopt when `deadline_us` (MonotonicNowUs() time) passes first. DeviceError when
  // the port is gone (lines complete before that are returned first).
  Result<std::optional<SerialLine>> ReadLine(int64_t deadline_us);

  // Drops every byte received and not read yet (the kernel's buffer and ours).
  void FlushInput();

  // Looks, without waiting, whether the port is still there (a hang-up is seen at once); false once gone.
  bool CheckAlive();
  bool gone() const { return gone_; }
  const std::string& path() const { return path_; }

 private:
  SerialPort(int fd, std::string path) : fd_(fd), path_(std::move(path)) {}
  // Reads what is there into buffer_ (waiting up to the deadline for the first byte).
  Status Fill(int64_t deadline_us);
  std::optional<SerialLine> PopLine();

  int fd_ = -1;
  std::string path_;
  std::string buffer_;
  int64_t buffer_time_us_ = 0;
  bool gone_ = false;
};

// Serial ports that may be a USB-serial board (the Ciclop's ZUM board enumerates as /dev/ttyUSB* or
// /dev/ttyACM*), with their /dev/serial/by-id/ names where udev made them; sorted. Opening one would
// reset an Arduino-type board (DTR), so nothing is opened here.
struct SerialPortInfo {
  std::string path;   // "/dev/ttyUSB0"
  std::string by_id;  // "/dev/serial/by-id/usb-FTDI_FT231X_USB_UART_DN00XXXX-if00-port0", or empty
};
std::vector<SerialPortInfo> ListSerialPorts();

}  // namespace rotoscan::device

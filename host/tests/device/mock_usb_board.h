// A Rotoscan board on a mocked USB bus, for the hardware-in-the-loop tests: the host's real libusb
// transport talks to it through the kernel interface (usbdevfs ioctls) as emulated by umockdev.
//
// How: a umockdev testbed gets the board's sysfs description (data/rotoscan-board.umockdev), so udev and
// libusb enumerate it; an ioctl handler attached to its device node answers the usbdevfs ioctls libusb
// issues (GET_CAPABILITIES, CLAIMINTERFACE, SUBMITURB, REAPURBNDELAY, DISCARDURB, ...) from a VirtualBoard:
// bulk OUT URBs are handed to VirtualBoard::Receive, bulk IN URBs are filled from VirtualBoard::Transmit.
// umockdev runs the handler on its own worker thread; a second thread runs the board's time forward
// (`virtual_us_per_tick` every `real_us_per_tick`). One mutex serialises both around the board.
//
// The test binary must run under `umockdev-wrapper` (LD_PRELOAD of libumockdev-preload); InMockEnvironment()
// says whether it does.
//
// Faults are armed for the next packets: a lost OUT packet, a corrupted byte in an OUT or IN packet, an OUT
// packet delivered twice; Unplug() fails every URB and ioctl like a pulled cable and removes the device,
// Replug() brings it back at a new address with the board's state intact (a self-powered board). Several
// MockUsbBoards may be alive at once (Options::port, address, serial): they share the process's testbed.
#pragma once

#include <cstdint>
#include <functional>
#include <memory>
#include <string>

#include "rotoscan/device/transport.h"

namespace rotoscan::device::testing {

class MockUsbBoard {
 public:
  struct Options {
    int64_t virtual_us_per_tick = 1000;
    int64_t real_us_per_tick = 200;
    // The board's time follows the host's CLOCK_MONOTONIC instead (virtual_us_per_tick is ignored): device
    // time t is host time device_zero_host_us() + t, as a board whose crystal ran at the host's rate would
    // be. Each tick runs the board up to the host's time, so a late tick catches up instead of drifting.
    bool real_time = false;
    // Several boards on the one mocked bus (one umockdev testbed per process, shared by every MockUsbBoard
    // alive): each at its own root-hub port (sysfs "1-<port>") and address, with its own USB serial number
    // string (sysfs "serial", the kernel's copy of iSerialNumber; empty: the description's, which is the
    // FakeBoard's uid). A re-plug moves the board to the next free address.
    int port = 1;
    int address = 2;
    std::string serial;
  };

  static bool InMockEnvironment();

  // `board` must outlive this object.
  MockUsbBoard(VirtualBoard* board, const Options& options);
  explicit MockUsbBoard(VirtualBoard* board) : MockUsbBoard(board, Options{}) {}
  ~MockUsbBoard();
  MockUsbBoard(const MockUsbBoard&) = delete;
  MockUsbBoard& operator=(const MockUsbBoard&) = delete;

  void DropNextOut();
  void CorruptNextOut();
  void DuplicateNextOut();
  void CorruptNextIn();
  void Unplug();
  void Replug();
  int address() const;

  // Runs `f` with the board's time stopped (for reading the simulator's state).
  void WithBoardLocked(const std::function<void()>& f);
  // Options::real_time: runs the board up to the host's present time first (in the caller's thread), then
  // `f` with its time stopped, so that what `f` reads of the board's past is complete up to now even when
  // the clock thread lags on a loaded machine. Without real_time, as WithBoardLocked.
  void WithBoardAtNow(const std::function<void()>& f);
  // Stops or restarts the board's clock (the ioctls are still served). No effect with Options::real_time.
  void PauseTime(bool paused);
  // Options::real_time: the host time (CLOCK_MONOTONIC, microseconds) at which the board's time was 0.
  int64_t device_zero_host_us() const;

  struct Counters {
    int out_packets = 0, in_packets = 0, dropped = 0, corrupted = 0, duplicated = 0, unplugs = 0;
  };
  Counters counters() const;

 private:
  struct Impl;
  std::unique_ptr<Impl> impl_;
};

}  // namespace rotoscan::device::testing

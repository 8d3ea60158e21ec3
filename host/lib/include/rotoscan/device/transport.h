// The byte pipe between the host and the scanner board, behind one interface (STYLE.md §8):
//
//  * LibusbTransport (MakeLibusbTransport): the real board over USB, vendor class, one bulk OUT and one bulk
//    IN endpoint. Several IN transfers are kept submitted at all times by a private event thread, so bytes
//    the board sends while the caller is busy are queued, never lost. An unplug is seen as a failed
//    transfer; Open() again finds the board anew (re-open on unplug).
//  * InProcessTransport (MakeInProcessTransport): a VirtualBoard in the same process (the firmware core
//    built for the host, or a fake) running in virtual time. Reading advances that time, so tests are
//    deterministic and take no wall-clock time.
//
// A transport carries bytes only; framing and meaning are the Client's (client.h). Time: every transport
// has a host clock in microseconds (NowUs); the Client measures timeouts and round trips with it, so a
// virtual board gives virtual but consistent host times.
#pragma once

#include <cstdint>
#include <memory>
#include <string>
#include <vector>

#include "rotoscan/core/status.h"
#include "rotoscan/device/usb_ids.h"

namespace rotoscan::device {

class Transport {
 public:
  virtual ~Transport() = default;

  // Opens the board, or opens it again after Close() or an unplug. NotFound when no board is attached.
  virtual Status Open() = 0;
  // Releases the board. Safe to call when closed. Bytes received and not read yet are kept and returned by
  // Read() after the next Open(): a re-plugged board's stream goes on where it stopped.
  virtual void Close() = 0;
  // True from a successful Open() until Close() or until the board is seen gone.
  virtual bool IsOpen() const = 0;

  // Sends bytes to the board (bulk OUT). DeviceError when the board is gone, FailedPrecondition if closed.
  virtual Status Write(const std::vector<uint8_t>& bytes) = 0;

  // Waits up to `timeout_us` for bytes from the board and appends all that are queued to `*bytes`.
  // Returns OK with nothing appended on timeout; DeviceError when the board is gone (bytes that arrived
  // before are still returned first).
  virtual Status Read(std::vector<uint8_t>* bytes, int64_t timeout_us) = 0;

  // The host clock of this transport, microseconds from an arbitrary origin, monotonic.
  virtual int64_t NowUs() const = 0;

  // "usb 1209:0001 bus 1 address 2", "in-process board": for messages.
  virtual std::string Description() const = 0;
};

// ---- libusb ----

struct LibusbTransportOptions {
  uint16_t vendor_id = kUsbVendorId;
  uint16_t product_id = kUsbProductId;
  // Bus number and address of one board when several are attached; 0 = the first board found.
  int bus = 0;
  int address = 0;
  // The board's USB serial number (iSerialNumber: our firmware's unique id in hex, firmware/usb/usb_link.c;
  // compared without case): when set, Open() takes only the board with that serial, wherever it is, so a
  // re-plugged board is found again at its new address among several. Read from the kernel's copy
  // (sysfs .../serial), so no other board is opened to ask. Empty: any (with bus/address as above).
  std::string serial;
  int in_transfers = 4;         // IN transfers kept submitted; at least 2 so none is ever missing
  int in_transfer_size = 512;   // bytes per IN transfer, a multiple of the max packet size
  int write_timeout_ms = 1000;  // a bulk OUT transfer that takes longer fails with Timeout

  Status Check() const;
};

// The transport is created closed; call Open(). Fails only if libusb cannot start.
Result<std::unique_ptr<Transport>> MakeLibusbTransport(const LibusbTransportOptions& options = {});

// A board as seen on the bus, for `rotoscan device list`.
struct UsbBoard {
  int bus = 0;
  int address = 0;
  uint16_t vendor_id = 0;
  uint16_t product_id = 0;
  std::string port_path;  // "1-1.4"
  std::string serial;     // USB serial number string as the kernel read it (sysfs); empty when unknown
};

// Every attached device with the given ids (the Rotoscan ids by default); empty when none.
Result<std::vector<UsbBoard>> ListUsbBoards(uint16_t vendor_id = kUsbVendorId,
                                            uint16_t product_id = kUsbProductId);

// ---- in-process ----

// What sits at the other end of an in-process transport: the board's USB endpoints and its clock.
class VirtualBoard {
 public:
  virtual ~VirtualBoard() = default;
  // Bytes the host wrote to the bulk OUT endpoint.
  virtual void Receive(const uint8_t* data, size_t size) = 0;
  // Moves up to `max` bytes the board queued for the bulk IN endpoint into `out`; returns how many.
  virtual size_t Transmit(uint8_t* out, size_t max) = 0;
  // Runs the board's time forward by `us` microseconds (and its main loop).
  virtual void Advance(int64_t us) = 0;
};

struct InProcessTransportOptions {
  int64_t tick_us = 100;  // virtual time step while waiting in Read()
  Status Check() const;
};

// `board` must outlive the transport. Virtual host time starts at 0 and advances only in Read().
std::unique_ptr<Transport> MakeInProcessTransport(VirtualBoard* board,
                                                  const InProcessTransportOptions& options = {});

}  // namespace rotoscan::device

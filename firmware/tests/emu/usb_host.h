// The host side of the USB bus for the emulated board: transactions on the DWC2 model's USB side, with the
// emulated CPU run between them (a host controller retries a NAKed transaction; here each retry waits
// `retry_us` of emulated time). Control transfers and Linux's enumeration sequence (drivers/usb/core/hub.c
// hub_port_init, "new scheme", then usb_new_device), and bulk transfers for the board's vendor interface.
#pragma once

#include <cstdint>
#include <string>
#include <vector>

#include "f411_emu.h"

namespace rotoscan::fw_emu {

class UsbHost {
 public:
  using Bytes = std::vector<uint8_t>;

  explicit UsbHost(F411Emu* emu) : emu_(emu) {}

  struct Control {
    bool ok = false;       // the transfer completed (no STALL, no timeout)
    bool stalled = false;  // the device refused it
    Bytes data;            // the IN data stage
    std::string error;     // what went wrong when neither ok nor stalled
  };
  // One control transfer: SETUP, the data stage (IN: until a short packet or wLength), the status stage.
  Control ControlTransfer(uint8_t bm_request_type, uint8_t request, uint16_t value, uint16_t index,
                          uint16_t length);
  Control GetDescriptor(uint8_t type, uint8_t index, uint16_t length, uint16_t language = 0) {
    return ControlTransfer(0x80, 6, uint16_t(type << 8 | index), language, length);
  }

  struct Enumeration {
    bool ok = false;
    std::string error;
    Bytes device;                      // the 18-byte device descriptor
    Bytes configuration;               // the whole configuration descriptor
    std::vector<std::string> strings;  // manufacturer, product, serial (ASCII from UTF-16LE)
  };
  // Waits for the device to pull D+ up, then enumerates it as Linux does and sets configuration 1, at
  // `address`.
  Enumeration Enumerate(uint8_t address);

  // Bulk OUT: `data` in max-packet pieces, each retried while NAKed (at most `timeout_us` of emulated time
  // each). false on a STALL, no answer or timeout.
  bool BulkOut(uint8_t ep, const uint8_t* data, size_t size, uint64_t timeout_us = 200000);
  // Bulk IN: packets until a short one (a zero-length packet included) or `max` bytes; stops early, with
  // what it has, when the device NAKs (nothing queued). Returns false on a STALL or no answer.
  bool BulkIn(uint8_t ep, size_t max, Bytes* out);

  uint8_t address() const { return address_; }
  const std::string& error() const { return error_; }
  uint32_t retry_us = 10;

 private:
  int In(uint8_t ep, Bytes* packet, size_t max, uint64_t timeout_us);
  int Out(uint8_t ep, const uint8_t* data, size_t size, uint64_t timeout_us);

  F411Emu* emu_;
  uint8_t address_ = 0;
  std::string error_;
};

}  // namespace rotoscan::fw_emu

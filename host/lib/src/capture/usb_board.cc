// Backend `usb`: our STM32F411 board over libusb (device::Client, device/transport.h), on the real
// CLOCK_MONOTONIC clock. `usb` opens the first board; `usb:SERIAL` the one whose unique id (GET_INFO)
// is SERIAL, or `usb:BUS-ADDRESS` ("1-7") the one at that bus and address. An unplug is handled by the
// client (re-open and carry on) and a program stopped meanwhile is resumed (client_board.cc). With several
// boards attached, the board is re-opened by its USB serial number (our firmware's iSerialNumber is its
// unique id), so a re-plugged board is found again at its new address; only a board whose serial the
// kernel does not show stays pinned to its bus and address (a re-plug then ends the scan: resume it).
//
// Backend options: steps_per_rev (motor steps per table turn, default 19200), reconnect_ms (how long the
// client tries to re-open a board that went away before the scan fails, default 5000).
#include <algorithm>
#include <cctype>
#include <cstdio>

#include "backend_options.h"
#include "client_board.h"
#include "rotoscan/capture/factory.h"
#include "rotoscan/device/transport.h"

namespace rotoscan::capture {
namespace {

Result<std::unique_ptr<Board>> OpenUsbBoard(const std::string& argument, OpenContext* context) {
  ROTOSCAN_ASSIGN_OR_RETURN(const auto options,
                            internal::BackendOptions::Parse(context->options, "usb", {"steps_per_rev", "reconnect_ms"}));
  ROTOSCAN_ASSIGN_OR_RETURN(const double steps_per_rev, options.Number("steps_per_rev", 19200));
  ROTOSCAN_ASSIGN_OR_RETURN(const double reconnect_ms, options.Number("reconnect_ms", 5000));
  if (!(steps_per_rev >= 1 && steps_per_rev <= 1e7)) return InvalidArgumentError("usb: steps_per_rev out of range");
  if (!(reconnect_ms >= 0 && reconnect_ms <= 600'000)) return InvalidArgumentError("usb: reconnect_ms out of range");
  device::ClientOptions client_options;
  client_options.reconnect_timeout_us = static_cast<int64_t>(reconnect_ms * 1000);
  if (!context->clock) context->clock = MakeRealClock();
  if (context->clock->is_virtual()) return InvalidArgumentError("the usb board runs on the real clock, not a virtual one");

  ROTOSCAN_ASSIGN_OR_RETURN(const auto boards, device::ListUsbBoards());
  if (boards.empty()) return NotFoundError("no Rotoscan board on USB (is it plugged in? udev rules?)");
  std::vector<device::UsbBoard> candidates;
  int bus = 0, address = 0;
  char dash = 0;
  const bool by_address = std::sscanf(argument.c_str(), "%d%c%d", &bus, &dash, &address) == 3 && dash == '-';
  for (const auto& b : boards) {
    if (!by_address || (b.bus == bus && b.address == address)) candidates.push_back(b);
  }
  auto same = [](const std::string& a, const std::string& b) {
    return a.size() == b.size() && std::equal(a.begin(), a.end(), b.begin(), [](char x, char y) {
             return std::tolower(static_cast<unsigned char>(x)) == std::tolower(static_cast<unsigned char>(y));
           });
  };
  for (const auto& b : candidates) {
    // `usb:SERIAL`: a board whose USB serial is known and another is not opened at all (it may be
    // another program's).
    if (!argument.empty() && !by_address && !b.serial.empty() && !same(b.serial, argument)) continue;
    device::LibusbTransportOptions transport_options;
    // A re-plugged board comes back at a new address: with one board attached the transport opens "the
    // first board" so that the client's re-open after an unplug finds it again. With several, it opens the
    // one with this board's USB serial wherever it is, or, when the serial is unknown, the one at this
    // bus and address.
    if (by_address || boards.size() > 1) {
      if (!b.serial.empty()) {
        transport_options.serial = b.serial;
      } else {
        transport_options.bus = b.bus;
        transport_options.address = b.address;
      }
    }
    ROTOSCAN_ASSIGN_OR_RETURN(auto transport, device::MakeLibusbTransport(transport_options));
    auto client = device::Client::Connect(std::move(transport), client_options);
    if (!client.ok()) {
      if (candidates.size() == 1) return client.status();
      continue;
    }
    if (!argument.empty() && !by_address && !same(client.value()->info().uid, argument)) continue;
    BoardInfo info;
    info.name = "rotoscan board";
    info.serial = client.value()->info().uid;
    info.firmware_version = client.value()->info().firmware_version;
    internal::ClientBoardOptions board_options;
    board_options.steps_per_rev = static_cast<int>(steps_per_rev);
    ROTOSCAN_ASSIGN_OR_RETURN(auto board, internal::ClientBoard::Create(std::move(client).value(), context->clock,
                                                                        info, board_options));
    return std::unique_ptr<Board>(std::move(board));
  }
  return NotFoundError("no Rotoscan board matches 'usb:" + argument + "'");
}

Result<std::vector<DeviceListing>> ListUsb() {
  ROTOSCAN_ASSIGN_OR_RETURN(const auto boards, device::ListUsbBoards());
  std::vector<DeviceListing> out;
  for (const auto& b : boards) {
    out.push_back({"usb:" + std::to_string(b.bus) + "-" + std::to_string(b.address),
                   "rotoscan board, bus " + std::to_string(b.bus) + " address " + std::to_string(b.address) +
                       (b.port_path.empty() ? "" : " port " + b.port_path)});
  }
  return out;
}

}  // namespace

void RegisterCaptureBackend_usb(BackendRegistry* registry) {
  registry->AddBoard({"usb", "our STM32F411 board over USB (libusb)", OpenUsbBoard, ListUsb});
}

}  // namespace rotoscan::capture

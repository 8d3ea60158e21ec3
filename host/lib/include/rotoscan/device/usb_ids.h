// USB identity of the Rotoscan board, shared by the host transports, the CLI and the mocked endpoint of the
// hardware-in-the-loop tests. The firmware's device descriptor must say the same (firmware/port/stm32f411).
//
// The vendor id is pid.codes' open-hardware VID 0x1209 and the product id one of its test PIDs: fine for a
// bench and for tests, to be replaced by a PID registered at pid.codes before boards are shipped.
#pragma once

#include <cstdint>

namespace rotoscan::device {

inline constexpr uint16_t kUsbVendorId = 0x1209;
inline constexpr uint16_t kUsbProductId = 0x0001;
inline constexpr uint8_t kUsbInterfaceClass = 0xFF;  // vendor specific: no kernel driver binds to it
inline constexpr uint8_t kUsbInterface = 0;
inline constexpr uint8_t kUsbEndpointOut = 0x01;   // bulk, host -> board (commands)
inline constexpr uint8_t kUsbEndpointIn = 0x81;    // bulk, board -> host (acks, replies, events)
inline constexpr uint16_t kUsbMaxPacketSize = 64;  // full speed

}  // namespace rotoscan::device

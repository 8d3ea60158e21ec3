// A thin C++ driver over port/sim for the firmware tests: encodes commands, feeds them to the simulated USB
// endpoint, and decodes everything the device sends back.
#pragma once

#include <cstdint>
#include <vector>

#include "rotoscan_protocol.h"
#include "sim_port.h"

namespace rotoscan::firmware_test {

class SimDevice {
 public:
  // Power-on (optionally with the 32-bit timer near its wrap) and drain the BOOT status.
  explicit SimDevice(uint32_t counter_at_boot = 0);

  // Sends `msg` (version filled in) with a fresh seq unless `seq` >= 0; returns the seq used.
  uint16_t Send(proto_msg_t msg, int seq = -1);
  // Sends raw bytes as they are.
  void SendBytes(const std::vector<uint8_t>& bytes);
  // Sends a command and returns its answer (ACK, NACK, INFO, PONG or STATUS reply); events that arrive
  // meanwhile are kept for Events(). Fails the test (and returns a zeroed message) if none arrives.
  proto_msg_t Command(const proto_msg_t& msg);
  // Convenience constructors.
  static proto_msg_t Make(uint8_t type);

  // Reads and decodes everything queued by the device. Answers go to answers(), events to events().
  void Drain();
  std::vector<proto_msg_t>& answers() { return answers_; }
  std::vector<proto_msg_t>& events() { return events_; }
  // Events of one type, in order.
  std::vector<proto_msg_t> EventsOfType(uint8_t type) const;
  int decode_errors() const { return decode_errors_; }

  // Advances virtual time, draining the USB IN endpoint every `drain_every_us` (as a host would).
  void Advance(uint64_t us, uint64_t drain_every_us = 5000);
  // Advances until an event of `type` arrives (true) or `limit_us` passes (false).
  bool AdvanceUntil(uint8_t type, uint64_t limit_us, uint64_t step_us = 1000);

 private:
  uint16_t next_seq_ = 1;
  proto_deframer_t deframer_{};
  std::vector<proto_msg_t> answers_;
  std::vector<proto_msg_t> events_;
  int decode_errors_ = 0;
};

}  // namespace rotoscan::firmware_test

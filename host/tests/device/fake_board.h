// A small fake of the board for the client's unit tests: it speaks the protocol (rotoscan_protocol.h) with
// scripted behaviour and faults, in virtual time. The real firmware core (firmware/port/sim) is used by the
// hardware-in-the-loop tests; this fake exists to produce the faults and clocks the real one never shows.
#pragma once

#include <cstdint>
#include <deque>
#include <map>
#include <random>
#include <vector>

#include "rotoscan/device/transport.h"
#include "rotoscan_protocol.h"

namespace rotoscan::device::testing {

class FakeBoard : public VirtualBoard {
 public:
  // Board clock = offset_us + (1 + drift) * virtual time.
  double clock_offset_us = 1'000'000.0;
  double clock_drift = 0.0;
  // Each reply is queued this long after the command arrived, plus a uniform random extra in
  // [0, reply_jitter_us] (seeded).
  int64_t reply_delay_us = 200;
  int64_t reply_jitter_us = 0;
  uint8_t proto_major = PROTO_VERSION_MAJOR;
  int drop_commands = 0;               // the next N command frames are lost
  int corrupt_commands = 0;            // the next N command frames arrive damaged: NACK BAD_CRC
  int duplicate_answers = 0;           // the next N answers are sent twice
  bool refuse_with_bad_value = false;  // every command but GET_INFO / PING gets NACK BAD_VALUE field 2

  explicit FakeBoard(uint32_t seed = 1) : rng_(seed) { proto_deframer_init(&deframer_); }

  void Receive(const uint8_t* data, size_t size) override;
  size_t Transmit(uint8_t* out, size_t max) override;
  void Advance(int64_t us) override { now_us_ += us; }

  // Queues an event to be sent at once.
  void SendEvent(const proto_msg_t& event);
  uint64_t BoardTimeUs() const {
    return static_cast<uint64_t>(clock_offset_us + (1.0 + clock_drift) * static_cast<double>(now_us_));
  }

  // What the board saw: every command frame (seq, type) in arrival order, and how often each seq ran.
  std::vector<std::pair<uint16_t, uint8_t>> received;
  std::map<uint16_t, int> executed;

 private:
  void Queue(const proto_msg_t& msg, int64_t due_us);
  proto_deframer_t deframer_;
  int64_t now_us_ = 0;
  std::mt19937 rng_;
  std::map<uint16_t, proto_msg_t> answered_;             // seq -> answer, for duplicates
  std::multimap<int64_t, std::vector<uint8_t>> outbox_;  // due time -> frame bytes
  std::deque<uint8_t> tx_;
};

}  // namespace rotoscan::device::testing

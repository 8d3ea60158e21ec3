#include "sim_device.h"

#include <gtest/gtest.h>

#include <algorithm>

namespace rotoscan::firmware_test {

namespace {

bool IsAnswer(const proto_msg_t& m) {
  if (m.type == PROTO_ACK || m.type == PROTO_NACK || m.type == PROTO_INFO || m.type == PROTO_PONG ||
      m.type == PROTO_DIAG)
    return true;
  return m.type == PROTO_STATUS && m.body.status.cause == PROTO_CAUSE_REPLY;
}

}  // namespace

SimDevice::SimDevice(uint32_t counter_at_boot) {
  sim_reset_with_counter(counter_at_boot);
  proto_deframer_init(&deframer_);
  Drain();
  events_.clear();
}

proto_msg_t SimDevice::Make(uint8_t type) {
  proto_msg_t m;
  proto_msg_init(&m, type, 0);
  return m;
}

uint16_t SimDevice::Send(proto_msg_t msg, int seq) {
  msg.seq = seq >= 0 ? static_cast<uint16_t>(seq) : next_seq_++;
  uint8_t wire[PROTO_MAX_WIRE_FRAME];
  const int n = proto_encode_frame(&msg, wire, sizeof(wire));
  EXPECT_GT(n, 0) << "encoding " << proto_type_name(msg.type);
  if (n > 0) sim_usb_receive(wire, static_cast<size_t>(n));
  return msg.seq;
}

void SimDevice::SendBytes(const std::vector<uint8_t>& bytes) {
  sim_usb_receive(bytes.data(), bytes.size());
}

void SimDevice::Drain() {
  uint8_t buf[512];
  for (;;) {
    const size_t n = sim_usb_transmit(buf, sizeof(buf));
    if (n == 0) break;
    for (size_t i = 0; i < n; ++i) {
      size_t len = 0;
      const int r = proto_deframer_push(&deframer_, buf[i], &len);
      if (r < 0) ++decode_errors_;
      if (r != 1) continue;
      proto_msg_t m;
      if (proto_decode_frame(deframer_.buf, len, &m) != 0) {
        ++decode_errors_;
        continue;
      }
      (IsAnswer(m) ? answers_ : events_).push_back(m);
    }
  }
}

proto_msg_t SimDevice::Command(const proto_msg_t& msg) {
  answers_.clear();
  const uint16_t seq = Send(msg);
  Drain();
  for (const proto_msg_t& a : answers_) {
    if (a.seq == seq) return a;
  }
  ADD_FAILURE() << "no answer to " << proto_type_name(msg.type) << " seq " << seq;
  proto_msg_t none;
  proto_msg_init(&none, 0, 0);
  return none;
}

std::vector<proto_msg_t> SimDevice::EventsOfType(uint8_t type) const {
  std::vector<proto_msg_t> out;
  std::copy_if(events_.begin(), events_.end(), std::back_inserter(out),
               [type](const proto_msg_t& m) { return m.type == type; });
  return out;
}

void SimDevice::Advance(uint64_t us, uint64_t drain_every_us) {
  while (us > 0) {
    const uint64_t step = std::min(us, drain_every_us);
    sim_advance_us(step);
    Drain();
    us -= step;
  }
}

bool SimDevice::AdvanceUntil(uint8_t type, uint64_t limit_us, uint64_t step_us) {
  const size_t before = EventsOfType(type).size();
  for (uint64_t t = 0; t < limit_us; t += step_us) {
    Advance(step_us, step_us);
    if (EventsOfType(type).size() > before) return true;
  }
  return false;
}

}  // namespace rotoscan::firmware_test

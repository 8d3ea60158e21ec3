#include "fake_board.h"

#include <cstring>

namespace rotoscan::device::testing {

void FakeBoard::Queue(const proto_msg_t& msg, int64_t due_us) {
  std::vector<uint8_t> frame(PROTO_MAX_WIRE_FRAME);
  const int n = proto_encode_frame(&msg, frame.data(), frame.size());
  if (n <= 0) return;
  frame.resize(static_cast<size_t>(n));
  outbox_.emplace(due_us, frame);
}

void FakeBoard::SendEvent(const proto_msg_t& event) {
  Queue(event, now_us_);
}

void FakeBoard::Receive(const uint8_t* data, size_t size) {
  for (size_t i = 0; i < size; ++i) {
    size_t frame_len = 0;
    if (proto_deframer_push(&deframer_, data[i], &frame_len) != 1) continue;
    proto_msg_t cmd;
    const int decoded = proto_decode_frame(deframer_.buf, frame_len, &cmd);
    if (drop_commands > 0) {
      --drop_commands;
      continue;
    }
    std::uniform_int_distribution<int64_t> jitter(0, reply_jitter_us);
    const int64_t due = now_us_ + reply_delay_us + (reply_jitter_us > 0 ? jitter(rng_) : 0);
    proto_msg_t answer;
    if (corrupt_commands > 0 || decoded != 0) {
      if (corrupt_commands > 0) --corrupt_commands;
      proto_msg_init(&answer, PROTO_NACK, cmd.seq);
      answer.body.ack.acked_seq = cmd.seq;
      answer.body.ack.acked_type = 0;
      answer.body.ack.status = PROTO_ST_BAD_CRC;
      Queue(answer, due);
      continue;
    }
    received.emplace_back(cmd.seq, cmd.type);
    auto done = answered_.find(cmd.seq);
    if (done != answered_.end()) {
      Queue(done->second, due);  // a duplicate: same answer, not executed again
      continue;
    }
    ++executed[cmd.seq];
    if (cmd.type == PROTO_GET_INFO) {
      proto_msg_init(&answer, PROTO_INFO, cmd.seq);
      proto_info_t& info = answer.body.info;
      info.proto_major = proto_major;
      info.proto_minor = 3;
      info.capabilities = PROTO_CAP_STEPPER | PROTO_CAP_LASERS | PROTO_CAP_SIMULATED;
      info.fw_major = 0;
      info.fw_minor = 4;
      info.fw_patch = 2;
      info.max_payload = PROTO_MAX_PAYLOAD;
      info.max_shots = PROTO_MAX_SHOTS;
      for (int k = 0; k < PROTO_UID_SIZE; ++k) info.uid[k] = static_cast<uint8_t>(0xA0 + k);
    } else if (cmd.type == PROTO_PING) {
      proto_msg_init(&answer, PROTO_PONG, cmd.seq);
      answer.body.pong.host_time_us = cmd.body.ping.host_time_us;
      // The board reads its clock when it handles the PING: somewhere inside the round trip.
      const int64_t handled = now_us_ + (due - now_us_) / 3;
      answer.body.pong.device_time_us =
          static_cast<uint64_t>(clock_offset_us + (1.0 + clock_drift) * static_cast<double>(handled));
    } else if (cmd.type == PROTO_GET_STATUS) {
      proto_msg_init(&answer, PROTO_STATUS, cmd.seq);
      answer.body.status.cause = PROTO_CAUSE_REPLY;
      answer.body.status.time_us = BoardTimeUs();
    } else if (refuse_with_bad_value) {
      proto_msg_init(&answer, PROTO_NACK, cmd.seq);
      answer.body.ack.acked_seq = cmd.seq;
      answer.body.ack.acked_type = cmd.type;
      answer.body.ack.status = PROTO_ST_BAD_VALUE;
      answer.body.ack.detail = 2;
    } else {
      proto_msg_init(&answer, PROTO_ACK, cmd.seq);
      answer.body.ack.acked_seq = cmd.seq;
      answer.body.ack.acked_type = cmd.type;
    }
    answer.version = proto_major;
    answered_[cmd.seq] = answer;
    Queue(answer, due);
    if (duplicate_answers > 0) {
      --duplicate_answers;
      Queue(answer, due + 1);
    }
  }
}

size_t FakeBoard::Transmit(uint8_t* out, size_t max) {
  while (!outbox_.empty() && outbox_.begin()->first <= now_us_) {
    tx_.insert(tx_.end(), outbox_.begin()->second.begin(), outbox_.begin()->second.end());
    outbox_.erase(outbox_.begin());
  }
  size_t n = 0;
  while (n < max && !tx_.empty()) {
    out[n++] = tx_.front();
    tx_.pop_front();
  }
  return n;
}

}  // namespace rotoscan::device::testing

// The golden frames of protocol/vectors/ (see its README): each decodes to the values listed in
// vectors.json, and those values encode back to the very same bytes. The invalid ones are refused with the
// listed error.
#include <gtest/gtest.h>

#include <cerrno>
#include <fstream>
#include <nlohmann/json.hpp>
#include <sstream>
#include <string>
#include <vector>

#include "golden_vectors.h"
#include "rotoscan_protocol.h"

namespace {

using nlohmann::json;

using rotoscan::protocol_testing::ReadHexVector;
using rotoscan::protocol_testing::ReadVectorManifest;

json Fields(const proto_msg_t& m) {
  const auto& b = m.body;
  switch (m.type) {
    case PROTO_PING: return {{"host_time_us", b.ping.host_time_us}};
    case PROTO_PONG:
      return {{"host_time_us", b.pong.host_time_us}, {"device_time_us", b.pong.device_time_us}};
    case PROTO_INFO: {
      json uid = json::array();
      for (uint8_t u : b.info.uid) uid.push_back(u);
      return {{"proto_major", b.info.proto_major},
              {"proto_minor", b.info.proto_minor},
              {"capabilities", b.info.capabilities},
              {"fw_major", b.info.fw_major},
              {"fw_minor", b.info.fw_minor},
              {"fw_patch", b.info.fw_patch},
              {"max_payload", b.info.max_payload},
              {"max_shots", b.info.max_shots},
              {"uid", uid}};
    }
    case PROTO_SET_CONFIG:
      return {
          {"start_rate_hz", b.config.start_rate_hz},       {"max_rate_hz", b.config.max_rate_hz},
          {"accel_hz_per_s", b.config.accel_hz_per_s},     {"trigger_pulse_us", b.config.trigger_pulse_us},
          {"laser_timeout_ms", b.config.laser_timeout_ms}, {"flags", b.config.flags}};
    case PROTO_MOTOR_ENABLE: return {{"enable", b.motor_enable.enable}};
    case PROTO_MOVE: return {{"steps", b.move.steps}};
    case PROTO_SET_LASERS: return {{"mask", b.set_lasers.mask}};
    case PROTO_TRIGGER:
      return {{"laser_mask", b.trigger.laser_mask},
              {"laser_lead_us", b.trigger.laser_lead_us},
              {"exposure_us", b.trigger.exposure_us}};
    case PROTO_LOAD_PROGRAM: {
      json shots = json::array();
      for (int i = 0; i < b.program.shot_count; ++i) {
        shots.push_back(
            {{"laser_mask", b.program.shots[i].laser_mask}, {"exposure_us", b.program.shots[i].exposure_us}});
      }
      return {{"step_count", b.program.step_count}, {"steps_per_move", b.program.steps_per_move},
              {"settle_us", b.program.settle_us},   {"laser_lead_us", b.program.laser_lead_us},
              {"shot_count", b.program.shot_count}, {"shots", shots}};
    }
    case PROTO_START: return {{"first_step", b.start.first_step}};
    case PROTO_ACK:
    case PROTO_NACK:
      return {{"acked_seq", b.ack.acked_seq},
              {"acked_type", b.ack.acked_type},
              {"status", b.ack.status},
              {"detail", b.ack.detail}};
    case PROTO_TRIGGER_EVENT: {
      const proto_trigger_event_t& e = b.trigger_event;
      return {{"trigger_seq", e.trigger_seq},
              {"time_us", e.time_us},
              {"exposure_seen_us", e.exposure_seen_us},
              {"position", e.position},
              {"step_index", e.step_index},
              {"laser_mask", e.laser_mask},
              {"shot", e.shot},
              {"flags", e.flags}};
    }
    case PROTO_MOVE_DONE:
      return {{"move_seq", b.move_done.move_seq},
              {"time_us", b.move_done.time_us},
              {"position", b.move_done.position},
              {"status", b.move_done.status}};
    case PROTO_STATUS: {
      const proto_status_t& s = b.status;
      return {{"status_seq", s.status_seq},
              {"time_us", s.time_us},
              {"cause", s.cause},
              {"state", s.state},
              {"flags", s.flags},
              {"lasers", s.lasers},
              {"position", s.position},
              {"program_next_step", s.program_next_step},
              {"program_steps", s.program_steps},
              {"trigger_count", s.trigger_count},
              {"rx_errors", s.rx_errors},
              {"events_dropped", s.events_dropped}};
    }
    case PROTO_DIAG: {
      const proto_diag_t& d = b.diag;
      return {{"flags", d.flags},
              {"cpu_hz", d.cpu_hz},
              {"step_isr_cycles_max", d.step_isr_cycles_max},
              {"step_isr_cycles_last", d.step_isr_cycles_last},
              {"fault_count", d.fault_count},
              {"fault_vector", d.fault_vector},
              {"fault_pc", d.fault_pc},
              {"fault_lr", d.fault_lr},
              {"fault_psr", d.fault_psr},
              {"fault_cfsr", d.fault_cfsr},
              {"fault_hfsr", d.fault_hfsr}};
    }
    case PROTO_LOG:
      return {{"log_seq", b.log.log_seq},
              {"level", b.log.level},
              {"length", b.log.length},
              {"text", std::string(b.log.text)}};
    default: return json::object();
  }
}

int ErrorCode(const std::string& name) {
  if (name == "EBADMSG") return -EBADMSG;
  if (name == "EPROTO") return -EPROTO;
  if (name == "ENOMSG") return -ENOMSG;
  if (name == "EMSGSIZE") return -EMSGSIZE;
  ADD_FAILURE() << "unknown error name " << name;
  return 1;
}


TEST(ProtocolVectors, EveryGoldenFrameDecodesToItsListedValues) {
  const json manifest = ReadVectorManifest();
  ASSERT_GE(manifest.size(), 27u);
  int valid = 0;
  for (const json& v : manifest) {
    const std::string file = v.at("file");
    SCOPED_TRACE(file);
    const std::vector<uint8_t> wire = ReadHexVector(file);
    ASSERT_FALSE(wire.empty());
    EXPECT_EQ(wire.back(), 0x00) << "a frame ends with its delimiter";
    proto_msg_t m;
    const int rc = proto_decode_frame(wire.data(), wire.size(), &m);
    if (!v.at("error").is_null()) {
      EXPECT_EQ(rc, ErrorCode(v.at("error")));
      continue;
    }
    ++valid;
    ASSERT_EQ(rc, 0);
    EXPECT_EQ(m.type, v.at("type_code").get<int>());
    EXPECT_STREQ(proto_type_name(m.type), v.at("type").get<std::string>().c_str());
    EXPECT_EQ(m.seq, v.at("seq").get<int>());
    EXPECT_EQ(Fields(m), v.at("fields"));
    // And back: the same bytes.
    uint8_t again[PROTO_MAX_WIRE_FRAME];
    const int n = proto_encode_frame(&m, again, sizeof(again));
    ASSERT_EQ(n, static_cast<int>(wire.size()));
    EXPECT_EQ(std::vector<uint8_t>(again, again + n), wire);
  }
  EXPECT_EQ(valid, 22);
}

// One frame checked by hand against the README's byte-by-byte walk-through, independently of the codec.
TEST(ProtocolVectors, PingMatchesTheReadmeByteByByte) {
  const std::vector<uint8_t> wire = ReadHexVector("03_ping.hex");
  const std::vector<uint8_t> expected = {0x04, 0x01, 0x02, 0x02,  // COBS code, version 1, PING, seq lo
                                         0x0D, 0xEF, 0xCD, 0xAB, 0x89, 0x67,
                                         0x45, 0x23,                           // code for the zero seq hi
                                         0x01, 0xD2, 0xDE, 0xF0, 0x9D, 0x00};  // CRC 0x9DF0DED2, end
  EXPECT_EQ(wire, expected);
}

}  // namespace

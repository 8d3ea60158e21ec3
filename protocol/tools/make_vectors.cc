// Writes the golden frames of protocol/vectors/ (NN_name.hex and vectors.json). Run it only when a new
// vector is added or the major version changes: the files it writes are frozen, and the tests (firmware
// and host) check that today's codec still decodes them to the values in vectors.json and encodes those
// values back to the same bytes.
//
//   build-x/protocol/tools/rotoscan_make_vectors protocol/vectors
#include <cinttypes>
#include <cstdio>
#include <cstring>
#include <string>
#include <vector>

#include "rotoscan_protocol.h"

namespace {

struct Vector {
  std::string name;
  std::string comment;
  proto_msg_t msg;
  std::string fields_json;    // the expected decoded fields
  std::vector<uint8_t> wire;  // set for invalid vectors (hand-made bytes)
  std::string error;          // "" for a valid frame, else the errno name proto_decode_frame returns
};

std::string Hex(const std::vector<uint8_t>& bytes) {
  std::string out;
  char buf[4];
  for (size_t i = 0; i < bytes.size(); ++i) {
    std::snprintf(buf, sizeof(buf), "%02x", bytes[i]);
    out += buf;
    out += (i + 1) % 16 == 0 || i + 1 == bytes.size() ? "\n" : " ";
  }
  return out;
}

std::vector<uint8_t> Encode(const proto_msg_t& m) {
  std::vector<uint8_t> wire(PROTO_MAX_WIRE_FRAME);
  const int n = proto_encode_frame(&m, wire.data(), wire.size());
  if (n < 0) std::abort();
  wire.resize(static_cast<size_t>(n));
  return wire;
}

std::vector<uint8_t> Raw(const proto_msg_t& m) {
  std::vector<uint8_t> raw(PROTO_MAX_RAW_FRAME);
  const int n = proto_pack(&m, raw.data(), raw.size());
  if (n < 0) std::abort();
  raw.resize(static_cast<size_t>(n));
  return raw;
}

std::vector<uint8_t> Stuff(const std::vector<uint8_t>& raw) {
  std::vector<uint8_t> wire(PROTO_COBS_MAX_ENCODED(raw.size()) + 1);
  const int n = proto_cobs_encode(raw.data(), raw.size(), wire.data(), wire.size());
  wire.resize(static_cast<size_t>(n));
  wire.push_back(0);
  return wire;
}

proto_msg_t Msg(uint8_t type, uint16_t seq) {
  proto_msg_t m;
  proto_msg_init(&m, type, seq);
  return m;
}

}  // namespace

int main(int argc, char** argv) {
  if (argc != 2) {
    std::fprintf(stderr, "usage: %s <protocol/vectors directory>\n", argv[0]);
    return 2;
  }
  const std::string dir = argv[1];
  std::vector<Vector> v;

  v.push_back({"01_get_info", "GET_INFO, seq 1: no payload", Msg(PROTO_GET_INFO, 1), "{}", {}, ""});
  {
    proto_msg_t m = Msg(PROTO_INFO, 1);
    m.body.info = {1,
                   0,
                   PROTO_CAP_STEPPER | PROTO_CAP_LASERS | PROTO_CAP_TRIGGER_OUT | PROTO_CAP_EXPOSURE_IN |
                       PROTO_CAP_PROGRAM | PROTO_CAP_LASER_SAFETY | PROTO_CAP_SIMULATED,
                   0,
                   1,
                   0,
                   128,
                   8,
                   {'R', 'O', 'T', 'O', 'S', 'C', 'A', 'N', 'S', 'I', 'M', '1'}};
    v.push_back({"02_info",
                 "INFO answering seq 1: protocol 1.0, firmware 0.1.0, the simulated board",
                 m,
                 R"({"proto_major": 1, "proto_minor": 0, "capabilities": 2147483711, "fw_major": 0,
     "fw_minor": 1, "fw_patch": 0, "max_payload": 128, "max_shots": 8,
     "uid": [82, 79, 84, 79, 83, 67, 65, 78, 83, 73, 77, 49]})",
                 {},
                 ""});
  }
  {
    proto_msg_t m = Msg(PROTO_PING, 2);
    m.body.ping.host_time_us = 0x0123456789ABCDEFull;
    v.push_back({"03_ping",
                 "PING, seq 2, host time 0x0123456789abcdef",
                 m,
                 R"({"host_time_us": 81985529216486895})",
                 {},
                 ""});
  }
  {
    proto_msg_t m = Msg(PROTO_PONG, 2);
    m.body.pong.host_time_us = 0x0123456789ABCDEFull;
    m.body.pong.device_time_us = 1000000;
    v.push_back({"04_pong",
                 "PONG answering seq 2: device time 1 s",
                 m,
                 R"({"host_time_us": 81985529216486895, "device_time_us": 1000000})",
                 {},
                 ""});
  }
  {
    proto_msg_t m = Msg(PROTO_SET_CONFIG, 3);
    m.body.config = {200, 2000, 8000, 100, 2000, PROTO_CONFIG_INVERT_DIR};
    v.push_back(
        {"05_set_config",
         "SET_CONFIG, seq 3",
         m,
         R"({"start_rate_hz": 200, "max_rate_hz": 2000, "accel_hz_per_s": 8000, "trigger_pulse_us": 100,
     "laser_timeout_ms": 2000, "flags": 1})",
         {},
         ""});
  }
  {
    proto_msg_t m = Msg(PROTO_MOTOR_ENABLE, 4);
    m.body.motor_enable.enable = 1;
    v.push_back({"06_motor_enable", "MOTOR_ENABLE on, seq 4", m, R"({"enable": 1})", {}, ""});
  }
  {
    proto_msg_t m = Msg(PROTO_MOVE, 0x0105);
    m.body.move.steps = -1600;
    v.push_back({"07_move",
                 "MOVE -1600 steps, seq 0x0105 (a negative value, a seq above 255)",
                 m,
                 R"({"steps": -1600})",
                 {},
                 ""});
  }
  {
    proto_msg_t m = Msg(PROTO_SET_LASERS, 6);
    m.body.set_lasers.mask = PROTO_LASER_ALL;
    v.push_back({"08_set_lasers", "SET_LASERS both, seq 6", m, R"({"mask": 3})", {}, ""});
  }
  {
    proto_msg_t m = Msg(PROTO_TRIGGER, 7);
    m.body.trigger = {PROTO_LASER_LEFT, 300, 20000};
    v.push_back({"09_trigger",
                 "TRIGGER with the left laser, seq 7",
                 m,
                 R"({"laser_mask": 1, "laser_lead_us": 300, "exposure_us": 20000})",
                 {},
                 ""});
  }
  {
    proto_msg_t m = Msg(PROTO_LOAD_PROGRAM, 8);
    proto_program_t& p = m.body.program;
    p.step_count = 1200;
    p.steps_per_move = 16;
    p.settle_us = 50000;
    p.laser_lead_us = 300;
    p.shot_count = 4;
    p.shots[0] = {PROTO_LASER_LEFT, 20000};
    p.shots[1] = {PROTO_LASER_RIGHT, 20000};
    p.shots[2] = {0, 20000};
    p.shots[3] = {0, 80000};
    v.push_back({"10_load_program",
                 "LOAD_PROGRAM, seq 8: 1200 steps of 16, left / right / off / natural",
                 m,
                 R"({"step_count": 1200, "steps_per_move": 16, "settle_us": 50000, "laser_lead_us": 300,
     "shot_count": 4, "shots": [{"laser_mask": 1, "exposure_us": 20000}, {"laser_mask": 2, "exposure_us": 20000},
     {"laser_mask": 0, "exposure_us": 20000}, {"laser_mask": 0, "exposure_us": 80000}]})",
                 {},
                 ""});
  }
  {
    proto_msg_t m = Msg(PROTO_START, 9);
    m.body.start.first_step = 417;
    v.push_back({"11_start", "START at step 417 (a resume), seq 9", m, R"({"first_step": 417})", {}, ""});
  }
  v.push_back({"12_abort", "ABORT, seq 10", Msg(PROTO_ABORT, 10), "{}", {}, ""});
  v.push_back({"13_get_status", "GET_STATUS, seq 11", Msg(PROTO_GET_STATUS, 11), "{}", {}, ""});
  {
    proto_msg_t m = Msg(PROTO_ACK, 8);
    m.body.ack = {8, PROTO_LOAD_PROGRAM, PROTO_ST_OK, 0};
    v.push_back({"14_ack",
                 "ACK of LOAD_PROGRAM seq 8",
                 m,
                 R"({"acked_seq": 8, "acked_type": 8, "status": 0, "detail": 0})",
                 {},
                 ""});
  }
  {
    proto_msg_t m = Msg(PROTO_NACK, 0x0105);
    m.body.ack = {0x0105, PROTO_MOVE, PROTO_ST_BUSY, 0};
    v.push_back({"15_nack",
                 "NACK BUSY of MOVE seq 0x0105",
                 m,
                 R"({"acked_seq": 261, "acked_type": 5, "status": 7, "detail": 0})",
                 {},
                 ""});
  }
  {
    proto_msg_t m = Msg(PROTO_TRIGGER_EVENT, 0x0203);
    m.body.trigger_event = {4801,
                            0x00000001DCD65000ull,
                            0x00000001DCD6500Aull,
                            -19200,
                            1200,
                            PROTO_LASER_RIGHT,
                            1,
                            PROTO_TRIG_IN_PROGRAM | PROTO_TRIG_EXPOSURE_SEEN};
    v.push_back(
        {"16_trigger_event",
         "TRIGGER_EVENT, event frame 0x0203: trigger 4801 at 8000 s",
         m,
         R"({"trigger_seq": 4801, "time_us": 8000000000, "exposure_seen_us": 8000000010, "position": -19200,
     "step_index": 1200, "laser_mask": 2, "shot": 1, "flags": 3})",
         {},
         ""});
  }
  {
    proto_msg_t m = Msg(PROTO_MOVE_DONE, 0x0204);
    m.body.move_done = {3, 12345678, -1600, PROTO_ST_OK};
    v.push_back({"17_move_done",
                 "MOVE_DONE, event frame 0x0204",
                 m,
                 R"({"move_seq": 3, "time_us": 12345678, "position": -1600, "status": 0})",
                 {},
                 ""});
  }
  {
    proto_msg_t m = Msg(PROTO_STATUS, 11);
    proto_status_t& s = m.body.status;
    s = {17,
         5000000,
         PROTO_CAUSE_REPLY,
         PROTO_STATE_RUNNING,
         PROTO_FLAG_MOTOR_ENABLED | PROTO_FLAG_PROGRAM_LOADED,
         PROTO_LASER_LEFT,
         6672,
         417,
         1200,
         1668,
         2,
         0};
    v.push_back({"18_status",
                 "STATUS answering GET_STATUS seq 11, a program running",
                 m,
                 R"({"status_seq": 17, "time_us": 5000000, "cause": 0, "state": 2, "flags": 3, "lasers": 1,
     "position": 6672, "program_next_step": 417, "program_steps": 1200, "trigger_count": 1668, "rx_errors": 2,
     "events_dropped": 0})",
                 {},
                 ""});
  }
  {
    proto_msg_t m = Msg(PROTO_LOG, 0x0205);
    m.body.log.log_seq = 0;
    m.body.log.level = PROTO_LOG_WARNING;
    m.body.log.length = 5;
    std::memcpy(m.body.log.text, "hello", 6);
    v.push_back({"19_log",
                 "LOG warning \"hello\", event frame 0x0205",
                 m,
                 R"({"log_seq": 0, "level": 2, "length": 5, "text": "hello"})",
                 {},
                 ""});
  }
  {
    proto_msg_t m = Msg(PROTO_PONG, 0);
    v.push_back({"20_pong_zeros",
                 "PONG, seq 0, both times 0: mostly zeros, a COBS workout",
                 m,
                 R"({"host_time_us": 0, "device_time_us": 0})",
                 {},
                 ""});
  }

  // Protocol 1.1.
  v.push_back({"21_get_diag", "GET_DIAG, seq 15 (protocol 1.1)", Msg(PROTO_GET_DIAG, 15), "{}", {}, ""});
  {
    proto_msg_t m = Msg(PROTO_DIAG, 15);
    m.body.diag = {PROTO_DIAG_CYCLES_VALID | PROTO_DIAG_FAULT_VALID,
                   96000000,
                   228,
                   215,
                   1,
                   3,
                   0x080012A4,
                   0x08000F31,
                   0x61000000,
                   0x00000400,
                   0x40000000};
    v.push_back(
        {"22_diag",
         "DIAG answering seq 15: step interrupt at most 228 cycles at 96 MHz, a HardFault before the reset",
         m,
         R"({"flags": 3, "cpu_hz": 96000000, "step_isr_cycles_max": 228, "step_isr_cycles_last": 215,
     "fault_count": 1, "fault_vector": 3, "fault_pc": 134222500, "fault_lr": 134221617, "fault_psr": 1627389952,
     "fault_cfsr": 1024, "fault_hfsr": 1073741824})",
         {},
         ""});
  }

  // Invalid frames: what a decoder must refuse.
  {
    proto_msg_t m = Msg(PROTO_PING, 2);
    m.body.ping.host_time_us = 0x0123456789ABCDEFull;
    std::vector<uint8_t> raw = Raw(m);
    raw[raw.size() - 1] ^= 0x80;  // damage the CRC's last byte
    v.push_back(
        {"90_bad_crc", "03_ping with the top bit of the CRC flipped", m, "{}", Stuff(raw), "EBADMSG"});
  }
  {
    std::vector<uint8_t> raw = {1, 0x3F, 0x0C, 0x00};
    const uint32_t crc = proto_crc32(0, raw.data(), raw.size());
    for (int i = 0; i < 4; ++i) raw.push_back(static_cast<uint8_t>(crc >> (8 * i)));
    v.push_back({"91_unknown_type", "type 0x3F (unassigned), seq 12, good CRC", Msg(0x3F, 12), "{}",
                 Stuff(raw), "ENOMSG"});
  }
  {
    std::vector<uint8_t> raw = {1, PROTO_MOVE, 0x0D, 0x00, 0x10, 0x27};  // a MOVE with 2 payload bytes, not 4
    const uint32_t crc = proto_crc32(0, raw.data(), raw.size());
    for (int i = 0; i < 4; ++i) raw.push_back(static_cast<uint8_t>(crc >> (8 * i)));
    v.push_back({"92_bad_length", "MOVE, seq 13, with a 2-byte payload", Msg(PROTO_MOVE, 13), "{}",
                 Stuff(raw), "EMSGSIZE"});
  }
  {
    std::vector<uint8_t> wire = {0x07, 0x01, 0x02, 0x0E, 0x00};  // code 7 promises 6 bytes, 3 follow
    v.push_back(
        {"93_bad_cobs", "a COBS code running past the frame's end", Msg(0, 0), "{}", wire, "EBADMSG"});
  }
  {
    std::vector<uint8_t> raw = {2, PROTO_PING, 0x0E, 0x00, 1, 2, 3, 4, 5, 6, 7, 8};
    const uint32_t crc = proto_crc32(0, raw.data(), raw.size());
    for (int i = 0; i < 4; ++i) raw.push_back(static_cast<uint8_t>(crc >> (8 * i)));
    v.push_back({"94_other_major", "PING, seq 14, from protocol major 2", Msg(PROTO_PING, 14), "{}",
                 Stuff(raw), "EPROTO"});
  }

  std::string json = "[\n";
  for (size_t i = 0; i < v.size(); ++i) {
    Vector& x = v[i];
    const bool valid = x.error.empty();
    const std::vector<uint8_t> wire = valid ? Encode(x.msg) : x.wire;
    std::string text = "# " + x.name + ": " + x.comment + "\n";
    text +=
        "# The bytes on the wire, COBS-stuffed, ending with the 0x00 delimiter (hex, "
        "whitespace-separated).\n";
    if (valid) {
      text += "# Unstuffed frame: version type seq(le) payload crc32(le):\n";
      std::string raw = Hex(Raw(x.msg));
      for (size_t at = 0; at < raw.size();) {
        const size_t end = raw.find('\n', at);
        text += "#   " + raw.substr(at, end - at + 1);
        at = end + 1;
      }
    }
    text += Hex(wire);
    const std::string path = dir + "/" + x.name + ".hex";
    FILE* f = std::fopen(path.c_str(), "w");
    if (f == nullptr) {
      std::perror(path.c_str());
      return 1;
    }
    std::fputs(text.c_str(), f);
    std::fclose(f);
    char head[256];
    std::snprintf(head, sizeof(head),
                  "  {\"file\": \"%s.hex\", \"type\": \"%s\", \"type_code\": %u, \"seq\": %u, ",
                  x.name.c_str(), proto_type_name(x.msg.type), x.msg.type, x.msg.seq);
    json += head;
    json += valid ? "\"error\": null,\n   \"fields\": " + x.fields_json
                  : "\"error\": \"" + x.error + "\", \"fields\": {}";
    json += i + 1 == v.size() ? "}\n" : "},\n";
  }
  json += "]\n";
  FILE* f = std::fopen((dir + "/vectors.json").c_str(), "w");
  if (f == nullptr) return 1;
  std::fputs(json.c_str(), f);
  std::fclose(f);
  return 0;
}

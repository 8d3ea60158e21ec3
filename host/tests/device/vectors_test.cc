// The protocol's golden frames (protocol/vectors/, see its README) decoded on the host side: each file with
// the codec as the host builds it, and the event and INFO frames through the device client into the host's
// own types, checked against vectors.json.
#include <cerrno>
#include <deque>
#include <fstream>
#include <map>
#include <sstream>
#include <string>
#include <vector>

#include <gtest/gtest.h>
#include <nlohmann/json.hpp>

#include "rotoscan/device/client.h"
#include "golden_vectors.h"
#include "rotoscan_protocol.h"

namespace rotoscan::device {
namespace {

using protocol_testing::ReadHexVector;

nlohmann::json Manifest() { return protocol_testing::ReadVectorManifest(); }

const nlohmann::json& Entry(const nlohmann::json& manifest, const std::string& prefix) {
  for (const auto& e : manifest) {
    if (e["file"].get<std::string>().rfind(prefix, 0) == 0) return e;
  }
  throw std::runtime_error("no vector " + prefix);
}

// Answers the first bytes it receives with INFO (02_info), then sends whatever the test queues.
class ReplayBoard : public VirtualBoard {
 public:
  void Receive(const uint8_t*, size_t) override {
    if (!answered_) {
      answered_ = true;
      Queue(ReadHexVector("02_info.hex"));
    }
  }
  size_t Transmit(uint8_t* out, size_t max) override {
    size_t n = 0;
    while (n < max && !tx_.empty()) {
      out[n++] = tx_.front();
      tx_.pop_front();
    }
    return n;
  }
  void Advance(int64_t) override {}
  void Queue(const std::vector<uint8_t>& bytes) { tx_.insert(tx_.end(), bytes.begin(), bytes.end()); }

 private:
  bool answered_ = false;
  std::deque<uint8_t> tx_;
};

TEST(VectorsTest, EveryFrameDecodesAsTheManifestSays) {
  const nlohmann::json manifest = Manifest();
  ASSERT_GE(manifest.size(), 20u);
  const std::map<std::string, int> errors = {
      {"EBADMSG", -EBADMSG}, {"EPROTO", -EPROTO}, {"ENOMSG", -ENOMSG}, {"EMSGSIZE", -EMSGSIZE}};
  for (const auto& e : manifest) {
    const std::string file = e["file"];
    std::vector<uint8_t> wire = ReadHexVector(file);
    ASSERT_FALSE(wire.empty()) << file;
    EXPECT_EQ(wire.back(), 0) << file << ": a frame ends with its delimiter";
    proto_msg_t msg;
    const int result = proto_decode_frame(wire.data(), wire.size(), &msg);
    if (e["error"].is_null()) {
      ASSERT_EQ(result, 0) << file;
      EXPECT_EQ(msg.type, e["type_code"].get<int>()) << file;
      EXPECT_EQ(msg.seq, e["seq"].get<int>()) << file;
      // Encoding the decoded message again gives the same bytes.
      std::vector<uint8_t> again(PROTO_MAX_WIRE_FRAME);
      const int n = proto_encode_frame(&msg, again.data(), again.size());
      ASSERT_GT(n, 0) << file;
      again.resize(static_cast<size_t>(n));
      EXPECT_EQ(again, wire) << file;
    } else {
      EXPECT_EQ(result, errors.at(e["error"].get<std::string>())) << file;
    }
  }
}

TEST(VectorsTest, InfoThroughTheClient) {
  const nlohmann::json f = Entry(Manifest(), "02_info")["fields"];
  ReplayBoard board;
  auto client = Client::Connect(MakeInProcessTransport(&board));
  ASSERT_TRUE(client.ok()) << client.status().ToString();
  const DeviceInfo& info = (*client)->info();
  EXPECT_EQ(info.protocol_major, f["proto_major"].get<int>());
  EXPECT_EQ(info.protocol_minor, f["proto_minor"].get<int>());
  EXPECT_EQ(info.capabilities, f["capabilities"].get<uint32_t>());
  EXPECT_TRUE(info.simulated);
  EXPECT_EQ(info.firmware_version, std::to_string(f["fw_major"].get<int>()) + "." +
                                       std::to_string(f["fw_minor"].get<int>()) + "." +
                                       std::to_string(f["fw_patch"].get<int>()));
  EXPECT_EQ(info.max_payload, f["max_payload"].get<int>());
  EXPECT_EQ(info.max_shots, f["max_shots"].get<int>());
  std::string uid;
  for (int byte : f["uid"]) {
    char hex[3];
    std::snprintf(hex, sizeof(hex), "%02x", byte);
    uid += hex;
  }
  EXPECT_EQ(info.uid, uid);
}

TEST(VectorsTest, EventsThroughTheClientAndBadFramesDropped) {
  const nlohmann::json manifest = Manifest();
  ReplayBoard board;
  auto client = Client::Connect(MakeInProcessTransport(&board));
  ASSERT_TRUE(client.ok()) << client.status().ToString();
  int bad = 0;
  for (const auto& e : manifest) {
    board.Queue(ReadHexVector(e["file"]));
    if (!e["error"].is_null()) ++bad;
  }
  std::vector<Event> events;
  while (true) {
    auto event = (*client)->NextEvent(1000);
    ASSERT_TRUE(event.ok());
    if (!event->has_value()) break;
    events.push_back(**event);
  }
  EXPECT_EQ((*client)->stats().frames_dropped, bad);
  const nlohmann::json t = Entry(manifest, "16_trigger")["fields"];
  const nlohmann::json m = Entry(manifest, "17_move_done")["fields"];
  const nlohmann::json l = Entry(manifest, "19_log")["fields"];
  int triggers = 0, moves = 0, logs = 0;
  for (const Event& event : events) {
    if (const auto* e = std::get_if<TriggerEvent>(&event)) {
      ++triggers;
      EXPECT_EQ(e->trigger_seq, t["trigger_seq"].get<uint32_t>());
      EXPECT_EQ(e->time_us, t["time_us"].get<uint64_t>());
      ASSERT_TRUE(e->exposure_seen_us.has_value());  // flags bit 1
      EXPECT_EQ(*e->exposure_seen_us, t["exposure_seen_us"].get<uint64_t>());
      EXPECT_EQ(e->position, t["position"].get<int32_t>());
      ASSERT_TRUE(e->step_index.has_value());  // flags bit 0
      EXPECT_EQ(*e->step_index, t["step_index"].get<uint32_t>());
      EXPECT_EQ(e->laser_mask, t["laser_mask"].get<int>());
      EXPECT_EQ(e->shot, t["shot"].get<int>());
    } else if (const auto* d = std::get_if<MoveDoneEvent>(&event)) {
      ++moves;
      EXPECT_EQ(d->move_seq, m["move_seq"].get<uint32_t>());
      EXPECT_EQ(d->time_us, m["time_us"].get<uint64_t>());
      EXPECT_EQ(d->position, m["position"].get<int32_t>());
      EXPECT_EQ(d->aborted, (m["status"].get<int>() & PROTO_MOVE_ABORTED) != 0);
    } else if (const auto* g = std::get_if<LogEvent>(&event)) {
      ++logs;
      EXPECT_EQ(g->level, l["level"].get<int>());
      EXPECT_EQ(g->text, l["text"].get<std::string>());
    }
  }
  EXPECT_EQ(triggers, 1);
  EXPECT_EQ(moves, 1);
  EXPECT_EQ(logs, 1);
}

// A protocol 1.1 board made of the golden frames: INFO (02_info with the diag capability and minor 1) and
// DIAG (22_diag), each re-sent with the seq of the command it answers.
class DiagReplayBoard : public VirtualBoard {
 public:
  void Receive(const uint8_t* data, size_t size) override {
    for (size_t i = 0; i < size; ++i) {
      if (data[i] != 0) {
        rx_.push_back(data[i]);
        continue;
      }
      proto_msg_t cmd;
      if (proto_decode_frame(rx_.data(), rx_.size(), &cmd) == 0) Answer(cmd);
      rx_.clear();
    }
  }
  size_t Transmit(uint8_t* out, size_t max) override {
    size_t n = 0;
    while (n < max && !tx_.empty()) {
      out[n++] = tx_.front();
      tx_.pop_front();
    }
    return n;
  }
  void Advance(int64_t) override {}

 private:
  void Answer(const proto_msg_t& cmd) {
    proto_msg_t reply;
    const char* file = cmd.type == PROTO_GET_INFO   ? "02_info.hex"
                       : cmd.type == PROTO_GET_DIAG ? "22_diag.hex"
                                                    : nullptr;
    if (file == nullptr) return;
    const std::vector<uint8_t> wire = ReadHexVector(file);
    ASSERT_EQ(proto_decode_frame(wire.data(), wire.size(), &reply), 0);
    if (reply.type == PROTO_INFO) {
      reply.body.info.proto_minor = 1;
      reply.body.info.capabilities |= PROTO_CAP_DIAG;
    }
    reply.seq = cmd.seq;
    uint8_t out[PROTO_MAX_WIRE_FRAME];
    const int n = proto_encode_frame(&reply, out, sizeof(out));
    ASSERT_GT(n, 0);
    tx_.insert(tx_.end(), out, out + n);
  }
  std::vector<uint8_t> rx_;
  std::deque<uint8_t> tx_;
};

TEST(VectorsTest, DiagThroughTheClient) {
  const nlohmann::json f = Entry(Manifest(), "22_diag")["fields"];
  DiagReplayBoard board;
  auto client = Client::Connect(MakeInProcessTransport(&board));
  ASSERT_TRUE(client.ok()) << client.status().ToString();
  auto diag = (*client)->GetDiag();
  ASSERT_TRUE(diag.ok()) << diag.status().ToString();
  ASSERT_TRUE(diag->cpu_hz.has_value());  // flags bit 0
  EXPECT_EQ(*diag->cpu_hz, f["cpu_hz"].get<uint32_t>());
  EXPECT_EQ(*diag->step_isr_cycles_max, f["step_isr_cycles_max"].get<uint32_t>());
  EXPECT_EQ(*diag->step_isr_cycles_last, f["step_isr_cycles_last"].get<uint32_t>());
  ASSERT_TRUE(diag->fault.has_value());  // flags bit 1
  EXPECT_EQ(diag->fault->count, f["fault_count"].get<uint32_t>());
  EXPECT_EQ(diag->fault->vector, f["fault_vector"].get<uint32_t>());
  EXPECT_EQ(diag->fault->pc, f["fault_pc"].get<uint32_t>());
  EXPECT_EQ(diag->fault->lr, f["fault_lr"].get<uint32_t>());
  EXPECT_EQ(diag->fault->psr, f["fault_psr"].get<uint32_t>());
  EXPECT_EQ(diag->fault->cfsr, f["fault_cfsr"].get<uint32_t>());
  EXPECT_EQ(diag->fault->hfsr, f["fault_hfsr"].get<uint32_t>());
}

TEST(VectorsTest, DiagFromAProtocol10BoardIsRefusedWithoutAsking) {
  ReplayBoard board;  // 02_info: protocol 1.0, no diag capability
  auto client = Client::Connect(MakeInProcessTransport(&board));
  ASSERT_TRUE(client.ok()) << client.status().ToString();
  auto diag = (*client)->GetDiag();
  ASSERT_FALSE(diag.ok());
  EXPECT_EQ(diag.status().code(), StatusCode::kFailedPrecondition);
  EXPECT_NE(diag.status().message().find("protocol 1.0"), std::string::npos) << diag.status().ToString();
}

}  // namespace
}  // namespace rotoscan::device

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

}  // namespace
}  // namespace rotoscan::device

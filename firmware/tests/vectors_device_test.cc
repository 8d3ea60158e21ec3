// The golden frames of protocol/vectors/ sent to the firmware on the simulated board: every command gets
// its answer, naming its seq; every device-to-host frame and every invalid frame gets a NACK.
#include <gtest/gtest.h>

#include <fstream>
#include <nlohmann/json.hpp>
#include <sstream>
#include <string>
#include <vector>

#include "golden_vectors.h"
#include "rotoscan_protocol.h"
#include "sim_device.h"

namespace rotoscan::firmware_test {
namespace {

using protocol_testing::ReadHexVector;

uint8_t DataReplyOf(uint8_t command) {
  switch (command) {
    case PROTO_GET_INFO: return PROTO_INFO;
    case PROTO_PING: return PROTO_PONG;
    case PROTO_GET_STATUS: return PROTO_STATUS;
    case PROTO_GET_DIAG: return PROTO_DIAG;
    default: return 0;
  }
}

TEST(FirmwareVectors, TheDeviceAnswersEveryGoldenFrame) {
  const nlohmann::json manifest = protocol_testing::ReadVectorManifest();
  int checked = 0;
  for (const nlohmann::json& v : manifest) {
    const std::string file = v.at("file");
    SCOPED_TRACE(file);
    SimDevice dev;
    dev.SendBytes(ReadHexVector(file));
    dev.Drain();
    ASSERT_EQ(dev.answers().size(), 1u);
    const proto_msg_t& a = dev.answers()[0];
    const uint8_t type = static_cast<uint8_t>(v.at("type_code").get<int>());
    const uint16_t seq = static_cast<uint16_t>(v.at("seq").get<int>());
    ++checked;
    if (!v.at("error").is_null()) {
      EXPECT_EQ(a.type, PROTO_NACK);
      const std::string error = v.at("error");
      if (error == "EBADMSG") {
        EXPECT_TRUE(a.body.ack.status == PROTO_ST_BAD_CRC || a.body.ack.status == PROTO_ST_BAD_FRAME);
      } else {
        EXPECT_EQ(a.body.ack.status, proto_status_from_error(error == "EPROTO"   ? -EPROTO
                                                             : error == "ENOMSG" ? -ENOMSG
                                                                                 : -EMSGSIZE));
        EXPECT_EQ(a.body.ack.acked_seq, seq);
      }
      continue;
    }
    EXPECT_EQ(a.seq, seq);
    if (!proto_is_command(type)) {
      EXPECT_EQ(a.type, PROTO_NACK);
      EXPECT_EQ(a.body.ack.status, PROTO_ST_UNKNOWN_TYPE);
    } else if (DataReplyOf(type) != 0) {
      EXPECT_EQ(a.type, DataReplyOf(type));
    } else {
      EXPECT_TRUE(a.type == PROTO_ACK || a.type == PROTO_NACK);
      EXPECT_EQ(a.body.ack.acked_type, type);
      EXPECT_EQ(a.body.ack.acked_seq, seq);
    }
  }
  EXPECT_EQ(checked, 27);
}

}  // namespace
}  // namespace rotoscan::firmware_test

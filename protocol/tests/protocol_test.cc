// The wire protocol: CRC-32, COBS, the message codec and the stream deframer.
#include <gtest/gtest.h>

#include <cstring>
#include <random>
#include <vector>

#include "rotoscan_protocol.h"

namespace {

std::vector<uint8_t> CobsEncode(const std::vector<uint8_t>& in) {
  std::vector<uint8_t> out(PROTO_COBS_MAX_ENCODED(in.size()));
  const int n = proto_cobs_encode(in.data(), in.size(), out.data(), out.size());
  EXPECT_GT(n, 0);
  out.resize(static_cast<size_t>(n < 0 ? 0 : n));
  return out;
}

int CobsDecode(const std::vector<uint8_t>& in, std::vector<uint8_t>* out) {
  out->assign(in.size() + 1, 0xAA);
  const int n = proto_cobs_decode(in.data(), in.size(), out->data(), out->size());
  if (n >= 0) out->resize(static_cast<size_t>(n));
  return n;
}

// Bit-at-a-time CRC-32 straight from the definition, to check the table-driven one.
uint32_t ReferenceCrc32(const uint8_t* p, size_t n) {
  uint32_t crc = 0xFFFFFFFFu;
  for (size_t i = 0; i < n; ++i) {
    crc ^= p[i];
    for (int b = 0; b < 8; ++b) crc = (crc >> 1) ^ (0xEDB88320u & (0u - (crc & 1u)));
  }
  return ~crc;
}

TEST(ProtocolCrc32, MatchesZlib) {
  const char* check = "123456789";
  EXPECT_EQ(proto_crc32(0, reinterpret_cast<const uint8_t*>(check), 9), 0xCBF43926u);
  EXPECT_EQ(proto_crc32(0, nullptr, 0), 0u);
  std::mt19937 rng(6);
  std::vector<uint8_t> data(1000);
  for (uint8_t& b : data) b = static_cast<uint8_t>(rng());
  for (size_t n : {1u, 7u, 64u, 1000u})
    EXPECT_EQ(proto_crc32(0, data.data(), n), ReferenceCrc32(data.data(), n));
  // Chaining: crc(a + b) = crc(crc(a), b), as zlib's crc32().
  EXPECT_EQ(proto_crc32(proto_crc32(0, data.data(), 300), data.data() + 300, 700),
            proto_crc32(0, data.data(), 1000));
}

TEST(ProtocolCobs, EncodesTheStandardExamples) {
  // Examples from Cheshire & Baker's paper and the usual COBS references (delimiter not included).
  EXPECT_EQ(CobsEncode({}), (std::vector<uint8_t>{0x01}));
  EXPECT_EQ(CobsEncode({0x00}), (std::vector<uint8_t>{0x01, 0x01}));
  EXPECT_EQ(CobsEncode({0x00, 0x00}), (std::vector<uint8_t>{0x01, 0x01, 0x01}));
  EXPECT_EQ(CobsEncode({0x11, 0x22, 0x00, 0x33}), (std::vector<uint8_t>{0x03, 0x11, 0x22, 0x02, 0x33}));
  EXPECT_EQ(CobsEncode({0x11, 0x22, 0x33, 0x44}), (std::vector<uint8_t>{0x05, 0x11, 0x22, 0x33, 0x44}));
  EXPECT_EQ(CobsEncode({0x11, 0x00, 0x00, 0x00}), (std::vector<uint8_t>{0x02, 0x11, 0x01, 0x01, 0x01}));
  std::vector<uint8_t> run(254);
  for (int i = 0; i < 254; ++i) run[i] = static_cast<uint8_t>(i + 1);
  std::vector<uint8_t> expected = {0xFF};
  expected.insert(expected.end(), run.begin(), run.end());
  EXPECT_EQ(CobsEncode(run), expected);  // 01..FE: one full block, no trailing code
  std::vector<uint8_t> run0 = {0x00};
  run0.insert(run0.end(), run.begin(), run.end());
  expected.insert(expected.begin(), 0x01);
  EXPECT_EQ(CobsEncode(run0), expected);  // 00 01..FE
  std::vector<uint8_t> run2 = run;
  run2.push_back(0xFF);
  std::vector<uint8_t> expected2 = {0xFF};
  expected2.insert(expected2.end(), run.begin(), run.end());
  expected2.insert(expected2.end(), {0x02, 0xFF});
  EXPECT_EQ(CobsEncode(run2), expected2);  // 01..FE FF: a second block
}

TEST(ProtocolCobs, RoundTripsRandomDataWithoutZerosOnTheWire) {
  std::mt19937 rng(1999);
  for (int trial = 0; trial < 500; ++trial) {
    std::vector<uint8_t> data(rng() % 700);
    const int zero_odds = 1 + trial % 10;
    for (uint8_t& b : data) b = (rng() % zero_odds == 0) ? 0 : static_cast<uint8_t>(1 + rng() % 255);
    const std::vector<uint8_t> enc = CobsEncode(data);
    ASSERT_LE(enc.size(), PROTO_COBS_MAX_ENCODED(data.size()));
    for (uint8_t b : enc) ASSERT_NE(b, 0);
    std::vector<uint8_t> dec;
    ASSERT_EQ(CobsDecode(enc, &dec), static_cast<int>(data.size()));
    ASSERT_EQ(dec, data);
    // In place.
    std::vector<uint8_t> buf = enc;
    ASSERT_EQ(proto_cobs_decode(buf.data(), buf.size(), buf.data(), buf.size()),
              static_cast<int>(data.size()));
    ASSERT_TRUE(std::equal(data.begin(), data.end(), buf.begin()));
  }
}

TEST(ProtocolCobs, RefusesMalformedInputAndSmallBuffers) {
  std::vector<uint8_t> out;
  EXPECT_EQ(CobsDecode({0x05, 0x11, 0x22}, &out), -EBADMSG);  // code past the end
  EXPECT_EQ(CobsDecode({0x03, 0x11, 0x00}, &out), -EBADMSG);  // a zero inside
  EXPECT_EQ(CobsDecode({0x00}, &out), -EBADMSG);              // a zero code
  uint8_t small[2];
  const uint8_t in[] = {0x05, 0x11, 0x22, 0x33, 0x44};
  EXPECT_EQ(proto_cobs_decode(in, sizeof(in), small, sizeof(small)), -ENOSPC);
  EXPECT_EQ(proto_cobs_encode(in, sizeof(in), small, sizeof(small)), -ENOSPC);
  EXPECT_EQ(proto_cobs_encode(nullptr, 3, small, sizeof(small)), -EINVAL);
  EXPECT_EQ(proto_cobs_decode(in, sizeof(in), nullptr, 10), -EINVAL);
}

// A message of every type with random field values.
proto_msg_t RandomMessage(uint8_t type, std::mt19937_64& rng) {
  proto_msg_t m;
  proto_msg_init(&m, type, static_cast<uint16_t>(rng()));
  // Fill the whole body with random bytes, then fix the counts the wire format bounds.
  std::vector<uint8_t> noise(sizeof(m.body));
  for (uint8_t& b : noise) b = static_cast<uint8_t>(rng());
  std::memcpy(&m.body, noise.data(), noise.size());
  if (type == PROTO_LOAD_PROGRAM)
    m.body.program.shot_count = static_cast<uint8_t>(1 + rng() % PROTO_MAX_SHOTS);
  if (type == PROTO_LOG) {
    m.body.log.length = static_cast<uint8_t>(rng() % (PROTO_MAX_LOG_TEXT + 1));
    for (int i = 0; i < m.body.log.length; ++i) m.body.log.text[i] = static_cast<char>(' ' + rng() % 90);
    m.body.log.text[m.body.log.length] = '\0';
  }
  return m;
}

const uint8_t kAllTypes[] = {PROTO_GET_INFO,  PROTO_PING,       PROTO_SET_CONFIG, PROTO_MOTOR_ENABLE,
                             PROTO_MOVE,      PROTO_SET_LASERS, PROTO_TRIGGER,    PROTO_LOAD_PROGRAM,
                             PROTO_START,     PROTO_ABORT,      PROTO_GET_STATUS, PROTO_ACK,
                             PROTO_NACK,      PROTO_INFO,       PROTO_PONG,       PROTO_TRIGGER_EVENT,
                             PROTO_MOVE_DONE, PROTO_STATUS,     PROTO_LOG};

// Encodes, decodes, re-encodes: the bytes must agree (the struct may differ in unused padding and in the
// parts of the body another type uses).
TEST(ProtocolCodec, EveryTypeRoundTrips) {
  std::mt19937_64 rng(42);
  for (uint8_t type : kAllTypes) {
    for (int trial = 0; trial < 50; ++trial) {
      SCOPED_TRACE(proto_type_name(type));
      const proto_msg_t m = RandomMessage(type, rng);
      uint8_t wire[PROTO_MAX_WIRE_FRAME];
      const int n = proto_encode_frame(&m, wire, sizeof(wire));
      ASSERT_GT(n, 0);
      ASSERT_EQ(wire[n - 1], 0);
      for (int i = 0; i < n - 1; ++i) ASSERT_NE(wire[i], 0);
      proto_msg_t d;
      ASSERT_EQ(proto_decode_frame(wire, static_cast<size_t>(n), &d), 0);
      EXPECT_EQ(d.type, type);
      EXPECT_EQ(d.seq, m.seq);
      EXPECT_EQ(d.version, PROTO_VERSION_MAJOR);
      uint8_t again[PROTO_MAX_WIRE_FRAME];
      ASSERT_EQ(proto_encode_frame(&d, again, sizeof(again)), n);
      ASSERT_EQ(std::memcmp(wire, again, static_cast<size_t>(n)), 0);
      EXPECT_EQ(proto_pack(&m, again, sizeof(again)),
                proto_payload_size(&m) + PROTO_HEADER_SIZE + PROTO_CRC_SIZE);
    }
  }
}

TEST(ProtocolCodec, FieldsKeepTheirValuesAndSigns) {
  proto_msg_t m;
  proto_msg_init(&m, PROTO_TRIGGER_EVENT, 0xBEEF);
  m.body.trigger_event = {0xFFFFFFFFu, 0xFEDCBA9876543210ull, 1, INT32_MIN, 7, 3, 2, 1};
  uint8_t raw[PROTO_MAX_RAW_FRAME];
  const int n = proto_pack(&m, raw, sizeof(raw));
  ASSERT_EQ(n, PROTO_HEADER_SIZE + PROTO_TRIGGER_EVENT_SIZE + PROTO_CRC_SIZE);
  EXPECT_EQ(raw[2], 0xEF);  // seq, little endian
  EXPECT_EQ(raw[3], 0xBE);
  EXPECT_EQ(raw[4 + 4], 0x10);  // time_us low byte first
  EXPECT_EQ(raw[4 + 11], 0xFE);
  proto_msg_t d;
  ASSERT_EQ(proto_unpack(raw, static_cast<size_t>(n), &d), 0);
  EXPECT_EQ(d.body.trigger_event.trigger_seq, 0xFFFFFFFFu);
  EXPECT_EQ(d.body.trigger_event.time_us, 0xFEDCBA9876543210ull);
  EXPECT_EQ(d.body.trigger_event.position, INT32_MIN);
  proto_msg_init(&m, PROTO_MOVE, 1);
  for (int32_t steps : {-1, 1, INT32_MAX, INT32_MIN, -1600}) {
    m.body.move.steps = steps;
    ASSERT_GT(proto_pack(&m, raw, sizeof(raw)), 0);
    ASSERT_EQ(proto_unpack(raw, PROTO_HEADER_SIZE + PROTO_MOVE_SIZE + PROTO_CRC_SIZE, &d), 0);
    EXPECT_EQ(d.body.move.steps, steps);
  }
}

std::vector<uint8_t> RawWithCrc(std::vector<uint8_t> raw) {
  const uint32_t crc = proto_crc32(0, raw.data(), raw.size());
  for (int i = 0; i < 4; ++i) raw.push_back(static_cast<uint8_t>(crc >> (8 * i)));
  return raw;
}

TEST(ProtocolCodec, UnpackRefusesBadFramesAndKeepsTheHeader) {
  proto_msg_t d;
  const std::vector<uint8_t> short_frame = {1, 2, 3};
  EXPECT_EQ(proto_unpack(short_frame.data(), short_frame.size(), &d), -EBADMSG);
  EXPECT_EQ(d.type, 0);
  std::vector<uint8_t> ping = RawWithCrc({1, PROTO_PING, 9, 0, 1, 2, 3, 4, 5, 6, 7, 8});
  ping[5] ^= 1;
  EXPECT_EQ(proto_unpack(ping.data(), ping.size(), &d), -EBADMSG);
  EXPECT_EQ(d.seq, 9);  // a NACK can still name it
  std::vector<uint8_t> v2 = RawWithCrc({2, PROTO_PING, 9, 0, 1, 2, 3, 4, 5, 6, 7, 8});
  EXPECT_EQ(proto_unpack(v2.data(), v2.size(), &d), -EPROTO);
  std::vector<uint8_t> info_v2 = RawWithCrc({2, PROTO_GET_INFO, 9, 0, 0xAA});  // frozen, may grow
  EXPECT_EQ(proto_unpack(info_v2.data(), info_v2.size(), &d), 0);
  std::vector<uint8_t> unknown = RawWithCrc({1, 0x7F, 1, 0});
  EXPECT_EQ(proto_unpack(unknown.data(), unknown.size(), &d), -ENOMSG);
  EXPECT_EQ(d.type, 0x7F);
  std::vector<uint8_t> long_abort = RawWithCrc({1, PROTO_ABORT, 1, 0, 0});
  EXPECT_EQ(proto_unpack(long_abort.data(), long_abort.size(), &d), -EMSGSIZE);
  // A program whose shot count disagrees with its length, or exceeds the maximum.
  std::vector<uint8_t> prog = {1, PROTO_LOAD_PROGRAM, 1, 0};
  for (int i = 0; i < 16; ++i) prog.push_back(1);
  prog.push_back(2);  // two shots announced, one given
  for (int i = 0; i < 5; ++i) prog.push_back(1);
  std::vector<uint8_t> p1 = RawWithCrc(prog);
  EXPECT_EQ(proto_unpack(p1.data(), p1.size(), &d), -EMSGSIZE);
  prog[4 + 16] = 9;
  std::vector<uint8_t> p9 = RawWithCrc(prog);
  EXPECT_EQ(proto_unpack(p9.data(), p9.size(), &d), -EMSGSIZE);
  std::vector<uint8_t> log = RawWithCrc({1, PROTO_LOG, 1, 0, 0, 0, 0, 0, 1, 65, 'x'});
  EXPECT_EQ(proto_unpack(log.data(), log.size(), &d), -EMSGSIZE);
  EXPECT_EQ(proto_status_from_error(-EMSGSIZE), PROTO_ST_BAD_LENGTH);
  EXPECT_EQ(proto_status_from_error(-EPROTO), PROTO_ST_VERSION);
}

TEST(ProtocolCodec, PackRefusesCountsOutOfRangeAndSmallBuffers) {
  proto_msg_t m;
  proto_msg_init(&m, PROTO_LOAD_PROGRAM, 1);
  uint8_t raw[PROTO_MAX_RAW_FRAME];
  m.body.program.shot_count = 0;
  EXPECT_EQ(proto_pack(&m, raw, sizeof(raw)), -EINVAL);
  m.body.program.shot_count = PROTO_MAX_SHOTS + 1;
  EXPECT_EQ(proto_pack(&m, raw, sizeof(raw)), -EINVAL);
  m.body.program.shot_count = 1;
  EXPECT_EQ(proto_pack(&m, raw, 10), -ENOSPC);
  proto_msg_init(&m, 0x55, 1);
  EXPECT_EQ(proto_pack(&m, raw, sizeof(raw)), -ENOMSG);
  EXPECT_EQ(proto_pack(nullptr, raw, sizeof(raw)), -EINVAL);
  uint8_t wire[8];
  proto_msg_init(&m, PROTO_PING, 1);
  EXPECT_EQ(proto_encode_frame(&m, wire, sizeof(wire)), -ENOSPC);
}

TEST(ProtocolDeframer, SplitsAStreamIntoFramesWhateverTheChunks) {
  std::mt19937_64 rng(7);
  std::vector<uint8_t> stream = {0x00};  // a leading delimiter resynchronises
  std::vector<proto_msg_t> sent;
  for (int i = 0; i < 100; ++i) {
    const proto_msg_t m = RandomMessage(kAllTypes[i % 19], rng);
    uint8_t wire[PROTO_MAX_WIRE_FRAME];
    const int n = proto_encode_frame(&m, wire, sizeof(wire));
    ASSERT_GT(n, 0);
    stream.insert(stream.end(), wire, wire + n);
    sent.push_back(m);
  }
  proto_deframer_t d;
  proto_deframer_init(&d);
  size_t got = 0;
  for (uint8_t b : stream) {
    size_t len = 0;
    const int r = proto_deframer_push(&d, b, &len);
    ASSERT_GE(r, 0);
    if (r == 1) {
      proto_msg_t m;
      ASSERT_EQ(proto_decode_frame(d.buf, len, &m), 0);
      ASSERT_LT(got, sent.size());
      EXPECT_EQ(m.type, sent[got].type);
      EXPECT_EQ(m.seq, sent[got].seq);
      ++got;
    }
  }
  EXPECT_EQ(got, sent.size());
}

TEST(ProtocolDeframer, DropsAnOverlongFrameAndRecovers) {
  proto_deframer_t d;
  proto_deframer_init(&d);
  size_t len = 0;
  for (int i = 0; i < 1000; ++i) ASSERT_EQ(proto_deframer_push(&d, 0x42, &len), 0);
  EXPECT_EQ(proto_deframer_push(&d, 0x00, &len), -EMSGSIZE);
  proto_msg_t m;
  proto_msg_init(&m, PROTO_ABORT, 3);
  uint8_t wire[PROTO_MAX_WIRE_FRAME];
  const int n = proto_encode_frame(&m, wire, sizeof(wire));
  int result = 0;
  for (int i = 0; i < n; ++i) result = proto_deframer_push(&d, wire[i], &len);
  ASSERT_EQ(result, 1);
  proto_msg_t out;
  ASSERT_EQ(proto_decode_frame(d.buf, len, &out), 0);
  EXPECT_EQ(out.type, PROTO_ABORT);
}

TEST(ProtocolNames, EveryTypeAndStatusHasAName) {
  for (uint8_t type : kAllTypes) EXPECT_STRNE(proto_type_name(type), "UNKNOWN");
  EXPECT_STREQ(proto_type_name(0x99), "UNKNOWN");
  for (uint8_t s = 0; s <= PROTO_ST_INTERNAL; ++s) EXPECT_STRNE(proto_status_name(s), "unknown");
  EXPECT_TRUE(proto_is_command(PROTO_GET_STATUS));
  EXPECT_FALSE(proto_is_command(PROTO_ACK));
}

}  // namespace

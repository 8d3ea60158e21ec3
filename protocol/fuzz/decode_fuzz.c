/*
 * libFuzzer target for the protocol decoder: the input is a byte stream as it could arrive on the wire. It
 * goes through the deframer; every frame is decoded; a frame that decodes must encode back to a frame that
 * decodes to the same message (so the decoder never accepts what the encoder would write differently).
 * Also the raw COBS decoder and proto_unpack on the input as it is. Built and run by the CTest test
 * protocol.fuzz_decoder when clang is available (protocol/fuzz/run_fuzz.cmake).
 */
#include <stdint.h>
#include <stdlib.h>
#include <string.h>

#include "rotoscan_protocol.h"

int LLVMFuzzerTestOneInput(const uint8_t* data, size_t size);

static void check_round_trip(const proto_msg_t* m) {
  uint8_t wire[PROTO_MAX_WIRE_FRAME];
  const int n = proto_encode_frame(m, wire, sizeof(wire));
  if (n <= 0) abort(); /* a decoded message is always encodable */
  proto_msg_t again;
  if (proto_decode_frame(wire, (size_t)n, &again) != 0) abort();
  uint8_t wire2[PROTO_MAX_WIRE_FRAME];
  const int n2 = proto_encode_frame(&again, wire2, sizeof(wire2));
  if (n2 != n || memcmp(wire, wire2, (size_t)n) != 0) abort();
}

int LLVMFuzzerTestOneInput(const uint8_t* data, size_t size) {
  proto_deframer_t d;
  proto_deframer_init(&d);
  for (size_t i = 0; i < size; ++i) {
    size_t len = 0;
    if (proto_deframer_push(&d, data[i], &len) != 1) continue;
    proto_msg_t m;
    const int rc = proto_decode_frame(d.buf, len, &m);
    /* Frames of another major (GET_INFO/INFO only) decode but re-encode with ours: compare ours only. */
    if (rc == 0 && m.version == PROTO_VERSION_MAJOR) check_round_trip(&m);
  }
  proto_msg_t m;
  if (proto_unpack(data, size, &m) == 0 && m.version == PROTO_VERSION_MAJOR) check_round_trip(&m);
  uint8_t out[512];
  (void)proto_cobs_decode(data, size, out, sizeof(out));
  return 0;
}

/*
 * COBS (Consistent Overhead Byte Stuffing, Cheshire & Baker, IEEE/ACM ToN 1999). The input is cut into runs
 * that end at a 0x00 (or after 254 non-zero bytes); each run is written as a code byte (run length + 1)
 * followed by its non-zero bytes. A code of 0xFF means "254 bytes, no zero follows". The encoded data has no
 * 0x00, so a single 0x00 can delimit frames on the wire.
 */
#include "rotoscan_protocol.h"

int proto_cobs_encode(const uint8_t* in, size_t len, uint8_t* out, size_t out_cap) {
  if ((in == NULL && len > 0) || out == NULL) return -EINVAL;
  if (out_cap < PROTO_COBS_MAX_ENCODED(len) || PROTO_COBS_MAX_ENCODED(len) > (size_t)INT32_MAX) {
    return -ENOSPC;
  }
  size_t code_at = 0; /* where the current run's code byte goes */
  size_t o = 1;
  uint8_t code = 1;
  for (size_t i = 0; i < len; ++i) {
    if (in[i] == 0) {
      out[code_at] = code;
      code_at = o++;
      code = 1;
    } else {
      out[o++] = in[i];
      if (++code == 0xFF && i + 1 < len) { /* a full block; at the very end it needs no successor */
        out[code_at] = code;
        code_at = o++;
        code = 1;
      }
    }
  }
  out[code_at] = code;
  return (int)o;
}

int proto_cobs_decode(const uint8_t* in, size_t len, uint8_t* out, size_t out_cap) {
  if ((in == NULL && len > 0) || out == NULL) return -EINVAL;
  if (len > (size_t)INT32_MAX) return -ENOSPC;
  size_t i = 0;
  size_t o = 0;
  while (i < len) {
    const uint8_t code = in[i++];
    if (code == 0) return -EBADMSG;
    const size_t run = (size_t)code - 1u;
    if (run > len - i) return -EBADMSG; /* the code promises more bytes than there are */
    if (run > out_cap - o) return -ENOSPC;
    for (size_t k = 0; k < run; ++k) {
      const uint8_t b = in[i++];
      if (b == 0) return -EBADMSG;
      out[o++] = b; /* o < i always, so decoding in place is safe */
    }
    if (code != 0xFF && i < len) {
      if (o >= out_cap) return -ENOSPC;
      out[o++] = 0;
    }
  }
  return (int)o;
}

/*
 * rotoscan_protocol.h -- the Rotoscan wire protocol, shared byte for byte by the firmware and the host.
 *
 * C99, no dynamic memory, no I/O. Everything a frame holds is encoded and decoded field by field in little
 * endian; structs are never cast onto the wire.
 *
 * Frame on the wire (see protocol/vectors/README.md for worked examples, byte by byte):
 *
 *     COBS( version u8 | type u8 | seq u16 | payload (0..PROTO_MAX_PAYLOAD bytes) | crc32 u32 ) 0x00
 *
 *   version  PROTO_VERSION_MAJOR of the sender. A receiver refuses another major (-EPROTO), except for
 *            GET_INFO and INFO, whose layouts are frozen across majors so that a host can always learn the
 *            device's version and refuse it with a clear message.
 *   type     enum proto_type. Commands (host -> device) are 0x01..0x3F, replies 0x40..0x5F, events 0x60..
 *   seq      host -> device: the command's sequence number, chosen by the host, kept when retransmitting.
 *            Replies (ACK, NACK, INFO, PONG, STATUS with cause REPLY) carry the seq of the command they
 *            answer. Events carry the device's own frame counter (wraps at 2^16); each event payload also
 *            has its own 32-bit counter, so that a lost event is visible as a gap.
 *   crc32    the zlib/IEEE 802.3 CRC-32 (reflected polynomial 0xEDB88320, init and final xor 0xFFFFFFFF)
 *            of every byte before it: version, type, seq and payload.
 *   COBS     Consistent Overhead Byte Stuffing (Cheshire & Baker 1999): the stuffed frame has no 0x00 byte,
 *            and a single 0x00 ends it. A receiver resynchronises on the next 0x00 after any error.
 *
 * Acknowledgement rules: every command is answered exactly once, by ACK, NACK, or its data reply (INFO for
 * GET_INFO, PONG for PING, STATUS for GET_STATUS), which stands for the ACK. The host retransmits the same
 * frame (same seq) on timeout; a device that has already executed that seq (one of its last 4 commands, same
 * bytes) does not execute it again but sends the same answer again. So an answer, NACK included, is final
 * for its seq: to try a refused command again (e.g. after NACK BUSY), send it with a new seq.
 *
 * After power-on the device queues one STATUS event with cause BOOT; a host that sees it knows the device
 * was reset (its program, position and configuration are gone).
 *
 * Functions return 0 (or a length) on success and a negative errno value on failure:
 *   -EINVAL    a bad argument (null pointer, a field out of range when encoding)
 *   -ENOSPC    the output buffer is too small
 *   -EBADMSG   the frame is malformed: bad COBS, too short, or the CRC does not match
 *   -EPROTO    another major protocol version
 *   -ENOMSG    unknown message type
 *   -EMSGSIZE  the payload length does not match the message type
 * proto_status_from_error() maps them onto the wire status codes a NACK carries.
 */
#ifndef ROTOSCAN_PROTOCOL_H_
#define ROTOSCAN_PROTOCOL_H_

#include <errno.h>
#include <stdbool.h>
#include <stddef.h>
#include <stdint.h>

#ifdef __cplusplus
extern "C" {
#define PROTO_STATIC_ASSERT(expr, msg) static_assert(expr, msg)
#else
/* _Static_assert is C11; __extension__ keeps -std=c99 -Wpedantic quiet with gcc and clang. */
#define PROTO_STATIC_ASSERT(expr, msg) __extension__ _Static_assert(expr, msg)
#endif

/* ---- Version and limits ------------------------------------------------------------------------------ */

#define PROTO_VERSION_MAJOR 1 /* a change that an old peer would misread */
#define PROTO_VERSION_MINOR 1 /* additions an old peer can ignore (1.1: GET_DIAG / DIAG) */

#define PROTO_HEADER_SIZE 4 /* version, type, seq */
#define PROTO_CRC_SIZE 4
#define PROTO_MAX_PAYLOAD 128
#define PROTO_MAX_RAW_FRAME (PROTO_HEADER_SIZE + PROTO_MAX_PAYLOAD + PROTO_CRC_SIZE)
/* COBS adds one byte per 254 bytes (rounded up), plus one; then the 0x00 delimiter. */
#define PROTO_COBS_MAX_ENCODED(n) ((n) + ((n) / 254) + 1)
#define PROTO_MAX_WIRE_FRAME (PROTO_COBS_MAX_ENCODED(PROTO_MAX_RAW_FRAME) + 1)

#define PROTO_MAX_SHOTS 8 /* shots (exposures) per table step in a scan program */
#define PROTO_MAX_LOG_TEXT 64
#define PROTO_UID_SIZE 12

/* ---- Message types ----------------------------------------------------------------------------------- */

enum proto_type {
  /* Commands, host -> device. */
  PROTO_GET_INFO = 0x01,     /* -> INFO */
  PROTO_PING = 0x02,         /* -> PONG */
  PROTO_SET_CONFIG = 0x03,   /* -> ACK | NACK(BUSY, BAD_VALUE) */
  PROTO_MOTOR_ENABLE = 0x04, /* -> ACK | NACK(BUSY) */
  PROTO_MOVE = 0x05,         /* -> ACK | NACK; MOVE_DONE event when the move ends */
  PROTO_SET_LASERS = 0x06,   /* -> ACK | NACK(BUSY, BAD_VALUE) */
  PROTO_TRIGGER = 0x07,      /* -> ACK | NACK; one TRIGGER_EVENT after the exposure */
  PROTO_LOAD_PROGRAM = 0x08, /* -> ACK | NACK(BUSY, BAD_VALUE) */
  PROTO_START = 0x09,        /* -> ACK | NACK(NO_PROGRAM, BUSY, BAD_VALUE, MOTOR_DISABLED) */
  PROTO_ABORT = 0x0A,        /* -> ACK; STATUS event with cause ABORTED if something was stopped */
  PROTO_GET_STATUS = 0x0B,   /* -> STATUS with cause REPLY */
  PROTO_GET_DIAG = 0x0C,     /* -> DIAG (protocol 1.1, PROTO_CAP_DIAG); NACK UNKNOWN_TYPE from a 1.0 device */
  /* Replies, device -> host; seq = the command's seq. */
  PROTO_ACK = 0x40,
  PROTO_NACK = 0x41,
  PROTO_INFO = 0x42,
  PROTO_PONG = 0x43,
  PROTO_DIAG = 0x44,
  /* Events, device -> host; seq = the device's frame counter (STATUS with cause REPLY: the command's). */
  PROTO_TRIGGER_EVENT = 0x60,
  PROTO_MOVE_DONE = 0x61,
  PROTO_STATUS = 0x62,
  PROTO_LOG = 0x63
};

/* True for the types a host may send. */
bool proto_is_command(uint8_t type);
/* Short upper-case name ("TRIGGER_EVENT"), or "UNKNOWN". */
const char* proto_type_name(uint8_t type);

/* ---- Wire status codes (carried by NACK and STATUS) --------------------------------------------------- */

enum proto_status_code {
  PROTO_ST_OK = 0,
  PROTO_ST_BAD_FRAME = 1,      /* COBS error or frame too short */
  PROTO_ST_BAD_CRC = 2,        /* CRC mismatch: the seq in the NACK may itself be damaged */
  PROTO_ST_VERSION = 3,        /* another major version */
  PROTO_ST_UNKNOWN_TYPE = 4,   /* not a command this device knows */
  PROTO_ST_BAD_LENGTH = 5,     /* payload length wrong for the type */
  PROTO_ST_BAD_VALUE = 6,      /* a field out of range (the NACK's detail says which field, 1-based) */
  PROTO_ST_BUSY = 7,           /* a move or a program is running */
  PROTO_ST_NO_PROGRAM = 8,     /* START without a loaded program */
  PROTO_ST_MOTOR_DISABLED = 9, /* MOVE or START with the motor driver disabled */
  PROTO_ST_OVERFLOW = 10,      /* a receive buffer overflowed; the frame was dropped */
  PROTO_ST_INTERNAL = 11       /* a firmware invariant broke: a bug to report */
};

/* Wire status for a negative errno returned by the decoder (0 -> PROTO_ST_OK). */
uint8_t proto_status_from_error(int err);
/* Short lower-case name of a wire status code ("bad crc"), or "unknown". */
const char* proto_status_name(uint8_t status);

/* ---- Capability bits (INFO.capabilities) -------------------------------------------------------------- */

#define PROTO_CAP_STEPPER (1u << 0)      /* a stepper table: MOVE, MOTOR_ENABLE */
#define PROTO_CAP_LASERS (1u << 1)       /* SET_LASERS, laser masks in programs */
#define PROTO_CAP_TRIGGER_OUT (1u << 2)  /* hardware camera trigger with exact edge timestamps */
#define PROTO_CAP_EXPOSURE_IN (1u << 3)  /* the camera's exposure-active line is read (exposure-seen time) */
#define PROTO_CAP_PROGRAM (1u << 4)      /* LOAD_PROGRAM / START / ABORT */
#define PROTO_CAP_LASER_SAFETY (1u << 5) /* lasers go off when the host is silent (SET_CONFIG timeout) */
#define PROTO_CAP_DIAG (1u << 6)         /* GET_DIAG (protocol 1.1): interrupt cost and the last fault */
#define PROTO_CAP_SIMULATED (1u << 31)   /* the host-built firmware (port/sim), not a real board */

/* Laser mask bits. */
#define PROTO_LASER_LEFT (1u << 0)
#define PROTO_LASER_RIGHT (1u << 1)
#define PROTO_LASER_ALL (PROTO_LASER_LEFT | PROTO_LASER_RIGHT)

/* ---- Payloads ---------------------------------------------------------------------------------------- */
/* Each payload's wire size is the sum of its fields' sizes, in the order listed; the sizes are asserted. */

/* GET_INFO, ABORT, GET_STATUS, GET_DIAG: no payload. */

typedef struct {       /* INFO: frozen layout across majors (new fields only at the end) */
  uint8_t proto_major; /* PROTO_VERSION_MAJOR of the device */
  uint8_t proto_minor;
  uint32_t capabilities; /* PROTO_CAP_* */
  uint8_t fw_major;
  uint8_t fw_minor;
  uint8_t fw_patch;
  uint16_t max_payload;        /* largest payload the device accepts */
  uint8_t max_shots;           /* PROTO_MAX_SHOTS of the device */
  uint8_t uid[PROTO_UID_SIZE]; /* the MCU's unique id (serial number) */
} proto_info_t;
#define PROTO_INFO_SIZE (1 + 1 + 4 + 1 + 1 + 1 + 2 + 1 + PROTO_UID_SIZE)

typedef struct {         /* PING */
  uint64_t host_time_us; /* any host value, echoed in PONG */
} proto_ping_t;
#define PROTO_PING_SIZE 8

typedef struct {           /* PONG */
  uint64_t host_time_us;   /* echoed from PING */
  uint64_t device_time_us; /* device timebase (1 MHz, 64 bit, 0 at power-on) when PING was handled */
} proto_pong_t;
#define PROTO_PONG_SIZE (8 + 8)

typedef struct {             /* SET_CONFIG (only while idle) */
  uint32_t start_rate_hz;    /* steps/s at the start and end of a move, 1..max_rate_hz */
  uint32_t max_rate_hz;      /* cruise steps/s, start_rate_hz..100000 */
  uint32_t accel_hz_per_s;   /* steps/s^2, 1..10000000 */
  uint32_t trigger_pulse_us; /* camera trigger pulse width, 1..100000 */
  uint32_t laser_timeout_ms; /* lasers off and program aborted after this much host silence, 100..600000 */
  uint8_t flags;             /* PROTO_CONFIG_* */
} proto_config_t;
#define PROTO_CONFIG_SIZE (4 + 4 + 4 + 4 + 4 + 1)
#define PROTO_CONFIG_INVERT_DIR (1u << 0) /* swap the DIR pin level for positive steps */

typedef struct {  /* MOTOR_ENABLE */
  uint8_t enable; /* 0 or 1 */
} proto_motor_enable_t;
#define PROTO_MOTOR_ENABLE_SIZE 1

typedef struct { /* MOVE: relative, with the configured trapezoidal profile */
  int32_t steps; /* signed, |steps| <= PROTO_MAX_MOVE_STEPS; 0 is allowed (MOVE_DONE at once) */
} proto_move_t;
#define PROTO_MOVE_SIZE 4
#define PROTO_MAX_MOVE_STEPS 10000000

typedef struct { /* SET_LASERS */
  uint8_t mask;  /* PROTO_LASER_* */
} proto_set_lasers_t;
#define PROTO_SET_LASERS_SIZE 1

typedef struct {          /* TRIGGER: one exposure outside a program */
  uint8_t laser_mask;     /* lasers during the exposure (they return to the SET_LASERS state after) */
  uint32_t laser_lead_us; /* lasers switch this long before the trigger edge, 1..1000000 */
  uint32_t exposure_us;   /* the device waits this long after the edge before the next action, 1..10000000 */
} proto_trigger_t;
#define PROTO_TRIGGER_SIZE (1 + 4 + 4)

typedef struct {        /* one exposure of a table step */
  uint8_t laser_mask;   /* lasers on during this exposure */
  uint32_t exposure_us; /* wait after the trigger edge before the next shot, 1..10000000 */
} proto_shot_t;
#define PROTO_SHOT_SIZE (1 + 4)

/*
 * LOAD_PROGRAM: a scan program. Step i (0 <= i < step_count) is taken with the table at
 * origin + i * steps_per_move, where origin is the motor position when the program was loaded. Per step:
 * move there (trapezoidal profile), wait settle_us, then for each shot: lasers to the shot's mask
 * laser_lead_us before the trigger edge, trigger, wait exposure_us; lasers off after the last shot. One
 * TRIGGER_EVENT per shot, no host round trip. START(first_step) lets a host resume an interrupted scan with
 * no step taken twice or lost.
 */
typedef struct {
  uint32_t step_count;    /* 1..PROTO_MAX_PROGRAM_STEPS */
  int32_t steps_per_move; /* motor steps per table step, signed, |.| <= PROTO_MAX_MOVE_STEPS */
  uint32_t settle_us;     /* after each move, 0..10000000 */
  uint32_t laser_lead_us; /* 1..1000000 */
  uint8_t shot_count;     /* 1..PROTO_MAX_SHOTS; the payload holds exactly this many shots */
  proto_shot_t shots[PROTO_MAX_SHOTS];
} proto_program_t;
#define PROTO_PROGRAM_FIXED_SIZE (4 + 4 + 4 + 4 + 1)
#define PROTO_PROGRAM_SIZE(shots) (PROTO_PROGRAM_FIXED_SIZE + (shots)*PROTO_SHOT_SIZE)
#define PROTO_MAX_PROGRAM_STEPS 1000000

typedef struct {       /* START */
  uint32_t first_step; /* 0 for a new scan; k to resume at step k (< step_count) */
} proto_start_t;
#define PROTO_START_SIZE 4

typedef struct {      /* ACK and NACK */
  uint16_t acked_seq; /* the seq of the command answered (also in the header) */
  uint8_t acked_type; /* its type (0 when the frame was too damaged to tell) */
  uint8_t status;     /* PROTO_ST_OK in an ACK, the reason in a NACK */
  uint8_t detail;     /* NACK BAD_VALUE: the 1-based index of the offending field; else 0 */
} proto_ack_t;
#define PROTO_ACK_SIZE (2 + 1 + 1 + 1)

/* TRIGGER_EVENT flags */
#define PROTO_TRIG_IN_PROGRAM (1u << 0)    /* taken by a scan program (step_index and shot are valid) */
#define PROTO_TRIG_EXPOSURE_SEEN (1u << 1) /* exposure_seen_us is valid */

typedef struct {             /* TRIGGER_EVENT: one camera trigger edge */
  uint32_t trigger_seq;      /* counts every trigger since power-on, from 0: a gap is a lost event */
  uint64_t time_us;          /* device time of the trigger edge (exact: the hardware compare time) */
  uint64_t exposure_seen_us; /* device time the camera's exposure line went active, if flags say so */
  int32_t position;          /* motor position (steps) at the edge */
  uint32_t step_index;       /* program step, 0xFFFFFFFF outside a program */
  uint8_t laser_mask;        /* lasers that were on at the edge */
  uint8_t shot;              /* shot index within the step (0 outside a program) */
  uint8_t flags;             /* PROTO_TRIG_* */
} proto_trigger_event_t;
#define PROTO_TRIGGER_EVENT_SIZE (4 + 8 + 8 + 4 + 4 + 1 + 1 + 1)

typedef struct {     /* MOVE_DONE: the end of a MOVE command */
  uint32_t move_seq; /* counts MOVE_DONE events since power-on, from 0 */
  uint64_t time_us;  /* device time of the end of the move */
  int32_t position;  /* motor position after it */
  uint8_t status;    /* PROTO_ST_OK, or PROTO_MOVE_ABORTED */
} proto_move_done_t;
#define PROTO_MOVE_DONE_SIZE (4 + 8 + 4 + 1)
#define PROTO_MOVE_ABORTED 0x80

/* STATUS.state */
enum proto_state {
  PROTO_STATE_IDLE = 0,
  PROTO_STATE_MOVING = 1,
  PROTO_STATE_RUNNING = 2,
  PROTO_STATE_TRIGGER = 3
};
/* STATUS.cause */
enum proto_cause {
  PROTO_CAUSE_REPLY = 0,        /* answer to GET_STATUS (header seq = the command's seq) */
  PROTO_CAUSE_PROGRAM_DONE = 1, /* the program ran its last step */
  PROTO_CAUSE_ABORTED = 2,      /* ABORT stopped a move, program or trigger */
  PROTO_CAUSE_SAFETY = 3, /* the host was silent longer than laser_timeout_ms: lasers off, program stopped */
  PROTO_CAUSE_BOOT = 4    /* sent once after power-on */
};
/* STATUS.flags */
#define PROTO_FLAG_MOTOR_ENABLED (1u << 0)
#define PROTO_FLAG_PROGRAM_LOADED (1u << 1)
#define PROTO_FLAG_SAFETY_TRIPPED (1u << 2) /* cleared by the next valid command */

typedef struct {              /* STATUS */
  uint32_t status_seq;        /* counts STATUS frames since power-on, from 0 */
  uint64_t time_us;           /* device time */
  uint8_t cause;              /* enum proto_cause */
  uint8_t state;              /* enum proto_state */
  uint8_t flags;              /* PROTO_FLAG_* */
  uint8_t lasers;             /* laser mask now */
  int32_t position;           /* motor position (steps) */
  uint32_t program_next_step; /* the step a running program takes next (= where to resume) */
  uint32_t program_steps;     /* the loaded program's step_count, 0 if none */
  uint32_t trigger_count;     /* TRIGGER_EVENTs produced since power-on */
  uint32_t rx_errors;         /* frames dropped as malformed since power-on */
  uint32_t events_dropped;    /* events lost because the transmit queue was full */
} proto_status_t;
#define PROTO_STATUS_SIZE (4 + 8 + 1 + 1 + 1 + 1 + 4 + 4 + 4 + 4 + 4 + 4)

/* DIAG.flags */
#define PROTO_DIAG_CYCLES_VALID (1u << 0) /* the board counts CPU cycles: the step_isr_* fields hold them */
#define PROTO_DIAG_FAULT_VALID (1u << 1)  /* a fault was recorded before the last reset: the fault_* fields */

typedef struct {                 /* DIAG: what only the board knows about itself (answer to GET_DIAG) */
  uint8_t flags;                 /* PROTO_DIAG_* */
  uint32_t cpu_hz;               /* the clock the cycles are counted in (0 if not counted) */
  uint32_t step_isr_cycles_max;  /* the step interrupt's worst run since power-on, in CPU cycles */
  uint32_t step_isr_cycles_last; /* its last run */
  uint32_t fault_count;          /* faults since power-on (the record survives resets, not power cycles) */
  uint32_t fault_vector;         /* exception number of the fault (3 = HardFault, 16 + n = interrupt n) */
  uint32_t fault_pc;             /* the stacked PC, LR and xPSR of the faulting code */
  uint32_t fault_lr;
  uint32_t fault_psr;
  uint32_t fault_cfsr; /* the fault status registers (Cortex-M: CFSR, HFSR) */
  uint32_t fault_hfsr;
} proto_diag_t;
#define PROTO_DIAG_SIZE (1 + 4 * 10)

/* LOG.level */
enum proto_log_level { PROTO_LOG_DEBUG = 0, PROTO_LOG_INFO = 1, PROTO_LOG_WARNING = 2, PROTO_LOG_ERROR = 3 };

typedef struct {    /* LOG: a short text from the firmware */
  uint32_t log_seq; /* counts LOG events since power-on */
  uint8_t level;    /* enum proto_log_level */
  uint8_t length;   /* bytes of text, 0..PROTO_MAX_LOG_TEXT; the payload holds exactly these */
  char text[PROTO_MAX_LOG_TEXT + 1]; /* NUL-terminated after decoding; not NUL-terminated on the wire */
} proto_log_t;
#define PROTO_LOG_FIXED_SIZE (4 + 1 + 1)

PROTO_STATIC_ASSERT(PROTO_INFO_SIZE == 24, "INFO is frozen at 24 bytes");
PROTO_STATIC_ASSERT(PROTO_PONG_SIZE == 16, "PONG size");
PROTO_STATIC_ASSERT(PROTO_CONFIG_SIZE == 21, "SET_CONFIG size");
PROTO_STATIC_ASSERT(PROTO_TRIGGER_SIZE == 9, "TRIGGER size");
PROTO_STATIC_ASSERT(PROTO_ACK_SIZE == 5, "ACK size");
PROTO_STATIC_ASSERT(PROTO_TRIGGER_EVENT_SIZE == 31, "TRIGGER_EVENT size");
PROTO_STATIC_ASSERT(PROTO_MOVE_DONE_SIZE == 17, "MOVE_DONE size");
PROTO_STATIC_ASSERT(PROTO_STATUS_SIZE == 40, "STATUS size");
PROTO_STATIC_ASSERT(PROTO_DIAG_SIZE == 41, "DIAG size");
PROTO_STATIC_ASSERT(PROTO_PROGRAM_SIZE(PROTO_MAX_SHOTS) <= PROTO_MAX_PAYLOAD, "a full program fits a frame");
PROTO_STATIC_ASSERT(PROTO_LOG_FIXED_SIZE + PROTO_MAX_LOG_TEXT <= PROTO_MAX_PAYLOAD,
                    "a full LOG fits a frame");
PROTO_STATIC_ASSERT(PROTO_MAX_RAW_FRAME < 254, "a raw frame needs one COBS code byte at most");
PROTO_STATIC_ASSERT(PROTO_MAX_WIRE_FRAME == 138, "largest frame on the wire, delimiter included");

/* A decoded (or to-be-encoded) message. `type` says which member of `body` is valid. */
typedef struct {
  uint8_t version; /* as received; proto_msg_init() sets PROTO_VERSION_MAJOR */
  uint8_t type;    /* enum proto_type */
  uint16_t seq;
  union {
    proto_info_t info;
    proto_ping_t ping;
    proto_pong_t pong;
    proto_config_t config;
    proto_motor_enable_t motor_enable;
    proto_move_t move;
    proto_set_lasers_t set_lasers;
    proto_trigger_t trigger;
    proto_program_t program;
    proto_start_t start;
    proto_ack_t ack; /* ACK and NACK */
    proto_trigger_event_t trigger_event;
    proto_move_done_t move_done;
    proto_status_t status;
    proto_diag_t diag;
    proto_log_t log;
  } body;
} proto_msg_t;

/* Zeroes *msg and sets version = PROTO_VERSION_MAJOR, type and seq. */
void proto_msg_init(proto_msg_t* msg, uint8_t type, uint16_t seq);

/* ---- CRC-32 ------------------------------------------------------------------------------------------ */

/* zlib-compatible: proto_crc32(0, "123456789", 9) == 0xCBF43926; chain by passing the previous result. */
uint32_t proto_crc32(uint32_t crc, const uint8_t* data, size_t len);

/* ---- COBS -------------------------------------------------------------------------------------------- */

/* Stuffs `len` bytes into `out` (no delimiter written). Returns the encoded length, or -ENOSPC / -EINVAL. */
int proto_cobs_encode(const uint8_t* in, size_t len, uint8_t* out, size_t out_cap);
/* Unstuffs `len` bytes (no delimiter). Returns the decoded length, -EBADMSG on a 0x00 or a code running past
 * the end, -ENOSPC / -EINVAL. `out` may equal `in` (in-place decoding). */
int proto_cobs_decode(const uint8_t* in, size_t len, uint8_t* out, size_t out_cap);

/* ---- Messages ---------------------------------------------------------------------------------------- */

/* Payload length of `msg` on the wire (depends on shot_count / length for programs and logs), or -ENOMSG
 * for an unknown type, -EINVAL for a count out of range. */
int proto_payload_size(const proto_msg_t* msg);

/* Raw frame (header | payload | crc, not stuffed). Returns its length or a negative errno. Fields that do not
 * fit their wire range (shot_count, log length) give -EINVAL; values are not otherwise judged here. */
int proto_pack(const proto_msg_t* msg, uint8_t* out, size_t out_cap);

/* Parses a raw frame. On any error at or after the header, msg->version/type/seq hold what was read (so that
 * a NACK can name the seq); msg->type is 0 when fewer than 4 bytes came. Returns 0 or -EBADMSG (short, CRC),
 * -EPROTO, -ENOMSG, -EMSGSIZE. */
int proto_unpack(const uint8_t* raw, size_t len, proto_msg_t* msg);

/* pack + COBS + the 0x00 delimiter: the bytes to put on the wire. Returns their count or a negative errno;
 * PROTO_MAX_WIRE_FRAME bytes always suffice. */
int proto_encode_frame(const proto_msg_t* msg, uint8_t* out, size_t out_cap);

/* COBS-decodes the bytes between two delimiters (the 0x00 excluded; a trailing 0x00 is also accepted) and
 * unpacks them. Same returns as proto_unpack (and -EBADMSG for bad COBS). */
int proto_decode_frame(const uint8_t* wire, size_t len, proto_msg_t* msg);

/* ---- Stream deframer: bytes in, one frame at a time out ---------------------------------------------- */

typedef struct {
  uint8_t buf[PROTO_MAX_WIRE_FRAME];
  size_t len;
  bool overflow; /* the current frame outgrew buf; it is dropped at the next 0x00 */
} proto_deframer_t;

void proto_deframer_init(proto_deframer_t* d);

/* Feeds one byte. Returns 0 while a frame is incomplete; 1 when `byte` was the 0x00 ending a non-empty
 * frame, whose stuffed bytes are then d->buf[0 .. *frame_len) (valid until the next call); -EMSGSIZE when
 * the delimiter ended a frame that overflowed the buffer (it is dropped). Empty frames (0x00 0x00) are
 * skipped, so a sender may send 0x00 first to resynchronise the receiver. */
int proto_deframer_push(proto_deframer_t* d, uint8_t byte, size_t* frame_len);

/* ---- Little-endian field helpers (shared by the codec and its tests) ---------------------------------- */

void proto_put_u16(uint8_t* p, uint16_t v);
void proto_put_u32(uint8_t* p, uint32_t v);
void proto_put_u64(uint8_t* p, uint64_t v);
uint16_t proto_get_u16(const uint8_t* p);
uint32_t proto_get_u32(const uint8_t* p);
uint64_t proto_get_u64(const uint8_t* p);

#ifdef __cplusplus
}
#endif

#endif /* ROTOSCAN_PROTOCOL_H_ */

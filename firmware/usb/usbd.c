/*
 * USB device request handling (USB 2.0 chapter 9) on top of dcd.h. A control transfer here:
 *   SETUP -> usbd_on_setup decodes it and either stalls endpoint 0, or queues the data stage (IN: the reply;
 *   OUT: a receive), or for a no-data request queues the status stage (a zero-length IN packet);
 *   IN data done -> a zero-length packet if one is due (the reply is shorter than wLength and a whole number
 *   of 64-byte packets: the host could not otherwise tell that it ended), then the status stage (receive
 *   the host's zero-length OUT);
 *   OUT data done -> the status stage (a zero-length IN).
 */
#include "usbd.h"

#include <string.h>

#include "dcd.h"

enum { REQ_GET_STATUS = 0, REQ_CLEAR_FEATURE = 1, REQ_SET_FEATURE = 3, REQ_SET_ADDRESS = 5,
       REQ_GET_DESCRIPTOR = 6, REQ_GET_CONFIGURATION = 8, REQ_SET_CONFIGURATION = 9, REQ_GET_INTERFACE = 10,
       REQ_SET_INTERFACE = 11 };
enum { DESC_DEVICE = 1, DESC_CONFIG = 2, DESC_STRING = 3, DESC_DEVICE_QUALIFIER = 6, DESC_BOS = 15 };
enum { TYPE_STANDARD = 0, TYPE_VENDOR = 2 };
enum { RCPT_DEVICE = 0, RCPT_INTERFACE = 1, RCPT_ENDPOINT = 2 };
#define FEATURE_ENDPOINT_HALT 0u

enum ctrl_stage { CTRL_IDLE = 0, CTRL_DATA_IN, CTRL_ZLP_IN, CTRL_STATUS_OUT, CTRL_STATUS_IN };

static struct {
  const usbd_function_t* fn;
  uint8_t configuration;
  uint8_t address;
  uint32_t stalls;
  enum ctrl_stage stage;
  bool zlp_due;
  uint8_t buf[DCD_EP0_SIZE]; /* replies built here (strings, status) */
} g_usbd;

void usbd_init(const usbd_function_t* function) {
  memset(&g_usbd, 0, sizeof(g_usbd));
  g_usbd.fn = function;
}
uint8_t usbd_configuration(void) {
  return g_usbd.configuration;
}
uint8_t usbd_address(void) {
  return g_usbd.address;
}
uint32_t usbd_stalls(void) {
  return g_usbd.stalls;
}

static void stall(void) {
  ++g_usbd.stalls;
  g_usbd.stage = CTRL_IDLE;
  dcd_ep_stall(0);
}

static void status_in(void) {
  g_usbd.stage = CTRL_STATUS_IN;
  (void)dcd_ep_xfer(DCD_DIR_IN, NULL, 0);
}

/* Sends `len` bytes of `data` as the data stage of a request asking for w_length. */
static void reply(const usbd_setup_t* s, const uint8_t* data, size_t len) {
  if (len > s->w_length) len = s->w_length;
  g_usbd.zlp_due = len < s->w_length && len % DCD_EP0_SIZE == 0u;
  g_usbd.stage = CTRL_DATA_IN;
  (void)dcd_ep_xfer(DCD_DIR_IN, (uint8_t*)(uintptr_t)data, (uint16_t)len);
}

static void set_configured(uint8_t value) {
  const usbd_function_t* fn = g_usbd.fn;
  if (g_usbd.configuration == value) return;
  g_usbd.configuration = value;
  if (value == 1u) {
    dcd_ep_open_bulk(fn->ep_in, fn->ep_size);
    dcd_ep_open_bulk(fn->ep_out, fn->ep_size);
  }
  if (fn->on_configured != NULL) fn->on_configured(value == 1u);
}

static bool our_endpoint(uint16_t ep) {
  const usbd_function_t* fn = g_usbd.fn;
  return g_usbd.configuration == 1u && (ep == fn->ep_in || ep == fn->ep_out);
}

/* String descriptor `index` as UTF-16LE in g_usbd.buf; its length, or 0 if there is none. */
static size_t string_descriptor(uint8_t index, uint16_t lang) {
  uint8_t* d = g_usbd.buf;
  if (index == 0u) {
    d[0] = 4;
    d[1] = DESC_STRING;
    d[2] = 0x09; /* 0x0409, English (United States) */
    d[3] = 0x04;
    return 4;
  }
  if (index > g_usbd.fn->string_count || lang != 0x0409u) return 0;
  const char* text = g_usbd.fn->strings[index];
  size_t n = strlen(text);
  if (n > USBD_MAX_STRING_CHARS) n = USBD_MAX_STRING_CHARS;
  d[0] = (uint8_t)(2u + 2u * n);
  d[1] = DESC_STRING;
  for (size_t i = 0; i < n; ++i) {
    d[2u + 2u * i] = (uint8_t)text[i];
    d[3u + 2u * i] = 0;
  }
  return d[0];
}

static void get_descriptor(const usbd_setup_t* s) {
  const uint8_t type = (uint8_t)(s->w_value >> 8);
  const uint8_t index = (uint8_t)(s->w_value & 0xFFu);
  switch (type) {
    case DESC_DEVICE:
      if (index != 0u) break;
      reply(s, g_usbd.fn->device, g_usbd.fn->device[0]);
      return;
    case DESC_CONFIG:
      if (index != 0u) break;
      reply(s, g_usbd.fn->config, (size_t)g_usbd.fn->config[2] | (size_t)g_usbd.fn->config[3] << 8);
      return;
    case DESC_STRING: {
      const size_t n = string_descriptor(index, s->w_index);
      if (n == 0u) break;
      reply(s, g_usbd.buf, n);
      return;
    }
    /* A full-speed-only device has no device qualifier and must stall its request (USB 2.0 9.6.2); with
     * bcdUSB 2.00 there is no BOS either. */
    case DESC_DEVICE_QUALIFIER:
    case DESC_BOS:
    default: break;
  }
  stall();
}

static void standard_request(const usbd_setup_t* s) {
  const uint8_t rcpt = s->bm_request_type & 0x1Fu;
  const bool in = (s->bm_request_type & 0x80u) != 0u;
  switch (s->b_request) {
    case REQ_GET_DESCRIPTOR:
      if (!in || rcpt != RCPT_DEVICE || s->w_length == 0u) break;
      get_descriptor(s);
      return;
    case REQ_SET_ADDRESS:
      if (in || rcpt != RCPT_DEVICE || s->w_value > 127u || s->w_index != 0u || s->w_length != 0u ||
          g_usbd.configuration != 0u)
        break;
      g_usbd.address = (uint8_t)s->w_value;
      dcd_set_address(g_usbd.address); /* before the status stage: dcd_dwc2.c, TRAP 5 */
      status_in();
      return;
    case REQ_SET_CONFIGURATION:
      if (in || rcpt != RCPT_DEVICE || s->w_value > 1u || s->w_length != 0u || g_usbd.address == 0u) break;
      set_configured((uint8_t)s->w_value);
      status_in();
      return;
    case REQ_GET_CONFIGURATION:
      if (!in || rcpt != RCPT_DEVICE || s->w_length != 1u) break;
      g_usbd.buf[0] = g_usbd.configuration;
      reply(s, g_usbd.buf, 1);
      return;
    case REQ_GET_STATUS: {
      if (!in || s->w_length != 2u || s->w_value != 0u) break;
      g_usbd.buf[0] = 0; /* bus powered, no remote wakeup; interface: reserved zeros */
      g_usbd.buf[1] = 0;
      if (rcpt == RCPT_ENDPOINT) {
        if (s->w_index != 0u && !our_endpoint(s->w_index)) break;
        g_usbd.buf[0] = dcd_ep_stalled((uint8_t)s->w_index) ? 1u : 0u;
      } else if (rcpt == RCPT_INTERFACE) {
        if (g_usbd.configuration == 0u || s->w_index != 0u) break;
      } else if (rcpt != RCPT_DEVICE) {
        break;
      }
      reply(s, g_usbd.buf, 2);
      return;
    }
    case REQ_CLEAR_FEATURE:
    case REQ_SET_FEATURE:
      if (in || rcpt != RCPT_ENDPOINT || s->w_value != FEATURE_ENDPOINT_HALT || s->w_length != 0u ||
          !our_endpoint(s->w_index))
        break;
      if (s->b_request == REQ_CLEAR_FEATURE) {
        dcd_ep_clear_stall((uint8_t)s->w_index);
      } else {
        dcd_ep_stall((uint8_t)s->w_index);
      }
      status_in();
      return;
    case REQ_GET_INTERFACE:
      if (!in || rcpt != RCPT_INTERFACE || s->w_index != 0u || s->w_length != 1u || g_usbd.configuration == 0u)
        break;
      g_usbd.buf[0] = 0;
      reply(s, g_usbd.buf, 1);
      return;
    case REQ_SET_INTERFACE:
      if (in || rcpt != RCPT_INTERFACE || s->w_index != 0u || s->w_value != 0u || s->w_length != 0u ||
          g_usbd.configuration == 0u)
        break;
      status_in();
      return;
    default: break;
  }
  stall();
}

static void vendor_request(const usbd_setup_t* s) {
  const bool in = (s->bm_request_type & 0x80u) != 0u;
  /* Host-to-device vendor requests carry no data here: one with a data stage is refused. */
  if (g_usbd.fn->on_vendor_request == NULL || (!in && s->w_length != 0u)) {
    stall();
    return;
  }
  const int n = g_usbd.fn->on_vendor_request(s, g_usbd.buf, sizeof(g_usbd.buf));
  if (n < 0 || (in && (s->w_length == 0u || n == 0)) || (!in && n != 0)) {
    stall();
    return;
  }
  if (in) {
    reply(s, g_usbd.buf, (size_t)n);
  } else {
    status_in();
  }
}

void usbd_on_bus_reset(void) {
  const bool was_configured = g_usbd.configuration != 0u;
  g_usbd.configuration = 0;
  g_usbd.address = 0;
  g_usbd.stage = CTRL_IDLE;
  if (was_configured && g_usbd.fn->on_configured != NULL) g_usbd.fn->on_configured(false);
}

void usbd_on_setup(const uint8_t raw[8]) {
  usbd_setup_t s;
  s.bm_request_type = raw[0];
  s.b_request = raw[1];
  s.w_value = (uint16_t)(raw[2] | raw[3] << 8);
  s.w_index = (uint16_t)(raw[4] | raw[5] << 8);
  s.w_length = (uint16_t)(raw[6] | raw[7] << 8);
  g_usbd.stage = CTRL_IDLE;
  switch ((s.bm_request_type >> 5) & 3u) {
    case TYPE_STANDARD: standard_request(&s); return;
    case TYPE_VENDOR: vendor_request(&s); return;
    default: stall(); return; /* no class requests */
  }
}

void usbd_on_xfer_done(uint8_t ep, uint16_t len) {
  if ((ep & 0x7Fu) != 0u) {
    if (g_usbd.fn->on_xfer_done != NULL) g_usbd.fn->on_xfer_done(ep, len);
    return;
  }
  switch (g_usbd.stage) {
    case CTRL_DATA_IN:
      if (!(ep & DCD_DIR_IN)) break;
      if (g_usbd.zlp_due) {
        g_usbd.zlp_due = false;
        g_usbd.stage = CTRL_ZLP_IN;
        (void)dcd_ep_xfer(DCD_DIR_IN, NULL, 0);
        break;
      }
      /* fall through */
    case CTRL_ZLP_IN:
      if (!(ep & DCD_DIR_IN)) break;
      g_usbd.stage = CTRL_STATUS_OUT;
      (void)dcd_ep_xfer(0, g_usbd.buf, sizeof(g_usbd.buf));
      break;
    case CTRL_STATUS_OUT:
    case CTRL_STATUS_IN: g_usbd.stage = CTRL_IDLE; break;
    default: break;
  }
}

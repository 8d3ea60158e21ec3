/*
 * The board's USB function: descriptors, and bulk traffic to and from the core's link queues.
 *
 * OUT (host -> board): one 64-byte packet at a time into rx_buf, handed to fw_usb_rx. When the core's queue is
 * full the rest is held back and the endpoint is not re-armed -- the core NAKs the host until usb_link_service
 * has delivered it (flow control instead of loss).
 * IN (board -> host): up to 64 bytes from fw_usb_tx per packet. When a packet was full and nothing more is
 * queued, a zero-length packet ends the transfer: a host read of more than 64 bytes would otherwise wait
 * for a short packet that never comes (USB 2.0 5.8.3).
 * A bus reset (a re-plug of this self-powered board, or the host's reset) flushes the transmit FIFO: the
 * packet in flight then was never acknowledged, and is sent again first once the host configures the board
 * (found by the emulator test of issue 18: without it the events in that packet were lost). A host that
 * did receive it before the reset sees a duplicate, which the framing's CRC and event sequence numbers
 * reject. Bytes of an OUT packet the core had not taken yet are kept across the reset in the same way.
 */
#include "usb_link.h"

#include <string.h>

#include "dcd.h"
#include "fw.h"
#include "usbd.h"

static const uint8_t k_device[18] = {
    18, 1,                   /* bLength, DEVICE */
    0x00, 0x02,              /* bcdUSB 2.00 */
    0x00, 0x00, 0x00,        /* class per interface */
    DCD_EP0_SIZE,            /* bMaxPacketSize0 */
    USB_LINK_VID & 0xFFu, USB_LINK_VID >> 8, USB_LINK_PID & 0xFFu, USB_LINK_PID >> 8,
    FW_VERSION_PATCH | FW_VERSION_MINOR << 4, FW_VERSION_MAJOR, /* bcdDevice = major.minor.patch */
    1, 2, 3,                 /* iManufacturer, iProduct, iSerialNumber */
    1};                      /* bNumConfigurations */

#define CONFIG_TOTAL (9u + 9u + 7u + 7u)
static const uint8_t k_config[CONFIG_TOTAL] = {
    9, 2, CONFIG_TOTAL, 0, 1, 1, 0, 0x80, 50, /* one interface, configuration 1, bus powered, 100 mA */
    9, 4, 0, 0, 2, 0xFF, 0x00, 0x00, 0,        /* interface 0: two endpoints, vendor specific */
    7, 5, USB_LINK_EP_OUT, 2, USB_LINK_PACKET, 0, 0, /* bulk OUT */
    7, 5, USB_LINK_EP_IN, 2, USB_LINK_PACKET, 0, 0}; /* bulk IN */

static struct {
  char serial[25];
  const char* strings[4];
  usbd_function_t fn;
  bool configured;
  uint8_t rx_buf[USB_LINK_PACKET];
  uint16_t rx_len;  /* bytes in rx_buf */
  uint16_t rx_done; /* of which fw_usb_rx took */
  bool rx_armed;
  uint8_t tx_buf[USB_LINK_PACKET];
  uint16_t tx_len; /* bytes of the packet in tx_buf */
  bool tx_busy;
  bool tx_resend; /* tx_buf was in flight at a bus reset: send it again before anything new */
  bool zlp_due; /* the last packet sent was full */
} g_link;

static void arm_rx(void) {
  g_link.rx_len = 0;
  g_link.rx_done = 0;
  g_link.rx_armed = dcd_ep_xfer(USB_LINK_EP_OUT, g_link.rx_buf, USB_LINK_PACKET);
}

static void pump_rx(void) {
  if (!g_link.configured || g_link.rx_armed) return;
  if (g_link.rx_done < g_link.rx_len) {
    g_link.rx_done = (uint16_t)(g_link.rx_done +
                                fw_usb_rx(g_link.rx_buf + g_link.rx_done, (size_t)(g_link.rx_len - g_link.rx_done)));
  }
  if (g_link.rx_done >= g_link.rx_len) arm_rx();
}

static void pump_tx(void) {
  if (!g_link.configured || g_link.tx_busy) return;
  const size_t n = g_link.tx_resend ? g_link.tx_len : fw_usb_tx(g_link.tx_buf, sizeof(g_link.tx_buf));
  if (n == 0u && !g_link.zlp_due) return;
  g_link.zlp_due = n == USB_LINK_PACKET;
  g_link.tx_len = (uint16_t)n;
  g_link.tx_busy = dcd_ep_xfer(USB_LINK_EP_IN, g_link.tx_buf, (uint16_t)n);
  if (g_link.tx_busy) g_link.tx_resend = false;
}

static void on_configured(bool configured) {
  if (!configured && g_link.tx_busy && g_link.tx_len > 0u) g_link.tx_resend = true;
  g_link.configured = configured;
  g_link.rx_armed = false; /* what rx_buf holds and the core has not taken yet is kept (pump_rx) */
  g_link.tx_busy = false;
  g_link.zlp_due = false;
  if (configured) {
    pump_rx();
    pump_tx();
  }
}

static void on_xfer_done(uint8_t ep, uint16_t len) {
  if (ep == USB_LINK_EP_OUT) {
    g_link.rx_armed = false;
    g_link.rx_len = len;
    g_link.rx_done = 0;
    pump_rx();
  } else if (ep == USB_LINK_EP_IN) {
    g_link.tx_busy = false;
    pump_tx();
  }
}

static int on_vendor_request(const usbd_setup_t* s, uint8_t* reply, size_t room) {
  if (s->b_request != USB_LINK_REQ_VERSION || (s->bm_request_type & 0x80u) == 0u ||
      (s->bm_request_type & 0x1Fu) != 0u || room < 3u)
    return -1;
  reply[0] = FW_VERSION_MAJOR;
  reply[1] = FW_VERSION_MINOR;
  reply[2] = FW_VERSION_PATCH;
  return 3;
}

void usb_link_init(const uint8_t uid[12]) {
  static const char hex[] = "0123456789ABCDEF";
  memset(&g_link, 0, sizeof(g_link));
  for (size_t i = 0; i < 12u; ++i) {
    g_link.serial[2u * i] = hex[uid[i] >> 4];
    g_link.serial[2u * i + 1u] = hex[uid[i] & 0xFu];
  }
  g_link.strings[0] = "";
  g_link.strings[1] = "Rotoscan";
  g_link.strings[2] = "Rotoscan scanner board";
  g_link.strings[3] = g_link.serial;
  g_link.fn.device = k_device;
  g_link.fn.config = k_config;
  g_link.fn.strings = g_link.strings;
  g_link.fn.string_count = 3;
  g_link.fn.ep_in = USB_LINK_EP_IN;
  g_link.fn.ep_out = USB_LINK_EP_OUT;
  g_link.fn.ep_size = USB_LINK_PACKET;
  g_link.fn.on_configured = on_configured;
  g_link.fn.on_xfer_done = on_xfer_done;
  g_link.fn.on_vendor_request = on_vendor_request;
  usbd_init(&g_link.fn);
}

void usb_link_service(void) {
  pump_rx();
  pump_tx();
}

bool usb_link_wants_service(void) {
  if (!g_link.configured) return false;
  return (!g_link.rx_armed && g_link.rx_done < g_link.rx_len) || (!g_link.tx_busy && fw_usb_tx_pending() > 0u);
}

#include "link.h"

#include "hal.h"
#include "ring.h"

static struct {
  uint8_t rx_storage[USB_RX_QUEUE];
  uint8_t tx_storage[USB_TX_QUEUE];
  ring_t rx; /* isr -> main */
  ring_t tx; /* main -> isr (or the port's main loop) */
  proto_deframer_t deframer;
} g_link;

void usb_init(void) {
  (void)ring_init(&g_link.rx, g_link.rx_storage, USB_RX_QUEUE, 1);
  (void)ring_init(&g_link.tx, g_link.tx_storage, USB_TX_QUEUE, 1);
  proto_deframer_init(&g_link.deframer);
}

size_t usb_rx_isr(const uint8_t* data, size_t len) {
  if (data == NULL) return 0;
  const uint32_t n = len > USB_RX_QUEUE ? USB_RX_QUEUE : (uint32_t)len;
  return ring_write_some(&g_link.rx, data, n);
}

size_t usb_tx_take(uint8_t* out, size_t max) {
  if (out == NULL) return 0;
  const uint32_t n = max > USB_TX_QUEUE ? USB_TX_QUEUE : (uint32_t)max;
  return ring_read(&g_link.tx, out, n);
}

size_t usb_tx_pending(void) {
  return ring_count(&g_link.tx);
}

int usb_next_frame(const uint8_t** frame, size_t* len) {
  uint8_t byte;
  while (ring_pop(&g_link.rx, &byte)) {
    const int r = proto_deframer_push(&g_link.deframer, byte, len);
    if (r == 1) {
      *frame = g_link.deframer.buf;
      return 1;
    }
    if (r < 0) return r;
  }
  return 0;
}

bool usb_tx_room(size_t bytes) {
  return ring_space(&g_link.tx) >= bytes;
}

bool usb_send_wire(const uint8_t* wire, size_t len) {
  if (len > USB_TX_QUEUE) return false;
  if (!ring_write_all(&g_link.tx, wire, (uint32_t)len)) return false;
  (void)hal_usb_tx_kick();
  return true;
}

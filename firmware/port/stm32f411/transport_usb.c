/*
 * The USB transport of the STM32F411 port: the OTG_FS core on PA11/PA12 through our stack (firmware/usb:
 * dcd_dwc2.c, usbd.c, usb_link.c). All USB work runs in the OTG_FS interrupt; the main loop only pends that
 * interrupt when the link has bytes to move (hal_usb_tx_kick, transport_poll), so the core's queues always
 * have one interrupt-side user.
 */
#include "board.h"
#include "dcd.h"
#include "hal.h"
#include "port.h"
#include "usb_link.h"

#define PRIO_USB 2u

void OTG_FS_IRQHandler(void);
void OTG_FS_IRQHandler(void) {
  port_note_wake();
  dcd_irq();
  usb_link_service();
}

void transport_init(void) {
  REG32(RCC_AHB2ENR) |= RCC_AHB2ENR_OTGFSEN;
  (void)REG32(RCC_AHB2ENR);
  const uint32_t moder = REG32(BOARD_USB_PORT + GPIO_MODER) &
                         ~((3u << (2u * BOARD_USB_DM_PIN)) | (3u << (2u * BOARD_USB_DP_PIN)));
  REG32(BOARD_USB_PORT + GPIO_MODER) =
      moder | (GPIO_MODE_AF << (2u * BOARD_USB_DM_PIN)) | (GPIO_MODE_AF << (2u * BOARD_USB_DP_PIN));
  REG32(BOARD_USB_PORT + GPIO_OSPEEDR) |= (3u << (2u * BOARD_USB_DM_PIN)) | (3u << (2u * BOARD_USB_DP_PIN));
  REG32(BOARD_USB_PORT + GPIO_AFRH) =
      (REG32(BOARD_USB_PORT + GPIO_AFRH) & ~((0xFu << (4u * (BOARD_USB_DM_PIN - 8u))) | (0xFu << (4u * (BOARD_USB_DP_PIN - 8u))))) |
      (BOARD_USB_AF << (4u * (BOARD_USB_DM_PIN - 8u))) | (BOARD_USB_AF << (4u * (BOARD_USB_DP_PIN - 8u)));
  uint8_t uid[12];
  (void)hal_uid(uid);
  usb_link_init(uid);
  if (dcd_init() != 0) return; /* no 48 MHz clock: the board stays off the bus (the LED still comes on) */
  dcd_connect();
  nvic_enable(IRQ_OTG_FS, PRIO_USB);
}

void transport_poll(void) {
  if (usb_link_wants_service()) nvic_pend(IRQ_OTG_FS);
}

int hal_usb_tx_kick(void) {
  nvic_pend(IRQ_OTG_FS);
  return 0;
}

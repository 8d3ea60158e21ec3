/*
 * The UART transport of the STM32F411 port, for bring-up without USB: USART1 on PB6 (TX) / PB7 (RX), 115200
 * 8N1, carrying exactly the bytes the USB bulk endpoints carry (COBS frames ending in 0x00), so a host can
 * talk to it through any USB-serial adapter. Receive and transmit run in the USART1 interrupt; a byte the
 * core's receive queue cannot take is dropped and counted (a UART has no flow control here) -- the COBS
 * framing resynchronises on the next 0x00 and the CRC rejects the damaged frame.
 */
#include "board.h"
#include "fw.h"
#include "hal.h"
#include "port.h"

#define PRIO_UART 2u
#define USART_REG(off) REG32(USART1_BASE + (off))

static volatile uint32_t g_uart_dropped;

void USART1_IRQHandler(void);
void USART1_IRQHandler(void) {
  const uint32_t sr = USART_REG(USART_SR);
  port_note_wake();
  if (sr & (USART_SR_RXNE | USART_SR_ORE)) {
    const uint8_t b = (uint8_t)USART_REG(USART_DR); /* reading DR clears RXNE and ORE */
    if (fw_usb_rx(&b, 1) != 1u) ++g_uart_dropped;
  }
  if ((sr & USART_SR_TXE) && (USART_REG(USART_CR1) & USART_CR1_TXEIE)) {
    uint8_t b;
    if (fw_usb_tx(&b, 1) == 1u) {
      USART_REG(USART_DR) = b;
    } else {
      USART_REG(USART_CR1) &= ~USART_CR1_TXEIE;
    }
  }
}

void transport_init(void) {
  REG32(RCC_APB2ENR) |= RCC_APB2ENR_USART1EN;
  (void)REG32(RCC_APB2ENR);
  const uint32_t moder = REG32(BOARD_UART_PORT + GPIO_MODER) &
                         ~((3u << (2u * BOARD_UART_TX_PIN)) | (3u << (2u * BOARD_UART_RX_PIN)));
  REG32(BOARD_UART_PORT + GPIO_MODER) =
      moder | (GPIO_MODE_AF << (2u * BOARD_UART_TX_PIN)) | (GPIO_MODE_AF << (2u * BOARD_UART_RX_PIN));
  REG32(BOARD_UART_PORT + GPIO_PUPDR) |= 1u << (2u * BOARD_UART_RX_PIN); /* idle high when unplugged */
  REG32(BOARD_UART_PORT + GPIO_AFRL) =
      (REG32(BOARD_UART_PORT + GPIO_AFRL) & ~((0xFu << (4u * BOARD_UART_TX_PIN)) | (0xFu << (4u * BOARD_UART_RX_PIN)))) |
      (BOARD_UART_AF << (4u * BOARD_UART_TX_PIN)) | (BOARD_UART_AF << (4u * BOARD_UART_RX_PIN));
  /* Oversampling by 16: BRR = f / baud as mantissa.fraction in 12.4 fixed point (RM0383 19.3.4). */
  USART_REG(USART_BRR) = (CLOCK_APB2_HZ + BOARD_UART_BAUD / 2u) / BOARD_UART_BAUD;
  USART_REG(USART_CR1) = USART_CR1_UE | USART_CR1_TE | USART_CR1_RE | USART_CR1_RXNEIE;
  nvic_enable(IRQ_USART1, PRIO_UART);
}

void transport_poll(void) {
  if (fw_usb_tx_pending() > 0u) USART_REG(USART_CR1) |= USART_CR1_TXEIE;
}

int hal_usb_tx_kick(void) {
  USART_REG(USART_CR1) |= USART_CR1_TXEIE;
  return 0;
}

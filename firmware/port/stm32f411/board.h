/*
 * board.h -- every pin of the Rotoscan board on a WeAct "Black Pill" STM32F411CEU6 (25 MHz crystal), in one
 * place. The README's wiring section shows the same table. Timer channels are hardware functions: the trigger
 * edge is made by TIM2's output compare, the exposure line is timestamped by TIM2's input capture, and the
 * STEP pulse's falling edge by TIM3's compare, so none of them depends on interrupt latency.
 *
 *   signal      pin    function                      level
 *   STEP        PB4    TIM3_CH1 (AF2)                 pulse high >= 2 us, rising edge = step
 *   DIR         PB5    GPIO out                       high = positive direction (SET_CONFIG can invert)
 *   ENABLE      PB12   GPIO out                       low = driver enabled (A4988 / DRV8825 /EN); high at reset
 *   LASER_L     PB13   GPIO out                       high = left laser on (external pull-down: off at reset)
 *   LASER_R     PB14   GPIO out                       high = right laser on (external pull-down)
 *   TRIGGER     PA15   TIM2_CH1 (AF1), output compare high = trigger pulse (3.3 V: shift to the camera's level)
 *   EXPOSURE    PB10   TIM2_CH3 (AF1), input capture  the camera's exposure-active output (3.3 V: shift down)
 *   LED         PC13   GPIO out                       low = LED on (the Black Pill's blue LED)
 *   USB D-/D+   PA11 / PA12  OTG_FS (AF10)             the USB-C socket; VBUS is not wired to PA9
 *   UART TX/RX  PB6 / PB7    USART1 (AF7)              bring-up transport, 115200 8N1, 3.3 V
 */
#ifndef ROTOSCAN_FIRMWARE_BOARD_H_
#define ROTOSCAN_FIRMWARE_BOARD_H_

#include "stm32f411_regs.h"

#define BOARD_HSE_HZ 25000000u

#define BOARD_STEP_PORT GPIOB_BASE
#define BOARD_STEP_PIN 4u
#define BOARD_STEP_AF 2u /* TIM3_CH1 */
#define BOARD_DIR_PORT GPIOB_BASE
#define BOARD_DIR_PIN 5u
#define BOARD_ENABLE_PORT GPIOB_BASE
#define BOARD_ENABLE_PIN 12u
#define BOARD_LASER_PORT GPIOB_BASE /* both lasers on one port: one BSRR write switches both */
#define BOARD_LASER_L_PIN 13u
#define BOARD_LASER_R_PIN 14u
#define BOARD_TRIGGER_PORT GPIOA_BASE
#define BOARD_TRIGGER_PIN 15u
#define BOARD_TRIGGER_AF 1u /* TIM2_CH1 */
#define BOARD_EXPOSURE_PORT GPIOB_BASE
#define BOARD_EXPOSURE_PIN 10u
#define BOARD_EXPOSURE_AF 1u /* TIM2_CH3 */
#define BOARD_LED_PORT GPIOC_BASE
#define BOARD_LED_PIN 13u
#define BOARD_USB_PORT GPIOA_BASE
#define BOARD_USB_DM_PIN 11u
#define BOARD_USB_DP_PIN 12u
#define BOARD_USB_AF 10u
#define BOARD_UART_PORT GPIOB_BASE
#define BOARD_UART_TX_PIN 6u
#define BOARD_UART_RX_PIN 7u
#define BOARD_UART_AF 7u
#define BOARD_UART_BAUD 115200u

/* Timer channels. */
#define BOARD_TRIGGER_CH 1u  /* TIM2 CH1: the trigger edge, both edges by compare */
#define BOARD_LASER_CH 2u    /* TIM2 CH2: compare only (no pin), switches the lasers in its interrupt */
#define BOARD_EXPOSURE_CH 3u /* TIM2 CH3: input capture, both edges */
#define BOARD_STEP_CH 1u     /* TIM3 CH1 */

/* STEP pulse width in timer ticks (us): DRV8825 needs 1.9 us, A4988 1 us. */
#define BOARD_STEP_PULSE_US 3u

/* The LED and both lasers switched off, the driver disabled: what a fault leaves behind. */
#define BOARD_SAFE_BSRR_B ((1u << (BOARD_LASER_L_PIN + 16u)) | (1u << (BOARD_LASER_R_PIN + 16u)) | (1u << BOARD_ENABLE_PIN))

#endif /* ROTOSCAN_FIRMWARE_BOARD_H_ */

// An STM32F411 emulator that runs the firmware's flashed image (rotoscan-fw.elf) from reset, for issue 18.
//
// The CPU is Debian's unicorn 2 (QEMU's ARM translator) as a Cortex-M4 (UC_MODE_THUMB | UC_MODE_MCLASS,
// UC_CPU_ARM_CORTEX_M4). Unicorn has no interrupt controller and no peripherals; this harness adds them:
//   - exceptions: the NVIC's enable / pending / priority registers, SysTick, and the SCB registers the image
//     touches. Entry and return are done here, not by unicorn (its M-profile exception return needs the NVIC
//     of QEMU that unicorn leaves out): on entry the 8-word frame (r0-r3, r12, lr, pc, xPSR; 26 words when
//     CONTROL.FPCA says the FPU context is live, its 18 FP words reserved as the lazy stacking of the chip
//     reserves them) is pushed on the main stack with the 4-byte alignment bit, LR = EXC_RETURN, PC = the
//     vector; a branch to an EXC_RETURN value (0xFFFFFFxx, a page mapped for it) is caught by the
//     instruction hook and the frame popped. Nested preemption by priority, and tail-chaining: an exception
//     pending at a return that would preempt the code returned to is taken with the frame kept
//     (EmuOptions::tail_chaining).
//   - RCC (ready flags, the PLL and bus prescalers checked against RM0383's limits), the flash interface
//     (wait states checked against SYSCLK), PWR (voltage scale), GPIO A-C (pin levels, every edge recorded
//     with its cycle and the TIM2 count), TIM2 and TIM3 (counting in emulated time, output compare with
//     the OC modes the image uses, input capture with its filter delay, update events, interrupts), the DWT
//     cycle counter, the 96-bit unique id, and the OTG_FS core through firmware/tests/usb/dwc2_model.
//   - A camera on the pins (optional): each trigger rising edge drives the exposure-active line high after a
//     latency and low after the exposure, into TIM2's capture.
//
// Emulated time is counted in CPU cycles, from the instructions executed, by a cycle model -- a model, not
// the chip's exact timing (the Cortex-M4 TRM gives most instruction timings as ranges):
//   every instruction 1 cycle; a load or store +1 (LDR is 2 cycles); LDM/STM/PUSH/POP and VLDM/VSTM/VPUSH/
//   VPOP 1 + one per register (+1 for a load of a single register); LDRD/STRD 3; UDIV/SDIV 12 (the worst
//   case of 2-12); a taken branch, or any write to PC, +3 (the worst-case pipeline refill of the TRM's 1-3);
//   an access to a peripheral on APB1 (TIM2, TIM3, PWR) +4 (two APB1 clocks at 48 MHz), on AHB1/AHB2 (GPIO,
//   RCC, flash interface, OTG_FS) +1; exception entry 12 cycles, exception return 10; and the flash's wait
//   states (FLASH_ACR LATENCY, 3 at 96 MHz) where the ART accelerator does not hide them (RM0383 3.4.2): an
//   instruction fetch from a flash line that is neither the current one, the prefetched next one (PRFTEN)
//   nor in the instruction cache (ICEN, 64 lines of 128 bits, LRU), and a data read of flash
//   (literals, the vector on exception entry) that misses the data cache (DCEN, 8 lines), each + LATENCY
//   (EmuOptions::flash_wait_states; the model is described at Art in f411_emu.cc).
// Instructions are counted too. While the CPU sleeps (WFI) time runs to the next event without instructions.
//
// Anything the model does not know stops the run with an error that names the address and the faulting
// instruction (its PC and its halfwords in hex): a read or write of an unmapped address or of an
// unmodelled register, a peripheral used with its clock off, a clock-tree rule broken, an interrupt whose
// vector is the image's default handler (HardFault_Handler: no handler of its own), a HardFault (an
// instruction unicorn rejects, a fault of memory access), a sub-word access to a register that allows only
// words.
#pragma once

#include <cstdint>
#include <memory>
#include <string>
#include <vector>

#include "elf_image.h"

extern "C" {
#include "dwc2_model.h"
}

namespace rotoscan::fw_emu {

constexpr uint32_t kTim2Irq = 28;
constexpr uint32_t kTim3Irq = 29;
constexpr uint32_t kOtgFsIrq = 67;
constexpr uint32_t kSysTickException = 15;
constexpr uint32_t kIrqCount = 86;
constexpr uint32_t kExceptionCount = 16 + kIrqCount;

// GPIO ports A, B, C as 0, 1, 2.
enum : uint8_t { kPortA = 0, kPortB = 1, kPortC = 2 };

struct PinEdge {
  uint64_t cycle = 0;  // CPU cycles since power-on
  uint32_t tim2 = 0;   // TIM2's counter at that cycle
  uint8_t port = 0;
  uint8_t pin = 0;
  bool level = false;
};

// One exception's runs: count, and cycles from its entry (the 12 cycles included) to its return (the 10
// included), less the time spent in higher-priority exceptions that preempted it.
struct ExceptionStats {
  uint64_t runs = 0;
  uint64_t max_cycles = 0;
  uint64_t total_cycles = 0;
  // The largest difference between the first and the last DWT_CYCCNT read within one run: what the image's
  // own DWT measurement of the handler's body saw.
  uint64_t max_dwt_window = 0;
};

struct CameraModel {
  bool enabled = false;
  uint32_t latency_us = 12;    // trigger rising edge -> exposure line high
  uint32_t exposure_us = 400;  // exposure line high for this long
};

struct EmuOptions {
  uint8_t uid[12] = {0x33, 0x00, 0x2D, 0x00, 0x0F, 0x51, 0x34, 0x31, 0x33, 0x38, 0x37, 0x37};
  CameraModel camera;
  uint8_t ram_paint = 0xA5;  // every RAM byte at power-on (stack high-water mark by paint)
  // An interrupt whose vector is the image's default handler stops the run; false lets the image take it
  // (its fault handler then records the fault and resets the chip: the fault path under test).
  bool stop_on_unhandled_interrupt = true;
  // Flash wait states and the ART accelerator in the cycle model (false: flash as fast as RAM, the model
  // before they were added).
  bool flash_wait_states = true;
  // Tail-chaining: an exception pending at a handler's return that would preempt the code returned to is
  // taken at once, the frame kept (6 cycles instead of the return's 10 and the entry's 12). false: each
  // return goes back to the interrupted code, which then takes the pending exception.
  bool tail_chaining = true;
};

class F411Emu {
 public:
  F411Emu(const ElfImage& image, const EmuOptions& options);
  ~F411Emu();
  F411Emu(const F411Emu&) = delete;
  F411Emu& operator=(const F411Emu&) = delete;

  // Power-on reset: RAM painted, peripherals at their reset values, SP and PC from the vector table.
  void PowerOn();
  // Runs the CPU for `cycles` more cycles of emulated time. false when it stopped on an error.
  bool Run(uint64_t cycles);
  // The same in microseconds (in 100 us slices, each at the SYSCLK of its start).
  bool RunUs(uint64_t us);

  bool ok() const;
  const std::string& error() const;

  uint64_t cycles() const;
  uint64_t instructions() const;
  // Cycles spent waiting for flash (ART misses) and how many misses, instruction and data side.
  uint64_t flash_stall_cycles() const;
  uint64_t flash_misses() const;
  // Exceptions taken by tail-chaining.
  uint64_t tail_chains() const;
  uint64_t sleep_cycles() const;  // cycles spent in WFI
  uint64_t wfi_count() const;
  uint64_t resets() const;  // system resets requested by the image (AIRCR.SYSRESETREQ)
  uint32_t sysclk_hz() const;
  uint32_t usb_clock_hz() const;
  uint32_t apb1_hz() const;

  // A word of memory or a modelled register, read without side effects (for the tests).
  uint32_t Peek(uint32_t address);

  dwc2_model_t* usb();
  const ElfImage& image() const;

  const std::vector<PinEdge>& edges() const;
  bool PinLevel(uint8_t port, uint8_t pin) const;
  // Drives an input pin from outside at the current cycle.
  void SetInputPin(uint8_t port, uint8_t pin, bool level);
  // Sets an interrupt pending in the NVIC, as a peripheral would (taken if enabled: by the image, or here).
  void PendInterrupt(uint32_t irq, bool enable = false);
  // TIM2's counter now.
  uint32_t Tim2Now();

  const ExceptionStats& exception_stats(uint32_t exception) const;
  // The deepest the main stack has been since power-on: bytes below the top of RAM that are no longer the
  // power-on paint.
  uint32_t StackHighWater();
  // The camera model's exposure edges (cycle, TIM2 count, level), when enabled.
  const std::vector<PinEdge>& camera_edges() const;
  // Every input capture TIM2's channel 3 made: the cycle and the counter value it latched.
  const std::vector<PinEdge>& captures() const;

 private:
  struct Impl;
  std::unique_ptr<Impl> impl_;
};

}  // namespace rotoscan::fw_emu

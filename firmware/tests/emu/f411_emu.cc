// See f411_emu.h. Register addresses and reset values are written here again from RM0383 (rev. 3) and the
// ARMv7-M Architecture Reference Manual, on purpose apart from the firmware's stm32f411_regs.h: a wrong
// address on either side then shows as an unmodelled access instead of agreeing with itself.
#include "f411_emu.h"

#include <unicorn/unicorn.h>

#include <algorithm>
#include <array>
#include <cinttypes>
#include <cstdio>
#include <cstring>
#include <limits>

namespace rotoscan::fw_emu {

namespace {

constexpr uint32_t kFlashBase = 0x08000000, kFlashSize = 512 * 1024;
constexpr uint32_t kSramBase = 0x20000000, kSramSize = 128 * 1024;
constexpr uint32_t kSysMemPage = 0x1FFF7800;  // the 1 KB page with the unique id (0x1FFF7A10) and flash size
constexpr uint32_t kUidAddress = 0x1FFF7A10, kFlashSizeAddress = 0x1FFF7A22;
constexpr uint32_t kExcReturnPage = 0xFFFFFF00;  // EXC_RETURN values: 0xFFFFFFxx

// Peripheral windows (RM0383 table 1), each mapped as MMIO; the models below dispatch on the address.
constexpr uint32_t kTim2 = 0x40000000, kTim3 = 0x40000400, kPwr = 0x40007000;
constexpr uint32_t kGpioA = 0x40020000, kGpioB = 0x40020400, kGpioC = 0x40020800;
constexpr uint32_t kRcc = 0x40023800, kFlashIf = 0x40023C00;
constexpr uint32_t kOtgFs = 0x50000000, kOtgFsSize = 0x40000;
constexpr uint32_t kPpb = 0xE0000000, kPpbSize = 0x100000;

constexpr uint64_t kNever = std::numeric_limits<uint64_t>::max();
constexpr uint32_t kNoException = 0;

// Cycle model (f411_emu.h).
constexpr uint32_t kBranchPenalty = 3;
// FLASH_ACR (RM0383 3.8.1): LATENCY[3:0], PRFTEN 8, ICEN 9, DCEN 10, ICRST 11, DCRST 12.
constexpr uint32_t kFlashAcrPrften = 1u << 8, kFlashAcrIcen = 1u << 9, kFlashAcrDcen = 1u << 10,
                   kFlashAcrIcrst = 1u << 11, kFlashAcrDcrst = 1u << 12;
constexpr uint32_t kExceptionEntry = 12, kExceptionReturn = 10, kTailChain = 6;
constexpr uint32_t kApb1Access = 4, kAhbAccess = 1;

enum InsnFlags : uint8_t { kInsnWfi = 1, kInsnWfe = 2, kInsnCpsie = 4 };

struct InsnInfo {
  uint8_t cycles = 1;
  uint8_t flags = 0;
  uint8_t size = 2;
};

int PopCount(uint32_t v) {
  return __builtin_popcount(v);
}

// Classifies the Thumb instruction whose first halfword is hw1 (hw2 follows it) for the cycle model.
InsnInfo Classify(uint16_t hw1, uint16_t hw2) {
  InsnInfo i;
  const uint32_t top5 = hw1 >> 11;
  if (top5 == 0x1D || top5 == 0x1E || top5 == 0x1F) {  // 32-bit
    i.size = 4;
    if ((hw1 & 0xFE00) == 0xF800) {  // load/store single (incl. PLD): +1
      i.cycles = 2;
    } else if ((hw1 & 0xFE40) == 0xE840) {  // LDRD/STRD (and LDREX/STREX family)
      i.cycles = 3;
    } else if ((hw1 & 0xFE40) == 0xE800 || (hw1 & 0xFE40) == 0xE900) {  // LDM/STM (incl. PUSH.W/POP.W)
      i.cycles = uint8_t(1 + PopCount(hw2));
    } else if ((hw1 & 0xFE00) == 0xEC00 || (hw1 & 0xFE00) == 0xEC00 + 0x200) {  // coprocessor load/store
      const uint32_t cp = (hw2 >> 8) & 0xF;
      if (cp == 0xA || cp == 0xB) {
        const uint32_t p = (hw1 >> 8) & 1, u = (hw1 >> 7) & 1, w = (hw1 >> 5) & 1;
        if (p == 1 && w == 0) {
          i.cycles = 2;  // VLDR / VSTR
        } else if (!(p == 0 && u == 0 && w == 0)) {
          const uint32_t words = hw2 & 0xFF;  // VLDM/VSTM/VPUSH/VPOP: imm8 words
          i.cycles = uint8_t(1 + std::min<uint32_t>(words, 32));
        }
      }
    } else if ((hw1 & 0xFFD0) == 0xFB90 && (hw2 & 0x00F0) == 0x00F0) {  // SDIV / UDIV
      i.cycles = 12;
    }
    return i;
  }
  if (hw1 == 0xBF30) {
    i.flags = kInsnWfi;
    return i;
  }
  if (hw1 == 0xBF20) {
    i.flags = kInsnWfe;
    return i;
  }
  if (hw1 == 0xB662) {  // CPSIE i: an interrupt held back by PRIMASK is taken right after it
    i.flags = kInsnCpsie;
    return i;
  }
  if ((hw1 & 0xF000) == 0x5000 || (hw1 & 0xE000) == 0x6000 || (hw1 & 0xF000) == 0x8000 ||
      (hw1 & 0xF000) == 0x9000 || (hw1 & 0xF800) == 0x4800) {  // LDR/STR (register, immediate, SP, literal)
    i.cycles = 2;
  } else if ((hw1 & 0xFE00) == 0xB400) {  // PUSH
    i.cycles = uint8_t(1 + PopCount(hw1 & 0x1FF));
  } else if ((hw1 & 0xFE00) == 0xBC00) {  // POP
    i.cycles = uint8_t(1 + PopCount(hw1 & 0x1FF));
  } else if ((hw1 & 0xF000) == 0xC000) {  // LDM/STM
    i.cycles = uint8_t(1 + PopCount(hw1 & 0xFF));
  }
  return i;
}

// ---- peripherals --------------------------------------------------------------------------------------

struct Gpio {
  uint32_t moder = 0, otyper = 0, ospeedr = 0, pupdr = 0, odr = 0, afr[2] = {0, 0};
  uint32_t external = 0;  // levels driven from outside
  void Reset(uint32_t m, uint32_t s, uint32_t p) {
    moder = m;
    ospeedr = s;
    pupdr = p;
    otyper = odr = afr[0] = afr[1] = 0;
  }
  uint32_t Mode(uint32_t pin) const { return (moder >> (2 * pin)) & 3u; }
  uint32_t Af(uint32_t pin) const { return (afr[pin / 8] >> (4 * (pin % 8))) & 0xFu; }
};

// A general-purpose timer (RM0383 13): upcounting, internal clock, the features the image uses. Counter
// changes happen at cycles next_tick, next_tick + (psc + 1), ...
struct Timer {
  const char* name = "";
  uint32_t width_mask = 0xFFFFFFFF;
  uint32_t cr1 = 0, cr2 = 0, dier = 0, sr = 0, ccmr[2] = {0, 0}, ccer = 0, psc = 0, psc_active = 0, arr = 0;
  uint32_t ccr[4] = {0, 0, 0, 0};
  uint32_t cnt = 0;
  uint64_t next_tick = 0;
  bool ref[4] = {false, false, false, false};  // OCxREF

  void Reset() {
    cr1 = cr2 = dier = sr = ccer = psc = psc_active = cnt = 0;
    ccmr[0] = ccmr[1] = 0;
    arr = width_mask;
    for (int c = 0; c < 4; ++c) {
      ccr[c] = 0;
      ref[c] = false;
    }
  }
  bool enabled() const { return (cr1 & 1u) != 0; }
  uint64_t period() const { return uint64_t(psc_active) + 1; }
  uint32_t ChannelField(int c) const { return (ccmr[c / 2] >> (8 * (c % 2))) & 0xFFu; }
  bool IsOutput(int c) const { return (ChannelField(c) & 3u) == 0; }
  uint32_t OcMode(int c) const { return (ChannelField(c) >> 4) & 7u; }
  bool ChannelEnabled(int c) const { return (ccer >> (4 * c)) & 1u; }
  bool OutputLevel(int c) const {
    if (!ChannelEnabled(c) || !IsOutput(c)) return false;
    return ref[c] != (((ccer >> (4 * c + 1)) & 1u) != 0);
  }
  bool Irq() const { return (sr & dier & 0x5Fu) != 0; }
  // Ticks from the counter's value now to the next value where something happens (a compare match of an
  // output channel, or the overflow).
  uint64_t TicksToEvent() const {
    const uint64_t top = uint64_t(arr) + 1;
    uint64_t best = top - cnt;  // to the overflow (cnt == arr -> 0)
    for (int c = 0; c < 4; ++c) {
      if (!IsOutput(c) || ccr[c] > arr) continue;
      uint64_t d = (uint64_t(ccr[c]) + top - cnt) % top;
      if (d == 0) d = top;
      best = std::min(best, d);
    }
    return best;
  }
  uint64_t NextEventCycle() const {
    if (!enabled()) return kNever;
    return next_tick + (TicksToEvent() - 1) * period();
  }
  // The counter's value at `cycle` >= the last sync, if no event comes in between (for timestamps).
  uint32_t CountAt(uint64_t cycle) const {
    if (!enabled() || cycle < next_tick) return cnt;
    const uint64_t ticks = (cycle - next_tick) / period() + 1;
    return uint32_t((uint64_t(cnt) + ticks) % (uint64_t(arr) + 1));
  }
};

struct SysTick {
  uint32_t ctrl = 0, load = 0;
  uint64_t zero_at = 0;  // the cycle the counter next reaches 0 (when enabled)
  uint32_t val_written = 0;
};

}  // namespace

// The flash read path with the ART accelerator (RM0383 3.4.2, FLASH_ACR bits of 3.8.1): the flash is read in
// lines of 128 bits, each read taking LATENCY wait states more than a zero-wait-state access. The model:
//   - instruction side: the CPU executes from one line at a time (the fetch buffer). Moving to another line
//     costs LATENCY cycles unless that line is the next one in sequence and prefetch is on (PRFTEN: read
//     while the current line executes; a line holds 4 to 8 instructions, at least 4 cycles, so with 3 wait
//     states a sequential read is always complete), or it is in the instruction cache (ICEN: 64 lines of
//     128 bits). A line read on a miss is copied into the cache, the least recently used line replaced
//     once the cache is full (the manual's words: "each time a miss occurs ... the line read is copied into
//     the instruction cache memory", then "the LRU policy");
//   - data side: a read of flash data (literal pools, constant tables, the vector on exception entry) costs
//     LATENCY cycles unless its line is in the data cache (DCEN: "like the instruction cache memory, but ...
//     limited to 8 rows of 128 bits");
//   - ICRST / DCRST empty the caches.
// A miss costs exactly LATENCY (the manual: "at least equal to the number of wait states"); a data read
// that stalls an instruction read (D-Code has priority over I-Code) is not modelled beyond that.
struct Art {
  static constexpr uint32_t kNone = ~0u;
  uint32_t current = kNone;              // the line the CPU executes from
  std::vector<uint32_t> icache, dcache;  // lines, most recently used first
  uint64_t i_misses = 0, d_misses = 0, stall_cycles = 0;

  static bool Touch(std::vector<uint32_t>* cache, uint32_t line) {
    for (size_t i = 0; i < cache->size(); ++i) {
      if ((*cache)[i] == line) {
        std::rotate(cache->begin(), cache->begin() + static_cast<std::ptrdiff_t>(i),
                    cache->begin() + static_cast<std::ptrdiff_t>(i) + 1);
        return true;
      }
    }
    return false;
  }
  static void Insert(std::vector<uint32_t>* cache, uint32_t line, size_t lines) {
    cache->insert(cache->begin(), line);
    if (cache->size() > lines) cache->pop_back();
  }
  // Cycles the fetch of an instruction at `address` waits for the flash.
  uint32_t Fetch(uint32_t address, uint32_t acr) {
    const uint32_t line = address >> 4;
    if (line == current) return 0;
    const bool sequential = current != kNone && line == current + 1;
    current = line;
    if (sequential && (acr & kFlashAcrPrften)) return 0;
    if ((acr & kFlashAcrIcen) && Touch(&icache, line)) return 0;
    if (acr & kFlashAcrIcen) Insert(&icache, line, 64);
    ++i_misses;
    stall_cycles += acr & 0xFu;
    return acr & 0xFu;
  }
  // Cycles a data read of flash at `address` waits.
  uint32_t Read(uint32_t address, uint32_t acr) {
    const uint32_t line = address >> 4;
    if ((acr & kFlashAcrDcen) && Touch(&dcache, line)) return 0;
    if (acr & kFlashAcrDcen) Insert(&dcache, line, 8);
    ++d_misses;
    stall_cycles += acr & 0xFu;
    return acr & 0xFu;
  }
  void Write(uint32_t acr) {
    if (acr & kFlashAcrIcrst) icache.clear();
    if (acr & kFlashAcrDcrst) dcache.clear();
  }
};

struct F411Emu::Impl {
  F411Emu* self = nullptr;
  EmuOptions options;
  ElfImage image;
  uc_engine* uc = nullptr;
  std::vector<uint8_t> flash;
  std::vector<InsnInfo> insn;  // per flash halfword
  std::string error;

  uint64_t cycles = 0, instructions = 0, sleep_cycles = 0, wfi_count = 0, resets = 0;
  uint64_t stop_at = kNever;
  uint32_t last_pc = 0;
  uint32_t expect_pc = 0;  // the address after the last instruction (0: after a jump made by the harness)
  bool want_wfi = false;   // stopped at a WFI
  uint32_t wfi_pc = 0;
  bool sleeping = false;
  bool want_return = false;  // stopped at an EXC_RETURN address
  uint32_t exc_return = 0;

  // RCC, flash interface, PWR.
  uint32_t rcc_cr = 0, rcc_pllcfgr = 0, rcc_cfgr = 0, rcc_ahb1enr = 0, rcc_ahb2enr = 0, rcc_apb1enr = 0,
           rcc_apb2enr = 0, rcc_csr = 0;
  uint32_t flash_acr = 0, pwr_cr = 0;
  uint32_t sysclk = 16000000, usb_clk = 0;
  Art art;
  std::array<Gpio, 3> gpio;
  Timer tim2, tim3;
  SysTick systick;
  // Input capture filter: the capture happens this many cycles after the edge (ICxF, N samples at fCK_INT).
  struct PendingCapture {
    uint64_t at;
    int channel;
    bool level;
  };
  std::vector<PendingCapture> captures;
  struct CameraEvent {
    uint64_t at;
    bool level;
  };
  std::vector<CameraEvent> camera_queue;
  std::vector<PinEdge> camera_edges;
  std::vector<PinEdge> capture_log;  // what TIM2's channel 3 latched, and when

  // System control.
  uint32_t nvic_iser[3] = {0, 0, 0}, nvic_ispr[3] = {0, 0, 0};
  uint8_t nvic_ipr[96] = {};
  uint32_t vtor = 0, scr = 0, ccr_scb = 0, shpr[3] = {0, 0, 0}, shcsr = 0, cpacr = 0, demcr = 0, aircr = 0;
  uint32_t dwt_ctrl = 0;
  uint32_t dwt_base = 0;  // CYCCNT = cycles - dwt_base when enabled
  uint32_t dwt_frozen = 0;
  bool systick_pending = false;

  struct Active {
    uint32_t exception;
    int priority;
    uint64_t entered;    // cycle of entry
    uint64_t preempted;  // cycles spent in exceptions nested in this one
    uint32_t sp_after;   // SP with the frame pushed
    bool fp_frame;
    bool dwt_seen = false;
    uint32_t dwt_first = 0, dwt_last = 0;
  };
  std::vector<Active> active;
  std::array<ExceptionStats, kExceptionCount> stats{};

  std::vector<PinEdge> edges;
  uint64_t pin_levels = 0;  // bit (port * 16 + pin)
  bool started = false;

  // ---- errors ----

  std::string Where() const {
    char buf[96];
    uint16_t hw[2] = {0, 0};
    if (last_pc >= kFlashBase && last_pc + 4 <= kFlashBase + flash.size()) {
      std::memcpy(hw, &flash[last_pc - kFlashBase], 4);
    }
    const bool wide = last_pc >= kFlashBase && insn.size() > (last_pc - kFlashBase) / 2 &&
                      insn[(last_pc - kFlashBase) / 2].size == 4;
    if (wide) {
      std::snprintf(buf, sizeof(buf), " at pc 0x%08" PRIx32 " (instruction %04x %04x)", last_pc, hw[0],
                    hw[1]);
    } else {
      std::snprintf(buf, sizeof(buf), " at pc 0x%08" PRIx32 " (instruction %04x)", last_pc, hw[0]);
    }
    return buf;
  }
  void Fail(const std::string& what) {
    if (!error.empty()) return;
    char c[48];
    std::snprintf(c, sizeof(c), " [cycle %" PRIu64 "]", cycles);
    error = what + Where() + c;
    if (uc) uc_emu_stop(uc);
  }
  void FailAt(const char* what, uint32_t address, unsigned size) {
    char buf[160];
    std::snprintf(buf, sizeof(buf), "%s 0x%08" PRIx32 " (%u bytes)", what, address, size);
    Fail(buf);
  }

  // ---- clocks ----

  uint32_t PllInputHz() const { return (rcc_pllcfgr & (1u << 22)) ? 25000000u : 16000000u; }
  uint32_t Ppre(uint32_t field) const {  // APB prescaler from a 3-bit PPRE field
    return field < 4 ? 1u : 2u << (field - 4);
  }
  uint32_t HpreDiv() const {
    const uint32_t f = (rcc_cfgr >> 4) & 0xFu;
    if (f < 8) return 1;
    static const uint32_t d[8] = {2, 4, 8, 16, 64, 128, 256, 512};
    return d[f - 8];
  }
  uint32_t Apb1Hz() const { return sysclk / HpreDiv() / Ppre((rcc_cfgr >> 10) & 7u); }
  uint32_t TimerClockHz() const {
    const uint32_t p = Ppre((rcc_cfgr >> 10) & 7u);
    return p == 1 ? Apb1Hz() : 2 * Apb1Hz();
  }

  void CheckPll() {
    const uint32_t m = rcc_pllcfgr & 0x3Fu, n = (rcc_pllcfgr >> 6) & 0x1FFu;
    const uint32_t p = 2 * (((rcc_pllcfgr >> 16) & 3u) + 1), q = (rcc_pllcfgr >> 24) & 0xFu;
    char buf[160];
    if (m < 2 || n < 50 || n > 432 || q < 2) {
      std::snprintf(buf, sizeof(buf), "PLL switched on with PLLM %u, PLLN %u, PLLQ %u (RM0383 6.3.2)", m, n,
                    q);
      Fail(buf);
      return;
    }
    const uint32_t in = PllInputHz() / m;
    const uint64_t vco = uint64_t(in) * n;
    if (in < 950000 || in > 2100000 || vco < 100000000 || vco > 432000000 || vco / p > 100000000) {
      std::snprintf(buf, sizeof(buf), "PLL out of range: input %u Hz, VCO %" PRIu64 " Hz (RM0383 6.3.2)", in,
                    vco);
      Fail(buf);
    }
  }
  uint32_t PllP() const {
    const uint32_t m = rcc_pllcfgr & 0x3Fu, n = (rcc_pllcfgr >> 6) & 0x1FFu;
    const uint32_t p = 2 * (((rcc_pllcfgr >> 16) & 3u) + 1);
    return m ? uint32_t(uint64_t(PllInputHz()) / m * n / p) : 0;
  }
  uint32_t PllQ() const {
    const uint32_t m = rcc_pllcfgr & 0x3Fu, n = (rcc_pllcfgr >> 6) & 0x1FFu, q = (rcc_pllcfgr >> 24) & 0xFu;
    return m && q ? uint32_t(uint64_t(PllInputHz()) / m * n / q) : 0;
  }
  void SwitchSysclk() {
    const uint32_t sw = rcc_cfgr & 3u;
    uint32_t hz = 0;
    if (sw == 0) hz = 16000000;
    if (sw == 1) hz = (rcc_cr & (1u << 17)) ? 25000000 : 0;
    if (sw == 2) hz = (rcc_cr & (1u << 25)) ? PllP() : 0;
    if (sw == 3) {
      Fail("SYSCLK switch to an invalid source (SW = 11)");
      return;
    }
    if (hz == 0) return;  // the source is not ready: SWS stays
    // RM0383 3.4.1 table 5 (2.7-3.6 V): wait states needed for HCLK.
    const uint32_t hclk = hz / HpreDiv();
    const uint32_t ws_needed = hclk <= 30000000 ? 0 : hclk <= 64000000 ? 1 : hclk <= 90000000 ? 2 : 3;
    char buf[160];
    if ((flash_acr & 0xFu) < ws_needed) {
      std::snprintf(buf, sizeof(buf), "HCLK %u Hz with %u flash wait states (RM0383 table 5 needs %u)", hclk,
                    flash_acr & 0xFu, ws_needed);
      Fail(buf);
      return;
    }
    if (hclk > 84000000 && ((pwr_cr >> 14) & 3u) != 3u) {
      std::snprintf(buf, sizeof(buf), "HCLK %u Hz above 84 MHz without voltage scale 1 (PWR_CR.VOS = %u)",
                    hclk, (pwr_cr >> 14) & 3u);
      Fail(buf);
      return;
    }
    if (hclk / Ppre((rcc_cfgr >> 10) & 7u) > 50000000) {
      Fail("APB1 above 50 MHz (RM0383 6.2)");
      return;
    }
    sysclk = hz;
    rcc_cfgr = (rcc_cfgr & ~(3u << 2)) | (sw << 2);
    usb_clk = (rcc_cr & (1u << 25)) ? PllQ() : 0;
  }

  // ---- pins ----

  bool ComputeLevel(uint8_t port, uint8_t pin) const {
    const Gpio& g = gpio[port];
    switch (g.Mode(pin)) {
      case 1: return (g.odr >> pin) & 1u;
      case 2: {
        const uint32_t af = g.Af(pin);
        if (port == kPortA && pin == 15 && af == 1) return tim2.OutputLevel(0);  // TIM2_CH1
        if (port == kPortB && pin == 4 && af == 2) return tim3.OutputLevel(0);   // TIM3_CH1
        return (g.external >> pin) & 1u;  // an input function (TIM2_CH3 on PB10, USB, JTAG): the outside
      }
      default: return (g.external >> pin) & 1u;
    }
  }
  // Records every pin whose level changed, as of `cycle`.
  void UpdatePins(uint64_t cycle) {
    for (uint8_t port = 0; port < 3; ++port) {
      for (uint8_t pin = 0; pin < 16; ++pin) {
        const uint64_t bit = 1ull << (port * 16 + pin);
        const bool level = ComputeLevel(port, pin);
        if (level != ((pin_levels & bit) != 0)) {
          pin_levels ^= bit;
          if (started) edges.push_back(PinEdge{cycle, tim2.CountAt(cycle), port, pin, level});
          if (port == kPortA && pin == 15 && level && options.camera.enabled) {
            const uint64_t us = sysclk / 1000000u;
            camera_queue.push_back({cycle + uint64_t(options.camera.latency_us) * us, true});
            camera_queue.push_back(
                {cycle + uint64_t(options.camera.latency_us + options.camera.exposure_us) * us, false});
          }
        }
      }
    }
  }
  // An external edge on an input pin: TIM2_CH3 (PB10, AF1) captures it after the input filter's delay.
  void ExternalEdge(uint8_t port, uint8_t pin, bool level, uint64_t cycle) {
    Gpio& g = gpio[port];
    if (((g.external >> pin) & 1u) == uint32_t(level)) return;
    g.external ^= 1u << pin;
    if (port == kPortB && pin == 10 && g.Mode(10) == 2 && g.Af(10) == 1 && !tim2.IsOutput(2) &&
        tim2.ChannelEnabled(2)) {
      const uint32_t field = tim2.ChannelField(2);
      const uint32_t filter = (field >> 4) & 0xFu;
      static const uint32_t kSamples[4] = {1, 2, 4, 8};  // ICxF 0..3: N at fCK_INT (RM0383 13.4.8)
      if (filter > 3) {
        Fail("TIM2 input capture filter beyond fCK_INT sampling is not modelled");
        return;
      }
      const uint32_t ccer = tim2.ccer >> 8;  // channel 3's CC3P (bit 1) and CC3NP (bit 3)
      const bool both = (ccer & 2u) && (ccer & 8u);
      const bool falling = (ccer & 2u) && !(ccer & 8u);
      if (both || (falling && !level) || (!falling && !(ccer & 8u) && level)) {
        captures.push_back({cycle + kSamples[filter], 2, level});
      }
    }
    UpdatePins(cycle);
  }

  // ---- timers ----

  void TimerEvent(Timer& t, uint64_t at) {
    // The counter has just taken the value t.cnt at cycle `at`.
    for (int c = 0; c < 4; ++c) {
      if (!t.IsOutput(c) || t.cnt != t.ccr[c]) continue;
      t.sr |= 1u << (c + 1);
      switch (t.OcMode(c)) {
        case 1: t.ref[c] = true; break;
        case 2: t.ref[c] = false; break;
        case 3: t.ref[c] = !t.ref[c]; break;
        default: break;
      }
    }
    UpdatePins(at);
  }
  void SyncTimer(Timer& t, uint64_t now) {
    if (!t.enabled()) return;
    while (t.next_tick <= now) {
      const uint64_t period = t.period();
      const uint64_t available = (now - t.next_tick) / period + 1;
      const uint64_t n = std::min(available, t.TicksToEvent());
      const uint64_t at = t.next_tick + (n - 1) * period;
      const uint64_t top = uint64_t(t.arr) + 1;
      const uint64_t value = uint64_t(t.cnt) + n;
      t.next_tick = at + period;
      if (value >= top) {  // overflow: update event
        t.cnt = uint32_t(value % top);
        t.psc_active = t.psc;
        if (!(t.cr1 & 2u)) t.sr |= 1u;  // UIF unless UDIS
      } else {
        t.cnt = uint32_t(value);
      }
      TimerEvent(t, at);
    }
  }
  void SyncSysTick(uint64_t now) {
    SysTick& s = systick;
    if (!(s.ctrl & 1u) || s.load == 0) return;
    const uint64_t period = (uint64_t(s.load) + 1) * ((s.ctrl & 4u) ? 1 : 8);
    while (s.zero_at <= now) {
      s.ctrl |= 1u << 16;  // COUNTFLAG
      if (s.ctrl & 2u) systick_pending = true;
      s.zero_at += period;
    }
  }
  void Sync(uint64_t now) {
    SyncTimer(tim2, now);
    SyncTimer(tim3, now);
    SyncSysTick(now);
    for (size_t i = 0; i < captures.size();) {
      if (captures[i].at > now) {
        ++i;
        continue;
      }
      const PendingCapture c = captures[i];
      captures.erase(captures.begin() + long(i));
      SyncTimer(tim2, c.at);
      const uint32_t flag = 1u << (c.channel + 1);
      if (tim2.sr & flag) tim2.sr |= 1u << (c.channel + 9);  // overcapture
      tim2.ccr[c.channel] = tim2.CountAt(c.at);
      tim2.sr |= flag;
      capture_log.push_back(PinEdge{c.at, tim2.ccr[c.channel], kPortB, 10, c.level});
    }
    for (size_t i = 0; i < camera_queue.size();) {
      if (camera_queue[i].at > now) {
        ++i;
        continue;
      }
      const CameraEvent e = camera_queue[i];
      camera_queue.erase(camera_queue.begin() + long(i));
      camera_edges.push_back(PinEdge{e.at, tim2.CountAt(e.at), kPortB, 10, e.level});
      ExternalEdge(kPortB, 10, e.level, e.at);
    }
  }
  uint64_t NextEvent() const {
    uint64_t next = std::min(tim2.NextEventCycle(), tim3.NextEventCycle());
    if ((systick.ctrl & 1u) && systick.load != 0) next = std::min(next, systick.zero_at);
    for (const auto& c : captures) next = std::min(next, c.at);
    for (const auto& e : camera_queue) next = std::min(next, e.at);
    return next;
  }

  // ---- exceptions ----

  int Priority(uint32_t exception) const {
    if (exception == 2) return -2;
    if (exception == 3) return -1;
    if (exception >= 16) return nvic_ipr[exception - 16] >> 4;
    if (exception >= 4) return ((shpr[(exception - 4) / 4] >> (8 * (exception % 4))) & 0xFFu) >> 4;
    return 256;
  }
  int CurrentPriority() const { return active.empty() ? 256 : active.back().priority; }
  bool Enabled(uint32_t irq) const { return (nvic_iser[irq / 32] >> (irq % 32)) & 1u; }
  bool IrqLine(uint32_t irq) const {
    switch (irq) {
      case kTim2Irq: return tim2.Irq();
      case kTim3Irq: return tim3.Irq();
      case kOtgFsIrq: return (rcc_ahb2enr & (1u << 7)) && usb_model && dwc2_model_irq(usb_model);
      default: return false;
    }
  }
  bool IsActive(uint32_t exception) const {
    for (const auto& a : active) {
      if (a.exception == exception) return true;
    }
    return false;
  }
  void LatchLines() {
    for (uint32_t irq : {kTim2Irq, kTim3Irq, kOtgFsIrq}) {
      if (IrqLine(irq) && !IsActive(16 + irq)) nvic_ispr[irq / 32] |= 1u << (irq % 32);
    }
  }
  // The pending exception that would be taken now (ignoring PRIMASK), or kNoException.
  uint32_t BestPending() const {
    uint32_t best = kNoException;
    int best_prio = CurrentPriority();
    if (systick_pending && Priority(kSysTickException) < best_prio) {
      best = kSysTickException;
      best_prio = Priority(kSysTickException);
    }
    for (uint32_t irq = 0; irq < kIrqCount; ++irq) {
      if (!((nvic_ispr[irq / 32] >> (irq % 32)) & 1u) || !Enabled(irq)) continue;
      if (Priority(16 + irq) < best_prio) {
        best = 16 + irq;
        best_prio = Priority(16 + irq);
      }
    }
    return best;
  }

  uint32_t Reg(int r) {
    uint32_t v = 0;
    uc_reg_read(uc, r, &v);
    return v;
  }
  void SetReg(int r, uint32_t v) { uc_reg_write(uc, r, &v); }
  uint32_t ReadWord(uint32_t address) {
    uint32_t v = 0;
    if (uc_mem_read(uc, address, &v, 4) != UC_ERR_OK) FailAt("exception frame outside RAM:", address, 4);
    return v;
  }
  void WriteWord(uint32_t address, uint32_t v) {
    if (uc_mem_write(uc, address, &v, 4) != UC_ERR_OK) FailAt("exception frame outside RAM:", address, 4);
  }

  // IPSR as the image reads it (MRS IPSR: the fault handler records the vector from it).
  void SetIpsr(uint32_t exception) {
    const uint32_t xpsr = Reg(UC_ARM_REG_XPSR);
    SetReg(UC_ARM_REG_XPSR, (xpsr & ~0x1FFu) | (exception & 0x1FFu));
  }

  // Takes `exception`: pushes the frame, or with `chain` (tail-chaining from the handler returning with the
  // EXC_RETURN `chain_return`) keeps the frame that handler's entry pushed.
  void Enter(uint32_t exception, const Active* chain = nullptr, uint32_t chain_return = 0) {
    const uint32_t vector = ReadWord(vtor + 4 * exception);
    const uint32_t hardfault = image.Symbol("HardFault_Handler", 1) & ~1u;
    char buf[160];
    if ((vector & ~1u) == hardfault && exception != 3 && options.stop_on_unhandled_interrupt) {
      std::snprintf(buf, sizeof(buf), "unhandled interrupt: exception %u (IRQ %d) has the default handler",
                    exception, int(exception) - 16);
      Fail(buf);
      return;
    }
    if (exception == 3) {
      Fail("HardFault taken");
      return;
    }
    if (!(vector & 1u) || vector < kFlashBase || vector >= kFlashBase + flash.size()) {
      std::snprintf(buf, sizeof(buf), "exception %u: vector 0x%08x is not Thumb code in flash", exception,
                    vector);
      Fail(buf);
      return;
    }
    if (Reg(UC_ARM_REG_CONTROL) & 2u) {
      Fail("exception taken on the process stack (CONTROL.SPSEL): not modelled");
      return;
    }
    bool fp = false;
    uint32_t sp = 0;
    if (chain != nullptr) {
      SetReg(UC_ARM_REG_LR, chain_return);
      if (chain->fp_frame) SetReg(UC_ARM_REG_CONTROL, Reg(UC_ARM_REG_CONTROL) & ~4u);
    } else {
      fp = (Reg(UC_ARM_REG_CONTROL) & 4u) != 0;  // FPCA: an extended frame is reserved
      sp = Reg(UC_ARM_REG_SP);
      uint32_t xpsr = Reg(UC_ARM_REG_XPSR);
      const uint32_t frame = fp ? 26 * 4 : 8 * 4;
      if ((sp - frame) & 4u)
        xpsr |= 1u << 9;  // the frame is aligned to 8 bytes; bit 9 says it was
      else
        xpsr &= ~(1u << 9);
      sp = ((sp - frame) & ~7u);
      const uint32_t regs[8] = {
          Reg(UC_ARM_REG_R0),  Reg(UC_ARM_REG_R1), Reg(UC_ARM_REG_R2), Reg(UC_ARM_REG_R3),
          Reg(UC_ARM_REG_R12), Reg(UC_ARM_REG_LR), Reg(UC_ARM_REG_PC), xpsr};
      for (int i = 0; i < 8; ++i) WriteWord(sp + 4 * i, regs[i]);
      SetReg(UC_ARM_REG_SP, sp);
      SetReg(UC_ARM_REG_LR, fp ? 0xFFFFFFE9u : 0xFFFFFFF9u);
      if (fp) SetReg(UC_ARM_REG_CONTROL, Reg(UC_ARM_REG_CONTROL) & ~4u);
    }
    SetReg(UC_ARM_REG_PC, vector & ~1u);
    SetIpsr(exception);
    if (exception == kSysTickException) {
      systick_pending = false;
    } else {
      nvic_ispr[(exception - 16) / 32] &= ~(1u << ((exception - 16) % 32));
    }
    const uint64_t entered = cycles;
    cycles += chain != nullptr ? kTailChain : kExceptionEntry;
    if (options.flash_wait_states) cycles += art.Read(vtor + 4 * exception, flash_acr);
    if (chain != nullptr) sp = chain->sp_after, fp = chain->fp_frame;
    active.push_back(Active{exception, Priority(exception), entered, 0, sp, fp});
    expect_pc = 0;
  }

  void Return(uint32_t value) {
    if (active.empty()) {
      Fail("EXC_RETURN in thread mode");
      return;
    }
    Active a = active.back();
    if ((value & 0xFFFFFF00u) != 0xFFFFFF00u || (value & 0xFu) != 9u ||
        (((value >> 4) & 1u) == 0) != a.fp_frame) {
      char buf[96];
      std::snprintf(buf, sizeof(buf), "unexpected EXC_RETURN 0x%08x", value);
      Fail(buf);
      return;
    }
    uint32_t sp = Reg(UC_ARM_REG_SP);
    if (sp != a.sp_after) {
      char buf[128];
      std::snprintf(buf, sizeof(buf), "exception return with SP 0x%08x, frame at 0x%08x", sp, a.sp_after);
      Fail(buf);
      return;
    }
    if (options.tail_chaining && TailChain(a, value)) return;
    uint32_t regs[8];
    for (int i = 0; i < 8; ++i) regs[i] = ReadWord(sp + 4 * i);
    SetReg(UC_ARM_REG_R0, regs[0]);
    SetReg(UC_ARM_REG_R1, regs[1]);
    SetReg(UC_ARM_REG_R2, regs[2]);
    SetReg(UC_ARM_REG_R3, regs[3]);
    SetReg(UC_ARM_REG_R12, regs[4]);
    SetReg(UC_ARM_REG_LR, regs[5]);
    const uint32_t frame = a.fp_frame ? 26 * 4 : 8 * 4;
    sp += frame;
    if (regs[7] & (1u << 9)) sp += 4;
    SetReg(UC_ARM_REG_SP, sp);
    if (a.fp_frame) SetReg(UC_ARM_REG_CONTROL, Reg(UC_ARM_REG_CONTROL) | 4u);
    SetReg(UC_ARM_REG_XPSR, regs[7] & ~(0x1FFu | (1u << 9)));
    SetReg(UC_ARM_REG_PC, regs[6] & ~1u);
    cycles += kExceptionReturn;
    active.pop_back();
    SetIpsr(active.empty() ? 0u : active.back().exception);
    Finished(a);
    expect_pc = 0;
  }

  // The record of a handler's run, from its entry to now.
  void Finished(const Active& a) {
    const uint64_t spent = cycles - a.entered;
    ExceptionStats& s = stats[a.exception];
    ++s.runs;
    s.total_cycles += spent - a.preempted;
    s.max_cycles = std::max(s.max_cycles, spent - a.preempted);
    if (a.dwt_seen) s.max_dwt_window = std::max<uint64_t>(s.max_dwt_window, a.dwt_last - a.dwt_first);
    if (!active.empty()) active.back().preempted += spent;
  }

  // Tail-chaining (Cortex-M4: a pending exception that would preempt the context being returned to is taken
  // at the return, without popping the frame and pushing it again: 6 cycles instead of 10 + 12). The
  // returning handler's run ends at its return; the chained one's starts with the 6 cycles. false when
  // nothing is to be taken, and the return goes on.
  bool TailChain(const Active& a, uint32_t value) {
    Sync(cycles);
    LatchLines();
    active.pop_back();
    const uint32_t next = BestPending();
    if (next == kNoException || (Reg(UC_ARM_REG_PRIMASK) & 1u)) {
      active.push_back(a);
      return false;
    }
    Finished(a);
    ++tail_chains;
    Enter(next, &a, value);
    return true;
  }

  // ---- system reset (AIRCR.SYSRESETREQ): RAM kept, core and peripherals reset ----

  void ResetPeripherals() {
    rcc_cr = 0x00000083;
    rcc_pllcfgr = 0x24003010;
    rcc_cfgr = rcc_ahb1enr = rcc_ahb2enr = rcc_apb1enr = rcc_apb2enr = 0;
    flash_acr = 0;
    art = Art{};
    pwr_cr = 0x00008000;
    sysclk = 16000000;
    usb_clk = 0;
    gpio[0].Reset(0xA8000000, 0x0C000000, 0x64000000);
    gpio[1].Reset(0x00000280, 0x000000C0, 0x00000100);
    gpio[2].Reset(0, 0, 0);
    tim2.Reset();
    tim3.Reset();
    captures.clear();
    systick = SysTick{};
    systick_pending = false;
    std::memset(nvic_iser, 0, sizeof(nvic_iser));
    std::memset(nvic_ispr, 0, sizeof(nvic_ispr));
    std::memset(nvic_ipr, 0, sizeof(nvic_ipr));
    vtor = scr = ccr_scb = shcsr = cpacr = demcr = aircr = dwt_ctrl = 0;
    shpr[0] = shpr[1] = shpr[2] = 0;
    active.clear();
    if (usb_model) dwc2_model_destroy(usb_model);
    usb_model = dwc2_model_create();
    sleeping = false;
  }
  void CoreReset() {
    ResetPeripherals();
    const uint32_t sp = ReadWord(0), pc = ReadWord(4);
    for (int r = UC_ARM_REG_R0; r <= UC_ARM_REG_R12; ++r) SetReg(r, 0);
    SetReg(UC_ARM_REG_CONTROL, 0);
    SetReg(UC_ARM_REG_PRIMASK, 0);
    SetReg(UC_ARM_REG_MSP, sp);
    SetReg(UC_ARM_REG_SP, sp);
    SetReg(UC_ARM_REG_LR, 0xFFFFFFFFu);
    SetReg(UC_ARM_REG_XPSR, 1u << 24);
    SetReg(UC_ARM_REG_PC, pc & ~1u);
    expect_pc = 0;
    UpdatePins(cycles);
  }

  dwc2_model_t* usb_model = nullptr;

  // ---- MMIO ----

  uint32_t Cyccnt() const {
    if (!(demcr & (1u << 24)) || !(dwt_ctrl & 1u)) return dwt_frozen;
    return uint32_t(cycles) - dwt_base;
  }

  // An MMIO window: unicorn hands its callbacks offsets from the window's base.
  struct Window {
    Impl* e;
    uint32_t base;
  };
  std::vector<std::unique_ptr<Window>> windows;
  static uint64_t MmioRead(uc_engine*, uint64_t offset, unsigned size, void* user) {
    const Window* w = static_cast<Window*>(user);
    return w->e->Access(w->base + uint32_t(offset), size, false, 0);
  }
  static void MmioWrite(uc_engine*, uint64_t offset, unsigned size, uint64_t value, void* user) {
    const Window* w = static_cast<Window*>(user);
    w->e->Access(w->base + uint32_t(offset), size, true, uint32_t(value));
  }
  uc_err MapWindow(uint32_t base, uint32_t size) {
    windows.push_back(std::make_unique<Window>(Window{this, base}));
    Window* w = windows.back().get();
    return uc_mmio_map(uc, base, size, &MmioRead, w, &MmioWrite, w);
  }

  // One access by the CPU. Sub-word accesses are allowed where the hardware has byte registers (NVIC_IPR,
  // SHPR) and for GPIO BSRR halves; anywhere else they stop the run.
  uint32_t Access(uint32_t address, unsigned size, bool write, uint32_t value) {
    if (!error.empty()) return 0;
    if (address >= 0x40000000 && address < 0x40010000)
      cycles += kApb1Access;
    else if (address < kPpb)
      cycles += kAhbAccess;
    Sync(cycles);
    const uint32_t word = address & ~3u;
    const unsigned shift = 8 * (address & 3u);
    const bool byte_ok =
        (address >= 0xE000E400 && address < 0xE000E460) || (address >= 0xE000ED18 && address < 0xE000ED24);
    const bool bsrr = (word == kGpioA + 0x18 || word == kGpioB + 0x18 || word == kGpioC + 0x18) && size == 2;
    if (size != 4 && !byte_ok && !bsrr) {
      FailAt(write ? "sub-word write to register" : "sub-word read of register", address, size);
      return 0;
    }
    if (size != 4) {
      if (write) {
        if (bsrr) {
          WriteReg(word, (value & 0xFFFFu) << shift);
          AfterWrite();
          return 0;
        }
        const uint32_t mask = (size == 1 ? 0xFFu : 0xFFFFu) << shift;
        const uint32_t old = ReadReg(word, true);
        WriteReg(word, (old & ~mask) | ((value << shift) & mask));
        AfterWrite();
        return 0;
      }
      return (ReadReg(word, false) >> shift) & (size == 1 ? 0xFFu : 0xFFFFu);
    }
    if (write) {
      WriteReg(address, value);
      AfterWrite();
      return 0;
    }
    return ReadReg(address, false);
  }
  // A write may have made an interrupt pending that preempts the code running now: stop before the next
  // instruction so that Step takes it.
  // It may also have started a timer or moved its next event closer than the run's stop.
  void AfterWrite() {
    LatchLines();
    if (BestPending() != kNoException) stop_at = 0;
    stop_at = std::min(stop_at, NextEvent());
  }

  bool ClockOn(uint32_t address, bool quiet) {
    bool on = true;
    const char* what = nullptr;
    if (address >= kTim2 && address < kTim2 + 0x400)
      on = rcc_apb1enr & 1u, what = "TIM2";
    else if (address >= kTim3 && address < kTim3 + 0x400)
      on = rcc_apb1enr & 2u, what = "TIM3";
    else if (address >= kPwr && address < kPwr + 0x400)
      on = rcc_apb1enr & (1u << 28), what = "PWR";
    else if (address >= kGpioA && address < kGpioC + 0x400) {
      const uint32_t port = (address - kGpioA) / 0x400;
      on = (rcc_ahb1enr >> port) & 1u;
      what = "a GPIO port";
    } else if (address >= kOtgFs && address < kOtgFs + kOtgFsSize) {
      on = rcc_ahb2enr & (1u << 7), what = "OTG_FS";
    }
    if (!on && !quiet) {
      char buf[96];
      std::snprintf(buf, sizeof(buf), "%s accessed with its clock off (RCC enable bit clear):", what);
      FailAt(buf, address, 4);
    }
    return on;
  }

  Timer* TimerAt(uint32_t address) {
    if (address >= kTim2 && address < kTim2 + 0x400) return &tim2;
    if (address >= kTim3 && address < kTim3 + 0x400) return &tim3;
    return nullptr;
  }
  Gpio* GpioAt(uint32_t address, uint8_t* port) {
    if (address < kGpioA || address >= kGpioC + 0x400) return nullptr;
    *port = uint8_t((address - kGpioA) / 0x400);
    return &gpio[*port];
  }

  uint32_t ReadReg(uint32_t a, bool peek) {
    if (!ClockOn(a, peek)) return 0;
    if (Timer* t = TimerAt(a)) {
      switch (a & 0x3FFu) {
        case 0x00: return t->cr1;
        case 0x04: return t->cr2;
        case 0x08: return 0;  // SMCR
        case 0x0C: return t->dier;
        case 0x10: return t->sr;
        case 0x14: return 0;
        case 0x18: return t->ccmr[0];
        case 0x1C: return t->ccmr[1];
        case 0x20: return t->ccer;
        case 0x24: return t->cnt;
        case 0x28: return t->psc;
        case 0x2C: return t->arr;
        case 0x34:
        case 0x38:
        case 0x3C:
        case 0x40: {
          const int c = int((a & 0x3FFu) - 0x34) / 4;
          if (!t->IsOutput(c) && !peek) t->sr &= ~(1u << (c + 1));  // reading a capture clears CCxIF
          return t->ccr[c];
        }
        default: break;
      }
    }
    uint8_t port = 0;
    if (Gpio* g = GpioAt(a, &port)) {
      switch (a & 0x3FFu) {
        case 0x00: return g->moder;
        case 0x04: return g->otyper;
        case 0x08: return g->ospeedr;
        case 0x0C: return g->pupdr;
        case 0x10: {
          uint32_t idr = 0;
          for (uint8_t pin = 0; pin < 16; ++pin) idr |= uint32_t(ComputeLevel(port, pin)) << pin;
          return idr;
        }
        case 0x14: return g->odr;
        case 0x18: return 0;
        case 0x20: return g->afr[0];
        case 0x24: return g->afr[1];
        default: break;
      }
    }
    if (a >= kOtgFs && a < kOtgFs + kOtgFsSize) {
      if (a - kOtgFs < DWC2_WINDOW_SIZE_BYTES) {
        if (peek && a - kOtgFs >= 0x1000) return 0;  // a FIFO read pops: not for a peek
        if (peek && a - kOtgFs == 0x20) return 0;    // GRXSTSP pops
        return dwc2_model_read(usb_model, a - kOtgFs);
      }
    }
    switch (a) {
      case kRcc + 0x00: return rcc_cr;
      case kRcc + 0x04: return rcc_pllcfgr;
      case kRcc + 0x08: return rcc_cfgr;
      case kRcc + 0x30: return rcc_ahb1enr;
      case kRcc + 0x34: return rcc_ahb2enr;
      case kRcc + 0x40: return rcc_apb1enr;
      case kRcc + 0x44: return rcc_apb2enr;
      case kRcc + 0x74: return rcc_csr;
      case kFlashIf + 0x00: return flash_acr;
      case kPwr + 0x00: return pwr_cr;
      case kPwr + 0x04: return ((pwr_cr >> 14) & 3u) ? 1u << 14 : 0u;  // VOSRDY
      case 0xE000E004: return 2;                                       // ICTR: 96 interrupt lines
      case 0xE000E010: {
        const uint32_t v = systick.ctrl;
        if (!peek) systick.ctrl &= ~(1u << 16);  // COUNTFLAG clears on read
        return v;
      }
      case 0xE000E014: return systick.load;
      case 0xE000E018: {
        if (!(systick.ctrl & 1u)) return systick.val_written;
        const uint64_t div = (systick.ctrl & 4u) ? 1 : 8;
        return uint32_t((systick.zero_at - cycles) / div) % (systick.load + 1);
      }
      case 0xE000E01C: return 0x40000000u | (96000000u / 8u / 100u - 1u);  // CALIB: no reference clock, 10 ms
      case 0xE000ED00: return 0x410FC241;                                  // CPUID: Cortex-M4 r0p1
      case 0xE000ED04: return active.empty() ? 0u : active.back().exception;  // ICSR.VECTACTIVE
      case 0xE000ED08: return vtor;
      case 0xE000ED0C: return 0xFA050000u | (aircr & 0x700u);
      case 0xE000ED10: return scr;
      case 0xE000ED14: return ccr_scb;
      case 0xE000ED18: return shpr[0];
      case 0xE000ED1C: return shpr[1];
      case 0xE000ED20: return shpr[2];
      case 0xE000ED24: return shcsr;
      case 0xE000ED28:  // CFSR, HFSR, MMFAR, BFAR: no fault has been modelled
      case 0xE000ED2C:
      case 0xE000ED34:
      case 0xE000ED38: return 0;
      case 0xE000ED88: return cpacr;
      case 0xE000EDFC: return demcr;
      case 0xE0001000: return 0x40000000u | dwt_ctrl;  // NUMCOMP 4
      case 0xE0001004: {
        const uint32_t v = Cyccnt();
        if (!peek && !active.empty()) {
          Active& ac = active.back();
          if (!ac.dwt_seen) ac.dwt_first = v;
          ac.dwt_seen = true;
          ac.dwt_last = v;
        }
        return v;
      }
      default: break;
    }
    if (a >= 0xE000E100 && a < 0xE000E10C) return nvic_iser[(a - 0xE000E100) / 4];
    if (a >= 0xE000E180 && a < 0xE000E18C) return nvic_iser[(a - 0xE000E180) / 4];
    if (a >= 0xE000E200 && a < 0xE000E20C) return nvic_ispr[(a - 0xE000E200) / 4];
    if (a >= 0xE000E280 && a < 0xE000E28C) return nvic_ispr[(a - 0xE000E280) / 4];
    if (a >= 0xE000E400 && a < 0xE000E460) {
      uint32_t v;
      std::memcpy(&v, &nvic_ipr[a - 0xE000E400], 4);
      return v;
    }
    if (!peek) FailAt("read of unmodelled register", a, 4);
    return 0;
  }

  void WriteTimer(Timer& t, uint32_t off, uint32_t v) {
    char buf[128];
    switch (off) {
      case 0x00:
        if (v & 0x7Au) {
          std::snprintf(buf, sizeof(buf), "%s CR1 0x%x: one-pulse, down/centre counting or ARR preload",
                        t.name, v);
          Fail(std::string(buf) + " are not modelled");
          return;
        }
        if ((v & 1u) && !t.enabled()) {
          if (TimerClockHz() != sysclk) {
            Fail("timer enabled with its clock not at SYSCLK: not modelled");
            return;
          }
          t.next_tick = cycles + t.period();
        }
        t.cr1 = v & 0x3FFu;
        return;
      case 0x04: t.cr2 = v; return;
      case 0x08:
        if (v != 0) Fail("timer slave mode (SMCR) is not modelled");
        return;
      case 0x0C:
        if (v & 0x7F00u) Fail("timer DMA requests are not modelled");
        t.dier = v & 0x5Fu;
        return;
      case 0x10: t.sr &= v; return;  // rc_w0
      case 0x14:
        if (v & ~1u) Fail("timer EGR events other than UG are not modelled");
        if (v & 1u) {  // UG: counter to 0, prescaler reloaded, UIF unless URS
          t.cnt = 0;
          t.psc_active = t.psc;
          t.next_tick = cycles + t.period();
          if (!(t.cr1 & 4u) && !(t.cr1 & 2u)) t.sr |= 1u;
        }
        return;
      case 0x18:
      case 0x1C: {
        t.ccmr[off == 0x1C] = v;
        for (int c = (off == 0x1C ? 2 : 0); c < (off == 0x1C ? 4 : 2); ++c) {
          if (!t.IsOutput(c)) {
            if ((t.ChannelField(c) & 3u) != 1u) Fail("input capture other than ICx on TIx is not modelled");
            continue;
          }
          const uint32_t m = t.OcMode(c);
          if (m == 4) t.ref[c] = false;
          if (m == 5) t.ref[c] = true;
          if (m >= 6) Fail("PWM output modes are not modelled");
          if (t.ChannelField(c) & 0x0Cu) Fail("output compare preload / fast enable are not modelled");
        }
        UpdatePins(cycles);
        return;
      }
      case 0x20:
        t.ccer = v;
        UpdatePins(cycles);
        return;
      case 0x24: t.cnt = v & t.width_mask; return;
      case 0x28: t.psc = v & 0xFFFFu; return;
      case 0x2C: t.arr = v & t.width_mask; return;
      case 0x34:
      case 0x38:
      case 0x3C:
      case 0x40: {
        const int c = int(off - 0x34) / 4;
        if (t.IsOutput(c)) t.ccr[c] = v & t.width_mask;
        return;
      }
      default: break;
    }
    FailAt("write to unmodelled timer register", (&t == &tim2 ? kTim2 : kTim3) + off, 4);
  }

  void WriteReg(uint32_t a, uint32_t v) {
    if (!ClockOn(a, false)) return;
    if (Timer* t = TimerAt(a)) {
      WriteTimer(*t, a & 0x3FFu, v);
      return;
    }
    uint8_t port = 0;
    if (Gpio* g = GpioAt(a, &port)) {
      switch (a & 0x3FFu) {
        case 0x00: g->moder = v; break;
        case 0x04: g->otyper = v; break;
        case 0x08: g->ospeedr = v; break;
        case 0x0C: g->pupdr = v; break;
        case 0x14: g->odr = v & 0xFFFFu; break;
        case 0x18: g->odr = (g->odr & ~(v >> 16)) | (v & 0xFFFFu); break;  // set wins over reset
        case 0x20: g->afr[0] = v; break;
        case 0x24: g->afr[1] = v; break;
        default: FailAt("write to unmodelled GPIO register", a, 4); return;
      }
      UpdatePins(cycles);
      return;
    }
    if (a >= kOtgFs && a < kOtgFs + DWC2_WINDOW_SIZE_BYTES) {
      if (a - kOtgFs == 0x804 && !(v & 2u) && usb_clk != 48000000u) {  // DCTL: soft-connect
        char buf[96];
        std::snprintf(buf, sizeof(buf), "USB connected with a %u Hz USB clock (the core needs 48 MHz)",
                      usb_clk);
        Fail(buf);
        return;
      }
      dwc2_model_write(usb_model, a - kOtgFs, v);
      return;
    }
    switch (a) {
      case kRcc + 0x00: {
        uint32_t cr = (rcc_cr & ~0x010D0001u) | (v & 0x010D0001u);    // HSION, HSEON, HSEBYP, CSSON, PLLON
        cr |= 2u;                                                     // HSIRDY
        cr = (cr & (1u << 16)) ? cr | (1u << 17) : cr & ~(1u << 17);  // the crystal starts at once
        if ((cr & (1u << 24)) && !(rcc_cr & (1u << 24))) {
          CheckPll();
          if ((rcc_pllcfgr & (1u << 22)) && !(cr & (1u << 17))) {
            Fail("PLL switched on from HSE with the crystal not ready");
            return;
          }
          cr |= 1u << 25;
        }
        if (!(cr & (1u << 24))) cr &= ~(1u << 25);
        rcc_cr = cr;
        return;
      }
      case kRcc + 0x04:
        if (rcc_cr & (1u << 24)) {
          Fail("RCC_PLLCFGR written while the PLL is on (RM0383 6.3.2)");
          return;
        }
        rcc_pllcfgr = v;
        return;
      case kRcc + 0x08:
        rcc_cfgr = (rcc_cfgr & (3u << 2)) | (v & ~(3u << 2));
        SwitchSysclk();
        return;
      case kRcc + 0x30: rcc_ahb1enr = v; return;
      case kRcc + 0x34: rcc_ahb2enr = v; return;
      case kRcc + 0x40: rcc_apb1enr = v; return;
      case kRcc + 0x44: rcc_apb2enr = v; return;
      case kRcc + 0x74:
        if (v & (1u << 24)) rcc_csr &= ~0xFE000000u;  // RMVF clears the reset flags
        return;
      case kFlashIf + 0x00: {
        if ((v & 0xFu) < (flash_acr & 0xFu) && sysclk > 30000000u) {
          Fail("flash wait states lowered while SYSCLK is fast");
          return;
        }
        if (options.flash_wait_states) art.Write(v);
        flash_acr = v & 0x70Fu;  // ICRST / DCRST self-clear
        return;
      }
      case kPwr + 0x00:
        if (((v ^ pwr_cr) & (3u << 14)) && (rcc_cr & (1u << 24))) {
          Fail("PWR_CR.VOS changed while the PLL is on (RM0383 5.4.1)");
          return;
        }
        pwr_cr = v;
        return;
      case 0xE000E010: {
        const bool was = systick.ctrl & 1u;
        systick.ctrl = (systick.ctrl & (1u << 16)) | (v & 7u);
        if ((v & 1u) && !was) {
          const uint64_t div = (v & 4u) ? 1 : 8;
          systick.zero_at = cycles + (uint64_t(systick.val_written) + 1) * div;
        }
        return;
      }
      case 0xE000E014: systick.load = v & 0xFFFFFFu; return;
      case 0xE000E018:
        systick.val_written = 0;
        systick.ctrl &= ~(1u << 16);
        if (systick.ctrl & 1u) systick.zero_at = cycles + ((systick.ctrl & 4u) ? 1 : 8);
        return;
      case 0xE000ED04:
        if (v & (1u << 25)) systick_pending = false;
        if (v & (1u << 26)) systick_pending = true;
        if (v & ~((1u << 25) | (1u << 26)))
          Fail("ICSR bits other than PENDSTSET / PENDSTCLR are not modelled");
        return;
      case 0xE000ED08: vtor = v & 0xFFFFFE00u; return;
      case 0xE000ED0C:
        if ((v >> 16) != 0x05FAu) return;  // no VECTKEY: ignored
        aircr = v & 0x700u;
        if (v & (1u << 2)) reset_requested = true, uc_emu_stop(uc);
        return;
      case 0xE000ED10:
        if (v & ~(1u << 4)) Fail("SCR: SLEEPONEXIT / SLEEPDEEP are not modelled");
        scr = v;
        return;
      case 0xE000ED14: ccr_scb = v; return;
      case 0xE000ED18: shpr[0] = v; return;
      case 0xE000ED1C: shpr[1] = v; return;
      case 0xE000ED20: shpr[2] = v; return;
      case 0xE000ED24: shcsr = v; return;
      case 0xE000ED88: cpacr = v; return;
      case 0xE000EDFC: demcr = v; return;
      case 0xE0001000: {
        const uint32_t before = Cyccnt();
        dwt_ctrl = v;
        dwt_base = uint32_t(cycles) - before;
        dwt_frozen = before;
        return;
      }
      case 0xE0001004:
        dwt_base = uint32_t(cycles) - v;
        dwt_frozen = v;
        return;
      default: break;
    }
    if (a >= 0xE000E100 && a < 0xE000E10C) {
      nvic_iser[(a - 0xE000E100) / 4] |= v;
      return;
    }
    if (a >= 0xE000E180 && a < 0xE000E18C) {
      nvic_iser[(a - 0xE000E180) / 4] &= ~v;
      return;
    }
    if (a >= 0xE000E200 && a < 0xE000E20C) {
      nvic_ispr[(a - 0xE000E200) / 4] |= v;
      return;
    }
    if (a >= 0xE000E280 && a < 0xE000E28C) {
      nvic_ispr[(a - 0xE000E280) / 4] &= ~v;
      return;
    }
    if (a >= 0xE000E400 && a < 0xE000E460) {
      std::memcpy(&nvic_ipr[a - 0xE000E400], &v, 4);
      for (int i = 0; i < 4; ++i) nvic_ipr[a - 0xE000E400 + i] &= 0xF0;  // 4 priority bits implemented
      return;
    }
    FailAt("write to unmodelled register", a, 4);
  }

  static constexpr uint32_t DWC2_WINDOW_SIZE_BYTES = 0x20000;
  bool reset_requested = false;
  uint64_t tail_chains = 0;

  // ---- hooks ----

  static void OnCode(uc_engine* uc, uint64_t address, uint32_t size, void* user) {
    Impl* e = static_cast<Impl*>(user);
    const uint32_t a = uint32_t(address);
    if (a >= kExcReturnPage) {
      e->want_return = true;
      e->exc_return = a | 1u;
      uc_emu_stop(uc);
      return;
    }
    if (e->cycles >= e->stop_at) {
      uc_emu_stop(uc);
      return;
    }
    e->last_pc = a;
    if (e->expect_pc != 0 && a != e->expect_pc) e->cycles += kBranchPenalty;
    const uint32_t index = (a - kFlashBase) / 2;
    if (a >= kFlashBase && index < e->insn.size()) {
      const InsnInfo& i = e->insn[index];
      if (i.flags & kInsnWfi) {
        e->want_wfi = true;
        e->wfi_pc = a;
        uc_emu_stop(uc);
        return;
      }
      if (i.flags & kInsnWfe) {
        e->Fail("WFE is not modelled");
        return;
      }
      e->cycles += i.cycles;
      if (e->options.flash_wait_states) e->cycles += e->art.Fetch(a, e->flash_acr);
      if (i.flags & kInsnCpsie) e->stop_at = 0;  // stop before the next instruction: Step takes it
    } else {
      e->cycles += 1;  // code outside flash (none in the image): one cycle
    }
    ++e->instructions;
    e->expect_pc = a + size;
  }

  // A data read of flash by the image (literal pools, constants): the ART's data side.
  static void OnFlashRead(uc_engine*, uc_mem_type, uint64_t address, int, int64_t, void* user) {
    Impl* e = static_cast<Impl*>(user);
    e->cycles += e->art.Read(uint32_t(address), e->flash_acr);
  }

  static bool OnUnmapped(uc_engine*, uc_mem_type type, uint64_t address, int size, int64_t, void* user) {
    Impl* e = static_cast<Impl*>(user);
    if (type == UC_MEM_FETCH_UNMAPPED && address >= kExcReturnPage && !e->active.empty()) {
      e->want_return = true;  // see OnInterrupt
      e->exc_return = uint32_t(address) | 1u;
      return false;
    }
    const char* what = type == UC_MEM_FETCH_UNMAPPED   ? "instruction fetch from unmapped address"
                       : type == UC_MEM_WRITE_UNMAPPED ? "write to unmapped address"
                                                       : "read of unmapped address";
    e->FailAt(what, uint32_t(address), unsigned(size));
    return false;
  }
  static bool OnProtected(uc_engine*, uc_mem_type type, uint64_t address, int size, int64_t, void* user) {
    Impl* e = static_cast<Impl*>(user);
    e->FailAt(type == UC_MEM_WRITE_PROT ? "write to read-only memory (flash or system memory)"
                                        : "access violating memory protection",
              uint32_t(address), unsigned(size));
    return false;
  }
  static void OnInterrupt(uc_engine*, uint32_t intno, void* user) {
    Impl* e = static_cast<Impl*>(user);
    // A branch to an EXC_RETURN value: QEMU raises EXCP_EXCEPTION_EXIT (8) when it believes it is in handler
    // mode, or a prefetch abort (3) on fetching from 0xFFFFFFxx (execute-never) when not. PC holds the
    // value; the harness does the return once unicorn has stopped.
    const uint32_t pc = e->Reg(UC_ARM_REG_PC);
    if ((intno == 8 || intno == 3) && pc >= kExcReturnPage && !e->active.empty()) {
      if (!e->want_return) {
        e->want_return = true;
        e->exc_return = pc | 1u;
      }
      uc_emu_stop(e->uc);
      return;
    }
    char buf[96];
    std::snprintf(buf, sizeof(buf), "HardFault: the CPU raised exception %u (unicorn)", intno);
    e->Fail(buf);
  }
  static bool OnInvalid(uc_engine*, void* user) {
    static_cast<Impl*>(user)->Fail("HardFault: undefined instruction");
    return false;
  }

  // ---- the run loop ----

  bool Step(uint64_t end) {
    Sync(cycles);
    LatchLines();
    if (!error.empty()) return false;
    const uint32_t primask = Reg(UC_ARM_REG_PRIMASK) & 1u;
    const uint32_t next = BestPending();
    if (sleeping) {
      if (next != kNoException) {
        sleeping = false;  // WFI wakes on an interrupt that would preempt, even with PRIMASK set
      } else {
        const uint64_t wake = std::min(end, NextEvent());
        if (wake == kNever) {
          Fail("WFI with no wake-up source: every interrupt off and no timer running");
          return false;
        }
        const uint64_t to = std::max(wake, cycles);
        sleep_cycles += to - cycles;
        cycles = to;
        return true;
      }
    }
    if (next != kNoException && !primask) {
      Enter(next);
      if (!error.empty()) return false;
    }
    stop_at = std::min(end, NextEvent());
    if (stop_at <= cycles) stop_at = cycles + 1;  // at least one instruction
    want_wfi = want_return = false;
    const uint32_t pc = Reg(UC_ARM_REG_PC);
    const uc_err err = uc_emu_start(uc, pc | 1u, 0xFFFFFFFFull, 0, 0);
    if (!error.empty()) return false;
    if (err != UC_ERR_OK && !want_return) {
      last_pc = Reg(UC_ARM_REG_PC);
      Fail(std::string("HardFault: ") + uc_strerror(err));
      return false;
    }
    if (reset_requested) {
      reset_requested = false;
      ++resets;
      rcc_csr = (rcc_csr & ~0xFE000000u) | (1u << 28);  // SFTRSTF
      CoreReset();
      return true;
    }
    if (want_return) Return(exc_return);
    if (want_wfi) {
      SetReg(UC_ARM_REG_PC, wfi_pc + 2);
      cycles += 1;
      ++instructions;
      ++wfi_count;
      expect_pc = 0;
      last_pc = wfi_pc;
      // A pending interrupt that could preempt makes WFI return at once.
      sleeping = BestPending() == kNoException;
    }
    return error.empty();
  }
};

F411Emu::F411Emu(const ElfImage& image, const EmuOptions& options) : impl_(new Impl) {
  Impl& e = *impl_;
  e.self = this;
  e.image = image;
  e.options = options;
  e.tim2.name = "TIM2";
  e.tim3.name = "TIM3";
  e.tim3.width_mask = 0xFFFF;
  e.flash.assign(kFlashSize, 0xFF);
  for (const ElfSegment& s : image.segments) {
    if (s.bytes.empty()) continue;
    if (s.load_address < kFlashBase || s.load_address + s.bytes.size() > kFlashBase + kFlashSize) {
      char buf[96];
      std::snprintf(buf, sizeof(buf), "a segment loads at 0x%08x, outside the flash", s.load_address);
      e.error = buf;
      return;
    }
    std::memcpy(&e.flash[s.load_address - kFlashBase], s.bytes.data(), s.bytes.size());
  }
  e.insn.resize(kFlashSize / 2);
  for (size_t i = 0; i + 1 < e.insn.size(); ++i) {
    uint16_t hw1, hw2;
    std::memcpy(&hw1, &e.flash[2 * i], 2);
    std::memcpy(&hw2, &e.flash[2 * i + 2], 2);
    e.insn[i] = Classify(hw1, hw2);
  }
  uc_err err = uc_open(UC_ARCH_ARM, uc_mode(UC_MODE_THUMB | UC_MODE_MCLASS), &e.uc);
  if (err == UC_ERR_OK) err = uc_ctl_set_cpu_model(e.uc, UC_CPU_ARM_CORTEX_M4);
  // Flash at 0x0800_0000 and its alias at 0 (BOOT0 low), read-only; SRAM; the system-memory page with the
  // unique id.
  if (err == UC_ERR_OK)
    err = uc_mem_map_ptr(e.uc, kFlashBase, kFlashSize, UC_PROT_READ | UC_PROT_EXEC, e.flash.data());
  if (err == UC_ERR_OK)
    err = uc_mem_map_ptr(e.uc, 0, kFlashSize, UC_PROT_READ | UC_PROT_EXEC, e.flash.data());
  if (err == UC_ERR_OK) err = uc_mem_map(e.uc, kSramBase, kSramSize, UC_PROT_ALL);
  if (err == UC_ERR_OK) err = uc_mem_map(e.uc, kSysMemPage, 0x400, UC_PROT_READ);
  if (err == UC_ERR_OK) {
    uint8_t page[0x400];
    std::memset(page, 0xFF, sizeof(page));
    std::memcpy(page + (kUidAddress - kSysMemPage), options.uid, 12);
    page[kFlashSizeAddress - kSysMemPage] = 512 & 0xFF;  // F_SIZE: 512 KB
    page[kFlashSizeAddress - kSysMemPage + 1] = 512 >> 8;
    err = uc_mem_write(e.uc, kSysMemPage, page, sizeof(page));
  }
  // APB1: TIM2, TIM3 and PWR; AHB1: GPIO A-C, RCC, the flash interface; AHB2: OTG_FS; the private
  // peripheral bus (NVIC, SysTick, SCB, DWT). 1 KB windows: any other peripheral address is unmapped.
  for (uint32_t base : {kTim2, kTim3, kPwr, kGpioA, kGpioB, kGpioC, kRcc, kFlashIf}) {
    if (err == UC_ERR_OK) err = e.MapWindow(base, 0x400);
  }
  if (err == UC_ERR_OK) err = e.MapWindow(kOtgFs, kOtgFsSize);
  if (err == UC_ERR_OK) err = e.MapWindow(kPpb, kPpbSize);
  uc_hook h;
  if (err == UC_ERR_OK)
    err = uc_hook_add(e.uc, &h, UC_HOOK_CODE, reinterpret_cast<void*>(&Impl::OnCode), impl_.get(), 1, 0);
  if (err == UC_ERR_OK && options.flash_wait_states) {
    err = uc_hook_add(e.uc, &h, UC_HOOK_MEM_READ, reinterpret_cast<void*>(&Impl::OnFlashRead), impl_.get(),
                      kFlashBase, kFlashBase + kFlashSize - 1);
  }
  if (err == UC_ERR_OK) {
    err = uc_hook_add(e.uc, &h, UC_HOOK_MEM_UNMAPPED, reinterpret_cast<void*>(&Impl::OnUnmapped), impl_.get(),
                      1, 0);
  }
  if (err == UC_ERR_OK) {
    err = uc_hook_add(e.uc, &h, UC_HOOK_MEM_PROT, reinterpret_cast<void*>(&Impl::OnProtected), impl_.get(), 1,
                      0);
  }
  if (err == UC_ERR_OK)
    err = uc_hook_add(e.uc, &h, UC_HOOK_INTR, reinterpret_cast<void*>(&Impl::OnInterrupt), impl_.get(), 1, 0);
  if (err == UC_ERR_OK) {
    err = uc_hook_add(e.uc, &h, UC_HOOK_INSN_INVALID, reinterpret_cast<void*>(&Impl::OnInvalid), impl_.get(),
                      1, 0);
  }
  if (err != UC_ERR_OK) e.error = std::string("unicorn: ") + uc_strerror(err);
}

F411Emu::~F411Emu() {
  if (impl_->uc) uc_close(impl_->uc);
  if (impl_->usb_model) dwc2_model_destroy(impl_->usb_model);
}

void F411Emu::PowerOn() {
  Impl& e = *impl_;
  if (!e.error.empty()) return;
  std::vector<uint8_t> paint(kSramSize, e.options.ram_paint);
  uc_mem_write(e.uc, kSramBase, paint.data(), paint.size());
  e.rcc_csr = 0x0C000000u;  // PORRSTF | PINRSTF
  e.started = false;
  e.pin_levels = 0;
  e.CoreReset();
  e.started = true;
}

bool F411Emu::Run(uint64_t n) {
  Impl& e = *impl_;
  const uint64_t end = e.cycles + n;
  while (e.error.empty() && e.cycles < end) {
    if (!e.Step(end)) break;
  }
  return e.error.empty();
}

bool F411Emu::RunUs(uint64_t us) {
  // In slices of 100 us, each at the SYSCLK of its start (the image switches from 16 MHz to 96 MHz once).
  for (uint64_t done = 0; done < us;) {
    const uint64_t slice = std::min<uint64_t>(us - done, 100);
    if (!Run(slice * (impl_->sysclk / 1000000u))) return false;
    done += slice;
  }
  return true;
}

bool F411Emu::ok() const {
  return impl_->error.empty();
}
const std::string& F411Emu::error() const {
  return impl_->error;
}
uint64_t F411Emu::cycles() const {
  return impl_->cycles;
}
uint64_t F411Emu::tail_chains() const {
  return impl_->tail_chains;
}
uint64_t F411Emu::flash_stall_cycles() const {
  return impl_->art.stall_cycles;
}
uint64_t F411Emu::flash_misses() const {
  return impl_->art.i_misses + impl_->art.d_misses;
}
uint64_t F411Emu::instructions() const {
  return impl_->instructions;
}
uint64_t F411Emu::sleep_cycles() const {
  return impl_->sleep_cycles;
}
uint64_t F411Emu::wfi_count() const {
  return impl_->wfi_count;
}
uint64_t F411Emu::resets() const {
  return impl_->resets;
}
uint32_t F411Emu::sysclk_hz() const {
  return impl_->sysclk;
}
uint32_t F411Emu::usb_clock_hz() const {
  return impl_->usb_clk;
}
uint32_t F411Emu::apb1_hz() const {
  return impl_->Apb1Hz();
}

uint32_t F411Emu::Peek(uint32_t address) {
  Impl& e = *impl_;
  if ((address >= 0x40000000 && address < 0x60000000) || address >= kPpb) {
    e.Sync(e.cycles);
    return e.ReadReg(address, true);
  }
  uint32_t v = 0;
  uc_mem_read(e.uc, address, &v, 4);
  return v;
}

const ElfImage& F411Emu::image() const {
  return impl_->image;
}

dwc2_model_t* F411Emu::usb() {
  return impl_->usb_model;
}
const std::vector<PinEdge>& F411Emu::edges() const {
  return impl_->edges;
}
bool F411Emu::PinLevel(uint8_t port, uint8_t pin) const {
  return (impl_->pin_levels >> (port * 16 + pin)) & 1u;
}
void F411Emu::PendInterrupt(uint32_t irq, bool enable) {
  if (irq >= kIrqCount) return;
  impl_->nvic_ispr[irq / 32] |= 1u << (irq % 32);
  if (enable) impl_->nvic_iser[irq / 32] |= 1u << (irq % 32);
}

void F411Emu::SetInputPin(uint8_t port, uint8_t pin, bool level) {
  impl_->Sync(impl_->cycles);
  impl_->ExternalEdge(port, pin, level, impl_->cycles);
}
uint32_t F411Emu::Tim2Now() {
  impl_->Sync(impl_->cycles);
  return impl_->tim2.cnt;
}
const ExceptionStats& F411Emu::exception_stats(uint32_t exception) const {
  return impl_->stats.at(exception);
}
const std::vector<PinEdge>& F411Emu::camera_edges() const {
  return impl_->camera_edges;
}
const std::vector<PinEdge>& F411Emu::captures() const {
  return impl_->capture_log;
}

uint32_t F411Emu::StackHighWater() {
  Impl& e = *impl_;
  // From the end of the static data (the last RAM section before the stack) up to the top of RAM: the
  // first byte that is not the paint is the deepest the stack reached.
  uint32_t low = kSramBase;
  for (const auto& [name, s] : e.image.sections) {
    if (name == ".stack") continue;
    if (s.address >= kSramBase && s.address < kSramBase + kSramSize) low = std::max(low, s.address + s.size);
  }
  std::vector<uint8_t> ram(kSramBase + kSramSize - low);
  uc_mem_read(e.uc, low, ram.data(), ram.size());
  for (size_t i = 0; i < ram.size(); ++i) {
    if (ram[i] != e.options.ram_paint) return uint32_t(ram.size() - i);
  }
  return 0;
}

}  // namespace rotoscan::fw_emu

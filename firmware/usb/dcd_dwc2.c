/*
 * The device controller driver for the Synopsys DWC2 core (STM32F411 OTG_FS), device mode, full speed, no
 * DMA (the FS core has none): slave mode, the CPU moves every packet through the FIFO windows. One packet per
 * hardware transfer, so that PKTCNT is always 1 and a transfer of any length is a loop of packets here.
 *
 * The facts that trip people up, each handled where the comment "TRAP" says:
 *   1. The Black Pill does not wire VBUS to PA9: with VBUS sensing on, the core never sees a session and
 *      never pulls D+ up. Set GCCFG.NOVBUSSENS, leave VBUSBSEN (and VBUSASEN) clear.
 *   2. FIFO sizes and start addresses are in 32-bit words, and the F411's core has 320 of them (1.25 KB).
 *      GHWCFG3 reports a larger figure on some parts: size from the manual, not from the register.
 *   3. Each read of GRXSTSP pops one entry of the receive FIFO; then exactly ceil(BCNT / 4) words of that
 *      entry must be read from the FIFO window before the next pop -- two words for a SETUP packet, none for
 *      the "transfer complete" and "SETUP done" entries. Reading more or fewer desynchronises the FIFO.
 *   4. DOEPTSIZ0.STUPCNT must be re-armed to 3 after every SETUP: the core takes up to three back-to-back
 *      SETUPs (a host retrying one whose ACK it lost), and only the last one counts -- it overwrites the one
 *      before in our buffer, and DOEPINT0.STUP is handled once, after the receive FIFO is drained.
 *   5. SET_ADDRESS: the new address goes into DCFG.DAD when the request arrives, before the status stage.
 *      The core itself answers the status stage at the old address (unlike most USB device controllers,
 *      where the address must be written after the status stage).
 *   6. DIEPTSIZ (and DOEPTSIZ) must be programmed before EPENA | CNAK are set in DIEPCTL: the core latches the
 *      size when the endpoint is enabled.
 *   7. Zero-length packets: the core sends one when an IN transfer of XFRSIZ 0 is enabled; deciding when one
 *      is due (after a bulk IN transfer that is a whole multiple of 64 bytes, after a control reply shorter
 *      than wLength and a multiple of 64) is the caller's job (usbd.c, usb_link.c).
 */
#include "dcd.h"

#include <string.h>

#include "dwc2_io.h"
#include "dwc2_regs.h"

DWC2_ASSERT(DCD_RX_FIFO_WORDS + DCD_TX0_FIFO_WORDS + DCD_TX1_FIFO_WORDS <= DWC2_FIFO_WORDS,
            "FIFOs exceed the core's 320 words (TRAP 2)");
DWC2_ASSERT(DCD_TX0_FIFO_WORDS >= DCD_EP0_SIZE / 4u && DCD_TX1_FIFO_WORDS >= 64u / 4u,
            "each transmit FIFO holds a whole packet");
DWC2_ASSERT(DCD_TX0_FIFO_WORDS >= 16u, "RM0383 22.16.2: DIEPTXF0 depth at least 16 words");

#define DCD_RESET_SPINS 100000u

typedef struct {
  uint8_t* buf;
  uint16_t len;  /* IN: bytes to send; OUT: room in buf */
  uint16_t done; /* bytes moved so far */
  uint16_t pkt;  /* IN: size of the packet in flight */
  uint16_t mps;
  bool busy;
} ep_state_t;

static struct {
  ep_state_t in[DCD_EP_COUNT];
  ep_state_t out[DCD_EP_COUNT];
  uint32_t setup[2]; /* the last SETUP packet received (TRAP 4) */
} g_dcd;

static void flush_fifos(void) {
  dwc2_wr(DWC2_GRSTCTL, DWC2_GRSTCTL_TXFFLSH | DWC2_GRSTCTL_TXFNUM_ALL);
  (void)dwc2_wait(DWC2_GRSTCTL, DWC2_GRSTCTL_TXFFLSH, 0u, DCD_RESET_SPINS);
  dwc2_wr(DWC2_GRSTCTL, DWC2_GRSTCTL_RXFFLSH);
  (void)dwc2_wait(DWC2_GRSTCTL, DWC2_GRSTCTL_RXFFLSH, 0u, DCD_RESET_SPINS);
}

/* Arms endpoint 0 OUT for up to three SETUPs and, with `data`, for one OUT data packet (TRAP 4, TRAP 6). */
static void arm_ep0_out(bool data) {
  dwc2_wr(DWC2_DOEPTSIZ(0), (3u << DWC2_DOEPTSIZ0_STUPCNT_POS) | (1u << DWC2_TSIZ_PKTCNT_POS) | DCD_EP0_SIZE);
  if (data) dwc2_set(DWC2_DOEPCTL(0), DWC2_EPCTL_EPENA | DWC2_EPCTL_CNAK);
}

int dcd_init(void) {
  memset(&g_dcd, 0, sizeof(g_dcd));
  if (dwc2_wait(DWC2_GRSTCTL, DWC2_GRSTCTL_AHBIDL, DWC2_GRSTCTL_AHBIDL, DCD_RESET_SPINS) != 0) return -1;
  dwc2_wr(DWC2_GRSTCTL, DWC2_GRSTCTL_CSRST);
  if (dwc2_wait(DWC2_GRSTCTL, DWC2_GRSTCTL_CSRST, 0u, DCD_RESET_SPINS) != 0) return -1;
  /* Forced device mode, the internal full-speed PHY, turnaround 6 (AHB >= 32 MHz, RM0383 22.16.2). */
  dwc2_wr(DWC2_GUSBCFG, DWC2_GUSBCFG_FDMOD | DWC2_GUSBCFG_PHYSEL | (6u << DWC2_GUSBCFG_TRDT_POS));
  /* TRAP 1: no VBUS sensing on this board. */
  dwc2_wr(DWC2_GCCFG, DWC2_GCCFG_PWRDWN | DWC2_GCCFG_NOVBUSSENS);
  dwc2_wr(DWC2_PCGCCTL, 0u);
  dwc2_wr(DWC2_DCTL, DWC2_DCTL_SDIS); /* stay disconnected until dcd_connect */
  dwc2_wr(DWC2_DCFG, DWC2_DCFG_DSPD_FS);
  /* TRAP 2: sizes and start addresses in words, out of 320. */
  dwc2_wr(DWC2_GRXFSIZ, DCD_RX_FIFO_WORDS);
  dwc2_wr(DWC2_DIEPTXF0, (DCD_TX0_FIFO_WORDS << 16) | DCD_RX_FIFO_WORDS);
  dwc2_wr(DWC2_DIEPTXF(1), (DCD_TX1_FIFO_WORDS << 16) | (DCD_RX_FIFO_WORDS + DCD_TX0_FIFO_WORDS));
  flush_fifos();
  dwc2_wr(DWC2_DIEPMSK, DWC2_EPINT_XFRC | DWC2_DIEPINT_TOC);
  dwc2_wr(DWC2_DOEPMSK, DWC2_EPINT_XFRC | DWC2_DOEPINT_STUP);
  dwc2_wr(DWC2_DAINTMSK, 0u);
  dwc2_wr(DWC2_GINTSTS, 0xFFFFFFFFu);
  dwc2_wr(DWC2_GINTMSK, DWC2_GINTSTS_USBRST | DWC2_GINTSTS_ENUMDNE | DWC2_GINTSTS_RXFLVL |
                            DWC2_GINTSTS_IEPINT | DWC2_GINTSTS_OEPINT);
  dwc2_wr(DWC2_GAHBCFG, DWC2_GAHBCFG_GINTMSK);
  return 0;
}

void dcd_connect(void) {
  dwc2_clear(DWC2_DCTL, DWC2_DCTL_SDIS);
}

void dcd_set_address(uint8_t address) {
  /* TRAP 5: now, before the status stage. */
  dwc2_wr(DWC2_DCFG, (dwc2_rd(DWC2_DCFG) & ~DWC2_DCFG_DAD_MASK) | ((uint32_t)(address & 0x7Fu) << DWC2_DCFG_DAD_POS));
}

void dcd_ep_open_bulk(uint8_t ep, uint16_t max_packet) {
  const uint32_t n = ep & 0x7Fu;
  if (n == 0u || n >= DCD_EP_COUNT) return;
  const uint32_t ctl = DWC2_EPCTL_USBAEP | DWC2_EPCTL_EPTYP_BULK | DWC2_EPCTL_SD0PID | DWC2_EPCTL_SNAK |
                       (max_packet & DWC2_EPCTL_MPSIZ_MASK);
  if (ep & DCD_DIR_IN) {
    memset(&g_dcd.in[n], 0, sizeof(g_dcd.in[n]));
    g_dcd.in[n].mps = max_packet;
    dwc2_wr(DWC2_DIEPCTL(n), ctl | (n << DWC2_EPCTL_TXFNUM_POS));
    dwc2_set(DWC2_DAINTMSK, 1u << n);
  } else {
    memset(&g_dcd.out[n], 0, sizeof(g_dcd.out[n]));
    g_dcd.out[n].mps = max_packet;
    dwc2_wr(DWC2_DOEPCTL(n), ctl);
    dwc2_set(DWC2_DAINTMSK, 1u << (16u + n));
  }
}

/* Starts the next IN packet of endpoint n: size, enable, then the data into its FIFO (TRAP 6). */
static void in_next_packet(uint32_t n) {
  ep_state_t* s = &g_dcd.in[n];
  const uint16_t left = (uint16_t)(s->len - s->done);
  s->pkt = left < s->mps ? left : s->mps;
  dwc2_wr(DWC2_DIEPTSIZ(n), (1u << DWC2_TSIZ_PKTCNT_POS) | s->pkt);
  dwc2_set(DWC2_DIEPCTL(n), DWC2_EPCTL_EPENA | DWC2_EPCTL_CNAK);
  const uint8_t* p = s->buf + s->done;
  for (uint32_t i = 0; i < s->pkt; i += 4u) {
    uint32_t w = 0;
    for (uint32_t b = 0; b < 4u && i + b < s->pkt; ++b) w |= (uint32_t)p[i + b] << (8u * b);
    dwc2_wr(DWC2_FIFO(n), w);
  }
}

static void out_arm(uint32_t n) {
  if (n == 0u) {
    arm_ep0_out(true);
    return;
  }
  dwc2_wr(DWC2_DOEPTSIZ(n), (1u << DWC2_TSIZ_PKTCNT_POS) | g_dcd.out[n].mps);
  dwc2_set(DWC2_DOEPCTL(n), DWC2_EPCTL_EPENA | DWC2_EPCTL_CNAK);
}

bool dcd_ep_xfer(uint8_t ep, uint8_t* buf, uint16_t len) {
  const uint32_t n = ep & 0x7Fu;
  if (n >= DCD_EP_COUNT) return false;
  ep_state_t* s = (ep & DCD_DIR_IN) ? &g_dcd.in[n] : &g_dcd.out[n];
  if (s->busy) return false;
  if (n == 0u) s->mps = DCD_EP0_SIZE;
  s->buf = buf;
  s->len = len;
  s->done = 0;
  s->busy = true;
  if (ep & DCD_DIR_IN) {
    in_next_packet(n);
  } else {
    out_arm(n);
  }
  return true;
}

bool dcd_ep_busy(uint8_t ep) {
  const uint32_t n = ep & 0x7Fu;
  if (n >= DCD_EP_COUNT) return false;
  return (ep & DCD_DIR_IN) ? g_dcd.in[n].busy : g_dcd.out[n].busy;
}

void dcd_ep_stall(uint8_t ep) {
  const uint32_t n = ep & 0x7Fu;
  if (n >= DCD_EP_COUNT) return;
  if (n == 0u) { /* a control pipe stalls both ways; the core clears it when the next SETUP comes */
    g_dcd.in[0].busy = false;
    g_dcd.out[0].busy = false;
    dwc2_set(DWC2_DIEPCTL(0), DWC2_EPCTL_STALL);
    dwc2_set(DWC2_DOEPCTL(0), DWC2_EPCTL_STALL);
    return;
  }
  if (ep & DCD_DIR_IN) {
    g_dcd.in[n].busy = false;
    const uint32_t ctl = dwc2_rd(DWC2_DIEPCTL(n));
    dwc2_wr(DWC2_DIEPCTL(n), ctl | DWC2_EPCTL_STALL | ((ctl & DWC2_EPCTL_EPENA) ? DWC2_EPCTL_EPDIS : 0u));
  } else {
    g_dcd.out[n].busy = false;
    dwc2_set(DWC2_DOEPCTL(n), DWC2_EPCTL_STALL);
  }
}

void dcd_ep_clear_stall(uint8_t ep) {
  const uint32_t n = ep & 0x7Fu;
  if (n == 0u || n >= DCD_EP_COUNT) return;
  const uint32_t reg = (ep & DCD_DIR_IN) ? DWC2_DIEPCTL(n) : DWC2_DOEPCTL(n);
  /* CLEAR_FEATURE(ENDPOINT_HALT) also resets the data toggle (USB 2.0 9.4.5). */
  dwc2_wr(reg, (dwc2_rd(reg) & ~DWC2_EPCTL_STALL) | DWC2_EPCTL_SD0PID);
}

bool dcd_ep_stalled(uint8_t ep) {
  const uint32_t n = ep & 0x7Fu;
  if (n >= DCD_EP_COUNT) return false;
  const uint32_t reg = (ep & DCD_DIR_IN) ? DWC2_DIEPCTL(n) : DWC2_DOEPCTL(n);
  return (dwc2_rd(reg) & DWC2_EPCTL_STALL) != 0u;
}

/* ---- interrupts ---- */

static void bus_reset(void) {
  for (uint32_t n = 0; n < DCD_EP_COUNT; ++n) {
    dwc2_set(DWC2_DOEPCTL(n), DWC2_EPCTL_SNAK);
    if (n > 0u) {
      if (dwc2_rd(DWC2_DIEPCTL(n)) & DWC2_EPCTL_EPENA) dwc2_set(DWC2_DIEPCTL(n), DWC2_EPCTL_EPDIS | DWC2_EPCTL_SNAK);
      if (dwc2_rd(DWC2_DOEPCTL(n)) & DWC2_EPCTL_EPENA) dwc2_set(DWC2_DOEPCTL(n), DWC2_EPCTL_EPDIS);
      dwc2_wr(DWC2_DIEPCTL(n), 0u);
      dwc2_wr(DWC2_DOEPCTL(n), 0u);
    }
    dwc2_wr(DWC2_DIEPINT(n), 0xFFFFFFFFu);
    dwc2_wr(DWC2_DOEPINT(n), 0xFFFFFFFFu);
  }
  memset(g_dcd.in, 0, sizeof(g_dcd.in));
  memset(g_dcd.out, 0, sizeof(g_dcd.out));
  dwc2_wr(DWC2_DAINTMSK, (1u << 0) | (1u << 16));
  dcd_set_address(0);
  flush_fifos();
  arm_ep0_out(false);
  usbd_on_bus_reset();
}

/* TRAP 3: one pop per entry, exactly its words. */
static void drain_rx_fifo(void) {
  for (uint32_t guard = 0; guard < 64u && (dwc2_rd(DWC2_GINTSTS) & DWC2_GINTSTS_RXFLVL); ++guard) {
    const uint32_t st = dwc2_rd(DWC2_GRXSTSP);
    const uint32_t n = DWC2_GRXSTS_EPNUM(st);
    const uint32_t bcnt = DWC2_GRXSTS_BCNT(st);
    switch (DWC2_GRXSTS_PKTSTS(st)) {
      case DWC2_PKTSTS_SETUP_DATA:
        /* Always 8 bytes = two words; a later back-to-back SETUP overwrites this one (TRAP 4). */
        g_dcd.setup[0] = dwc2_rd(DWC2_FIFO(0));
        g_dcd.setup[1] = dwc2_rd(DWC2_FIFO(0));
        break;
      case DWC2_PKTSTS_OUT_DATA: {
        ep_state_t* s = n < DCD_EP_COUNT ? &g_dcd.out[n] : NULL;
        for (uint32_t i = 0; i < bcnt; i += 4u) {
          const uint32_t w = dwc2_rd(DWC2_FIFO(0));
          for (uint32_t b = 0; b < 4u && i + b < bcnt; ++b) {
            /* Bytes beyond the buffer are read out of the FIFO and dropped (a babbling host). */
            if (s != NULL && s->buf != NULL && s->done < s->len) s->buf[s->done++] = (uint8_t)(w >> (8u * b));
          }
        }
        break;
      }
      default: break; /* OUT done, SETUP done, global OUT NAK: no data words */
    }
  }
}

static void handle_out_endpoints(void) {
  const uint32_t daint = (dwc2_rd(DWC2_DAINT) & dwc2_rd(DWC2_DAINTMSK)) >> 16;
  for (uint32_t n = 0; n < DCD_EP_COUNT; ++n) {
    if (!(daint & (1u << n))) continue;
    const uint32_t flags = dwc2_rd(DWC2_DOEPINT(n));
    dwc2_wr(DWC2_DOEPINT(n), flags); /* write 1 to clear */
    if ((flags & DWC2_EPINT_XFRC) && g_dcd.out[n].busy) {
      g_dcd.out[n].busy = false;
      usbd_on_xfer_done((uint8_t)n, g_dcd.out[n].done);
    }
    if (n == 0u && (flags & DWC2_DOEPINT_STUP)) {
      /* A SETUP ends whatever control transfer was going on. */
      g_dcd.in[0].busy = false;
      g_dcd.out[0].busy = false;
      arm_ep0_out(false); /* TRAP 4: STUPCNT back to 3 */
      uint8_t setup[8];
      for (uint32_t b = 0; b < 8u; ++b) setup[b] = (uint8_t)(g_dcd.setup[b / 4u] >> (8u * (b % 4u)));
      usbd_on_setup(setup);
    }
  }
}

static void handle_in_endpoints(void) {
  const uint32_t daint = dwc2_rd(DWC2_DAINT) & dwc2_rd(DWC2_DAINTMSK) & 0xFFFFu;
  for (uint32_t n = 0; n < DCD_EP_COUNT; ++n) {
    if (!(daint & (1u << n))) continue;
    const uint32_t flags = dwc2_rd(DWC2_DIEPINT(n));
    dwc2_wr(DWC2_DIEPINT(n), flags);
    ep_state_t* s = &g_dcd.in[n];
    if ((flags & DWC2_EPINT_XFRC) && s->busy) {
      s->done = (uint16_t)(s->done + s->pkt);
      if (s->done < s->len) {
        in_next_packet(n);
      } else {
        s->busy = false;
        usbd_on_xfer_done((uint8_t)(n | DCD_DIR_IN), s->done);
      }
    }
  }
}

void dcd_irq(void) {
  const uint32_t sts = dwc2_rd(DWC2_GINTSTS) & dwc2_rd(DWC2_GINTMSK);
  if (sts & DWC2_GINTSTS_USBRST) {
    dwc2_wr(DWC2_GINTSTS, DWC2_GINTSTS_USBRST);
    bus_reset();
  }
  if (sts & DWC2_GINTSTS_ENUMDNE) {
    dwc2_wr(DWC2_GINTSTS, DWC2_GINTSTS_ENUMDNE);
    dwc2_clear(DWC2_DIEPCTL(0), DWC2_EPCTL_MPSIZ_MASK); /* 00: 64-byte packets on endpoint 0 */
    dwc2_set(DWC2_DCTL, DWC2_DCTL_CGINAK);
  }
  if (sts & DWC2_GINTSTS_RXFLVL) drain_rx_fifo();
  if (sts & DWC2_GINTSTS_OEPINT) handle_out_endpoints();
  if (sts & DWC2_GINTSTS_IEPINT) handle_in_endpoints();
}

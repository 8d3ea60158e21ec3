/* The DWC2 register-level model: see dwc2_model.h. Register semantics from RM0383 22.16. */
#include "dwc2_model.h"

#include <stdio.h>
#include <stdlib.h>
#include <string.h>

#include "dwc2_regs.h"

#define EPS 4u
#define RX_ENTRIES 64u
#define TX_WORDS 512u

typedef struct {
  uint32_t status;  /* the GRXSTSP word */
  uint32_t words[16];
  uint32_t count;   /* data words */
} rx_entry_t;

typedef struct {
  uint32_t ctl;
  uint32_t intr;
  uint32_t tsiz;
  bool tsiz_fresh; /* DIEPTSIZ / DOEPTSIZ written since the endpoint was last enabled */
  bool nak;        /* NAK bit (SNAK / CNAK) */
  uint32_t fifo[TX_WORDS]; /* IN only */
  uint32_t fifo_head, fifo_count;
} ep_t;

struct dwc2_model {
  uint32_t gahbcfg, gusbcfg, gintsts, gintmsk, grxfsiz, dieptxf[EPS], gccfg, dcfg, dctl, diepmsk, doepmsk,
      daintmsk, pcgcctl;
  ep_t in[EPS], out[EPS];
  rx_entry_t rx[RX_ENTRIES];
  uint32_t rx_head, rx_count, rx_words;
  bool popped;            /* an entry has been popped ... */
  rx_entry_t current;     /* ... and this is it */
  uint32_t current_read;  /* its words read so far */
  uint8_t address;        /* the address the core answers at */
  char error[200];
};

static void fail(dwc2_model_t* m, const char* what, uint32_t a, uint32_t b) {
  if (m->error[0] != '\0') return;
  (void)snprintf(m->error, sizeof(m->error), what, (unsigned)a, (unsigned)b);
}

static void core_reset(dwc2_model_t* m) {
  char error[sizeof(m->error)];
  memcpy(error, m->error, sizeof(error));
  memset(m, 0, sizeof(*m));
  memcpy(m->error, error, sizeof(error));
  m->dctl = DWC2_DCTL_SDIS;
  for (uint32_t n = 0; n < EPS; ++n) {
    m->in[n].nak = true;
    m->out[n].nak = true;
  }
}

dwc2_model_t* dwc2_model_create(void) {
  dwc2_model_t* m = (dwc2_model_t*)calloc(1, sizeof(dwc2_model_t));
  if (m != NULL) core_reset(m);
  return m;
}

void dwc2_model_destroy(dwc2_model_t* m) {
  free(m);
}

const char* dwc2_model_error(const dwc2_model_t* m) {
  return m->error[0] != '\0' ? m->error : NULL;
}
uint8_t dwc2_model_address(const dwc2_model_t* m) {
  return m->address;
}

/* ---- FIFO layout ---- */

static uint32_t rx_depth(const dwc2_model_t* m) {
  return m->grxfsiz & 0xFFFFu;
}
static uint32_t tx_depth(const dwc2_model_t* m, uint32_t n) {
  return m->dieptxf[n] >> 16;
}

static void check_fifo_layout(dwc2_model_t* m) {
  uint32_t end = rx_depth(m);
  for (uint32_t n = 0; n < EPS; ++n) {
    if (tx_depth(m, n) == 0u) continue;
    const uint32_t start = m->dieptxf[n] & 0xFFFFu;
    if (start < rx_depth(m)) fail(m, "transmit FIFO %u starts at word %u, inside the receive FIFO", n, start);
    if (start + tx_depth(m, n) > end) end = start + tx_depth(m, n);
  }
  if (end > DWC2_FIFO_WORDS) fail(m, "FIFOs end at word %u, beyond the core's %u words", end, DWC2_FIFO_WORDS);
}

/* ---- interrupts ---- */

static uint32_t daint(const dwc2_model_t* m) {
  uint32_t v = 0;
  for (uint32_t n = 0; n < EPS; ++n) {
    if (m->in[n].intr & m->diepmsk) v |= 1u << n;
    if (m->out[n].intr & m->doepmsk) v |= 1u << (16u + n);
  }
  return v;
}

static uint32_t gintsts(const dwc2_model_t* m) {
  uint32_t v = m->gintsts;
  if (m->rx_count > 0u) v |= DWC2_GINTSTS_RXFLVL;
  const uint32_t d = daint(m) & m->daintmsk;
  if (d & 0xFFFFu) v |= DWC2_GINTSTS_IEPINT;
  if (d >> 16) v |= DWC2_GINTSTS_OEPINT;
  return v;
}

bool dwc2_model_irq(const dwc2_model_t* m) {
  return (m->gahbcfg & DWC2_GAHBCFG_GINTMSK) && (gintsts(m) & m->gintmsk) != 0u;
}

/* ---- receive FIFO ---- */

static bool rx_push(dwc2_model_t* m, uint32_t ep, uint32_t pktsts, const uint8_t* data, uint32_t bcnt) {
  const uint32_t words = (bcnt + 3u) / 4u;
  if (m->rx_count == RX_ENTRIES || m->rx_words + 1u + words > rx_depth(m)) return false;
  rx_entry_t* e = &m->rx[(m->rx_head + m->rx_count) % RX_ENTRIES];
  memset(e, 0, sizeof(*e));
  e->status = ep | bcnt << 4 | pktsts << 17;
  e->count = words;
  for (uint32_t i = 0; i < bcnt; ++i) e->words[i / 4u] |= (uint32_t)data[i] << (8u * (i % 4u));
  ++m->rx_count;
  m->rx_words += 1u + words;
  return true;
}

static uint32_t rx_pop(dwc2_model_t* m) {
  if (m->popped && m->current_read < m->current.count) {
    fail(m, "GRXSTSP popped with %u of %u words of the previous entry unread", m->current.count - m->current_read,
         m->current.count);
  }
  if (m->rx_count == 0u) {
    fail(m, "GRXSTSP popped from an empty receive FIFO", 0, 0);
    return 0;
  }
  m->current = m->rx[m->rx_head];
  m->rx_head = (m->rx_head + 1u) % RX_ENTRIES;
  --m->rx_count;
  m->rx_words -= 1u + m->current.count;
  m->current_read = 0;
  m->popped = true;
  const uint32_t ep = DWC2_GRXSTS_EPNUM(m->current.status);
  switch (DWC2_GRXSTS_PKTSTS(m->current.status)) {
    case DWC2_PKTSTS_OUT_DONE: /* the transfer-complete interrupt comes when its entry is popped */
      m->out[ep].intr |= DWC2_EPINT_XFRC;
      m->out[ep].ctl &= ~DWC2_EPCTL_EPENA;
      m->out[ep].nak = true;
      break;
    case DWC2_PKTSTS_SETUP_DONE:
      m->out[0].intr |= DWC2_DOEPINT_STUP;
      m->out[0].ctl &= ~DWC2_EPCTL_EPENA;
      break;
    default: break;
  }
  return m->current.status;
}

static uint32_t fifo_read(dwc2_model_t* m) {
  if (!m->popped || m->current_read >= m->current.count) {
    fail(m, "receive FIFO read beyond the %u words of the entry popped", m->popped ? m->current.count : 0u, 0);
    return 0xDEADBEEFu;
  }
  return m->current.words[m->current_read++];
}

/* ---- endpoints ---- */

static uint32_t ep_mps(const dwc2_model_t* m, uint32_t n, bool in) {
  const uint32_t ctl = in ? m->in[n].ctl : m->out[n].ctl;
  if (n == 0u) {
    static const uint32_t ep0[4] = {64, 32, 16, 8};
    return ep0[m->in[0].ctl & 3u];
  }
  return ctl & DWC2_EPCTL_MPSIZ_MASK;
}

static void write_ctl(dwc2_model_t* m, uint32_t n, bool in, uint32_t v) {
  ep_t* e = in ? &m->in[n] : &m->out[n];
  const uint32_t stored = DWC2_EPCTL_MPSIZ_MASK | DWC2_EPCTL_USBAEP | (3u << DWC2_EPCTL_EPTYP_POS) |
                          DWC2_EPCTL_STALL | (0xFu << DWC2_EPCTL_TXFNUM_POS);
  const bool enable = (v & DWC2_EPCTL_EPENA) && !(e->ctl & DWC2_EPCTL_EPENA);
  e->ctl = (e->ctl & ~stored) | (v & stored) | (e->ctl & DWC2_EPCTL_EPENA);
  if (n == 0u) e->ctl |= DWC2_EPCTL_USBAEP;
  if (v & DWC2_EPCTL_SNAK) e->nak = true;
  if (v & DWC2_EPCTL_CNAK) e->nak = false;
  if (v & DWC2_EPCTL_EPDIS) {
    e->ctl &= ~DWC2_EPCTL_EPENA;
    e->intr |= DWC2_EPINT_EPDISD;
    if (in) e->fifo_count = 0;
    return;
  }
  if (enable) {
    if (!e->tsiz_fresh) {
      fail(m, in ? "IN endpoint %u enabled (EPENA) before DIEPTSIZ was programmed"
                 : "OUT endpoint %u enabled (EPENA) before DOEPTSIZ was programmed",
           n, 0);
    }
    if (((e->tsiz & DWC2_TSIZ_PKTCNT_MASK) >> DWC2_TSIZ_PKTCNT_POS) == 0u && !(n == 0u && !in)) {
      fail(m, "endpoint %u enabled with PKTCNT 0 (in %u)", n, in);
    }
    e->tsiz_fresh = false;
    e->ctl |= DWC2_EPCTL_EPENA;
  }
}

static void fifo_push(dwc2_model_t* m, uint32_t n, uint32_t w) {
  ep_t* e = &m->in[n];
  if (e->fifo_count >= tx_depth(m, n) || e->fifo_count >= TX_WORDS) {
    fail(m, "transmit FIFO %u overfilled (%u words)", n, tx_depth(m, n));
    return;
  }
  e->fifo[(e->fifo_head + e->fifo_count) % TX_WORDS] = w;
  ++e->fifo_count;
}

/* ---- bus side ---- */

uint32_t dwc2_model_read(dwc2_model_t* m, uint32_t off) {
  if (off >= 0x1000u && off < DWC2_WINDOW_SIZE) return fifo_read(m);
  if (off >= 0x900u && off < 0x980u) {
    const uint32_t n = (off - 0x900u) / 0x20u;
    switch ((off - 0x900u) % 0x20u) {
      case 0x00: return m->in[n].ctl | (m->in[n].nak ? DWC2_EPCTL_NAKSTS : 0u);
      case 0x08: return m->in[n].intr;
      case 0x10: return m->in[n].tsiz;
      case 0x18: return tx_depth(m, n) - m->in[n].fifo_count;
      default: return 0;
    }
  }
  if (off >= 0xB00u && off < 0xB80u) {
    const uint32_t n = (off - 0xB00u) / 0x20u;
    switch ((off - 0xB00u) % 0x20u) {
      case 0x00: return m->out[n].ctl | (m->out[n].nak ? DWC2_EPCTL_NAKSTS : 0u);
      case 0x08: return m->out[n].intr;
      case 0x10: return m->out[n].tsiz;
      default: return 0;
    }
  }
  switch (off) {
    case DWC2_GAHBCFG: return m->gahbcfg;
    case DWC2_GUSBCFG: return m->gusbcfg;
    case DWC2_GRSTCTL: return DWC2_GRSTCTL_AHBIDL; /* resets and flushes finish at once */
    case DWC2_GINTSTS: return gintsts(m);
    case DWC2_GINTMSK: return m->gintmsk;
    case DWC2_GRXSTSR: return m->rx_count ? m->rx[m->rx_head].status : 0u;
    case DWC2_GRXSTSP: return rx_pop(m);
    case DWC2_GRXFSIZ: return m->grxfsiz;
    case DWC2_DIEPTXF0: return m->dieptxf[0];
    case DWC2_GCCFG: return m->gccfg;
    case DWC2_CID: return 0x00001200u;
    case DWC2_DCFG: return m->dcfg;
    case DWC2_DCTL: return m->dctl;
    case DWC2_DSTS: return 3u << 1; /* enumerated at full speed */
    case DWC2_DIEPMSK: return m->diepmsk;
    case DWC2_DOEPMSK: return m->doepmsk;
    case DWC2_DAINT: return daint(m);
    case DWC2_DAINTMSK: return m->daintmsk;
    case DWC2_PCGCCTL: return m->pcgcctl;
    default:
      if (off >= DWC2_DIEPTXF(1) && off <= DWC2_DIEPTXF(3)) return m->dieptxf[(off - DWC2_DIEPTXF(1)) / 4u + 1u];
      return 0;
  }
}

void dwc2_model_write(dwc2_model_t* m, uint32_t off, uint32_t v) {
  if (off >= 0x1000u && off < DWC2_WINDOW_SIZE) {
    const uint32_t n = off / 0x1000u - 1u;
    if (n < EPS) fifo_push(m, n, v);
    return;
  }
  if (off >= 0x900u && off < 0x980u) {
    const uint32_t n = (off - 0x900u) / 0x20u;
    switch ((off - 0x900u) % 0x20u) {
      case 0x00: write_ctl(m, n, true, v); break;
      case 0x08: m->in[n].intr &= ~v; break;
      case 0x10:
        m->in[n].tsiz = v;
        m->in[n].tsiz_fresh = true;
        break;
      default: break;
    }
    return;
  }
  if (off >= 0xB00u && off < 0xB80u) {
    const uint32_t n = (off - 0xB00u) / 0x20u;
    switch ((off - 0xB00u) % 0x20u) {
      case 0x00: write_ctl(m, n, false, v); break;
      case 0x08: m->out[n].intr &= ~v; break;
      case 0x10:
        m->out[n].tsiz = v;
        m->out[n].tsiz_fresh = true;
        break;
      default: break;
    }
    return;
  }
  switch (off) {
    case DWC2_GAHBCFG: m->gahbcfg = v; break;
    case DWC2_GUSBCFG: m->gusbcfg = v; break;
    case DWC2_GRSTCTL:
      if (v & DWC2_GRSTCTL_CSRST) core_reset(m);
      if (v & DWC2_GRSTCTL_RXFFLSH) {
        m->rx_count = 0;
        m->rx_words = 0;
        m->popped = false;
      }
      if (v & DWC2_GRSTCTL_TXFFLSH) {
        for (uint32_t n = 0; n < EPS; ++n) m->in[n].fifo_count = 0;
      }
      break;
    case DWC2_GINTSTS: m->gintsts &= ~v; break;
    case DWC2_GINTMSK: m->gintmsk = v; break;
    case DWC2_GRXFSIZ:
      m->grxfsiz = v;
      check_fifo_layout(m);
      break;
    case DWC2_DIEPTXF0:
      m->dieptxf[0] = v;
      check_fifo_layout(m);
      break;
    case DWC2_GCCFG:
      m->gccfg = v;
      if (v & DWC2_GCCFG_VBUSBSEN) fail(m, "VBUS sensing (VBUSBSEN) on, but this board has no VBUS on PA9", 0, 0);
      break;
    case DWC2_DCFG: m->dcfg = v; break;
    case DWC2_DCTL: m->dctl = v & ~(DWC2_DCTL_CGINAK | DWC2_DCTL_CGONAK); break;
    case DWC2_DIEPMSK: m->diepmsk = v; break;
    case DWC2_DOEPMSK: m->doepmsk = v; break;
    case DWC2_DAINTMSK: m->daintmsk = v; break;
    case DWC2_PCGCCTL: m->pcgcctl = v; break;
    default:
      if (off >= DWC2_DIEPTXF(1) && off <= DWC2_DIEPTXF(3)) {
        m->dieptxf[(off - DWC2_DIEPTXF(1)) / 4u + 1u] = v;
        check_fifo_layout(m);
      }
      break;
  }
}

/* ---- USB side ---- */

bool dwc2_model_connected(const dwc2_model_t* m) {
  /* D+ is pulled up when not soft-disconnected, the transceiver is on, and a session is seen: with no VBUS
   * on the board only NOVBUSSENS gives one. */
  return !(m->dctl & DWC2_DCTL_SDIS) && (m->gccfg & DWC2_GCCFG_PWRDWN) && (m->gccfg & DWC2_GCCFG_NOVBUSSENS) &&
         !(m->gccfg & DWC2_GCCFG_VBUSBSEN);
}

void dwc2_model_bus_reset(dwc2_model_t* m) {
  m->address = 0;
  m->gintsts |= DWC2_GINTSTS_USBRST | DWC2_GINTSTS_ENUMDNE;
}

static bool present(const dwc2_model_t* m, uint8_t address) {
  return dwc2_model_connected(m) && address == m->address && m->error[0] == '\0';
}

int dwc2_model_setup(dwc2_model_t* m, uint8_t address, const uint8_t packet[8]) {
  if (!present(m, address)) return DWC2_MODEL_NO_ANSWER;
  ep_t* e = &m->out[0];
  uint32_t stupcnt = (e->tsiz & DWC2_DOEPTSIZ0_STUPCNT_MASK) >> DWC2_DOEPTSIZ0_STUPCNT_POS;
  if (stupcnt == 0u) fail(m, "SETUP received with DOEPTSIZ0.STUPCNT at 0 (not re-armed)", 0, 0);
  if (stupcnt > 0u) --stupcnt;
  e->tsiz = (e->tsiz & ~DWC2_DOEPTSIZ0_STUPCNT_MASK) | stupcnt << DWC2_DOEPTSIZ0_STUPCNT_POS;
  /* A SETUP clears the control endpoint's stall in both directions and is always accepted. */
  m->in[0].ctl &= ~DWC2_EPCTL_STALL;
  m->out[0].ctl &= ~DWC2_EPCTL_STALL;
  if (!rx_push(m, 0, DWC2_PKTSTS_SETUP_DATA, packet, 8) || !rx_push(m, 0, DWC2_PKTSTS_SETUP_DONE, NULL, 0)) {
    fail(m, "receive FIFO too small for a SETUP (%u words)", rx_depth(m), 0);
    return DWC2_MODEL_NO_ANSWER;
  }
  return DWC2_MODEL_ACK;
}

int dwc2_model_out(dwc2_model_t* m, uint8_t address, uint8_t ep, const uint8_t* data, size_t len) {
  if (!present(m, address) || ep >= EPS) return DWC2_MODEL_NO_ANSWER;
  ep_t* e = &m->out[ep];
  if (!(e->ctl & DWC2_EPCTL_USBAEP)) return DWC2_MODEL_NO_ANSWER;
  if (e->ctl & DWC2_EPCTL_STALL) return DWC2_MODEL_STALL;
  const uint32_t pktcnt = (e->tsiz & DWC2_TSIZ_PKTCNT_MASK) >> DWC2_TSIZ_PKTCNT_POS;
  if (!(e->ctl & DWC2_EPCTL_EPENA) || e->nak || pktcnt == 0u) return DWC2_MODEL_NAK;
  if (len > ep_mps(m, ep, false)) {
    fail(m, "host sent %u bytes to an endpoint of %u", (uint32_t)len, ep_mps(m, ep, false));
    return DWC2_MODEL_NO_ANSWER;
  }
  if (m->rx_words + 2u + (len + 3u) / 4u > rx_depth(m)) return DWC2_MODEL_NAK;
  (void)rx_push(m, ep, DWC2_PKTSTS_OUT_DATA, data, (uint32_t)len);
  (void)rx_push(m, ep, DWC2_PKTSTS_OUT_DONE, NULL, 0);
  e->tsiz = (e->tsiz & ~DWC2_TSIZ_PKTCNT_MASK) | ((pktcnt - 1u) << DWC2_TSIZ_PKTCNT_POS);
  return DWC2_MODEL_ACK;
}

int dwc2_model_in(dwc2_model_t* m, uint8_t address, uint8_t ep, uint8_t* buf, size_t max, size_t* len) {
  *len = 0;
  if (!present(m, address) || ep >= EPS) return DWC2_MODEL_NO_ANSWER;
  ep_t* e = &m->in[ep];
  if (!(e->ctl & DWC2_EPCTL_USBAEP)) return DWC2_MODEL_NO_ANSWER;
  if (e->ctl & DWC2_EPCTL_STALL) return DWC2_MODEL_STALL;
  const uint32_t pktcnt = (e->tsiz & DWC2_TSIZ_PKTCNT_MASK) >> DWC2_TSIZ_PKTCNT_POS;
  const uint32_t xfrsiz = e->tsiz & DWC2_TSIZ_XFRSIZ_MASK;
  if (!(e->ctl & DWC2_EPCTL_EPENA) || e->nak || pktcnt == 0u) return DWC2_MODEL_NAK;
  const uint32_t mps = ep_mps(m, ep, true);
  const uint32_t n = xfrsiz < mps ? xfrsiz : mps;
  const uint32_t words = (n + 3u) / 4u;
  if (e->fifo_count < words) return DWC2_MODEL_NAK; /* data not written yet */
  if (n > max) {
    fail(m, "babble: a %u-byte packet for a %u-byte read", n, (uint32_t)max);
    return DWC2_MODEL_NO_ANSWER;
  }
  for (uint32_t i = 0; i < n; ++i) {
    buf[i] = (uint8_t)(e->fifo[(e->fifo_head + i / 4u) % TX_WORDS] >> (8u * (i % 4u)));
  }
  e->fifo_head = (e->fifo_head + words) % TX_WORDS;
  e->fifo_count -= words;
  *len = n;
  e->tsiz = (e->tsiz & ~(DWC2_TSIZ_PKTCNT_MASK | DWC2_TSIZ_XFRSIZ_MASK)) | ((pktcnt - 1u) << DWC2_TSIZ_PKTCNT_POS) |
            (xfrsiz - n);
  if (pktcnt == 1u) {
    e->ctl &= ~DWC2_EPCTL_EPENA;
    e->intr |= DWC2_EPINT_XFRC;
    /* The DWC2 takes a new DCFG.DAD only once the control transfer that set it has ended (its status stage):
     * a driver that writes it after the status stage is not at the new address for the next request. */
    if (ep == 0u && n == 0u) m->address = (uint8_t)((m->dcfg & DWC2_DCFG_DAD_MASK) >> DWC2_DCFG_DAD_POS);
  }
  return DWC2_MODEL_ACK;
}

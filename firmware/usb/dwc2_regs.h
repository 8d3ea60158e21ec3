/*
 * dwc2_regs.h -- registers of the Synopsys DWC2 USB OTG core as the STM32F411 has it (OTG_FS, device mode
 * only), offsets from the core's base, from RM0383 chapter 22 (22.16, the register map in 22.16.6). Shared by
 * the driver (dcd_dwc2.c) and the register-level model the host tests use (firmware/tests/usb/dwc2_model.c),
 * so both read the same bit positions; each offset is asserted against the register map.
 */
#ifndef ROTOSCAN_FIRMWARE_DWC2_REGS_H_
#define ROTOSCAN_FIRMWARE_DWC2_REGS_H_

#ifndef DWC2_ASSERT
#define DWC2_ASSERT(expr, msg) __extension__ _Static_assert(expr, msg)
#endif

/* Global registers (RM0383 22.16.1). */
#define DWC2_GOTGCTL 0x000u
#define DWC2_GAHBCFG 0x008u
#define DWC2_GUSBCFG 0x00Cu
#define DWC2_GRSTCTL 0x010u
#define DWC2_GINTSTS 0x014u
#define DWC2_GINTMSK 0x018u
#define DWC2_GRXSTSR 0x01Cu
#define DWC2_GRXSTSP 0x020u
#define DWC2_GRXFSIZ 0x024u
#define DWC2_DIEPTXF0 0x028u /* also called GNPTXFSIZ */
#define DWC2_GCCFG 0x038u
#define DWC2_CID 0x03Cu
#define DWC2_DIEPTXF(n) (0x104u + 4u * ((n)-1u)) /* n = 1..3 */
DWC2_ASSERT(DWC2_GINTSTS == 0x014u && DWC2_GINTMSK == 0x018u, "RM0383 22.16.6: GINTSTS, GINTMSK");
DWC2_ASSERT(DWC2_GRXSTSP == 0x020u && DWC2_GRXFSIZ == 0x024u && DWC2_DIEPTXF0 == 0x028u,
            "RM0383 22.16.6: GRXSTSP, GRXFSIZ, DIEPTXF0");
DWC2_ASSERT(DWC2_GCCFG == 0x038u && DWC2_DIEPTXF(1) == 0x104u && DWC2_DIEPTXF(3) == 0x10Cu,
            "RM0383 22.16.6: GCCFG, DIEPTXF1..3");

/* Device registers (RM0383 22.16.3). */
#define DWC2_DCFG 0x800u
#define DWC2_DCTL 0x804u
#define DWC2_DSTS 0x808u
#define DWC2_DIEPMSK 0x810u
#define DWC2_DOEPMSK 0x814u
#define DWC2_DAINT 0x818u
#define DWC2_DAINTMSK 0x81Cu
#define DWC2_DIEPEMPMSK 0x834u
#define DWC2_DIEPCTL(n) (0x900u + 0x20u * (n))
#define DWC2_DIEPINT(n) (0x908u + 0x20u * (n))
#define DWC2_DIEPTSIZ(n) (0x910u + 0x20u * (n))
#define DWC2_DTXFSTS(n) (0x918u + 0x20u * (n))
#define DWC2_DOEPCTL(n) (0xB00u + 0x20u * (n))
#define DWC2_DOEPINT(n) (0xB08u + 0x20u * (n))
#define DWC2_DOEPTSIZ(n) (0xB10u + 0x20u * (n))
#define DWC2_PCGCCTL 0xE00u
#define DWC2_FIFO(n) (0x1000u + 0x1000u * (n)) /* push (IN endpoint n) / pop (the receive FIFO) window */
DWC2_ASSERT(DWC2_DCFG == 0x800u && DWC2_DCTL == 0x804u && DWC2_DSTS == 0x808u, "RM0383 22.16.6: DCFG..DSTS");
DWC2_ASSERT(DWC2_DAINTMSK == 0x81Cu && DWC2_DIEPEMPMSK == 0x834u, "RM0383 22.16.6: DAINTMSK, DIEPEMPMSK");
DWC2_ASSERT(DWC2_DIEPCTL(1) == 0x920u && DWC2_DIEPTSIZ(1) == 0x930u && DWC2_DTXFSTS(0) == 0x918u,
            "RM0383 22.16.6: DIEPCTLx, DIEPTSIZx, DTXFSTSx");
DWC2_ASSERT(DWC2_DOEPCTL(1) == 0xB20u && DWC2_DOEPINT(0) == 0xB08u && DWC2_DOEPTSIZ(0) == 0xB10u,
            "RM0383 22.16.6: DOEPCTLx, DOEPINTx, DOEPTSIZx");
DWC2_ASSERT(DWC2_PCGCCTL == 0xE00u && DWC2_FIFO(1) == 0x2000u, "RM0383 22.16.6: PCGCCTL, FIFO windows");

/* Size of the core's register window, FIFO windows included (the model maps this much). */
#define DWC2_WINDOW_SIZE 0x20000u
/* Data FIFO RAM of the F411's OTG_FS core: 1.25 KB = 320 32-bit words (RM0383 22.11). This is the figure to
 * size the FIFOs from; GHWCFG3's field is not to be trusted for it. */
#define DWC2_FIFO_WORDS 320u

#define DWC2_GAHBCFG_GINTMSK (1u << 0)
#define DWC2_GUSBCFG_PHYSEL (1u << 6)
#define DWC2_GUSBCFG_TRDT_POS 10u
#define DWC2_GUSBCFG_FDMOD (1u << 30)
#define DWC2_GRSTCTL_CSRST (1u << 0)
#define DWC2_GRSTCTL_RXFFLSH (1u << 4)
#define DWC2_GRSTCTL_TXFFLSH (1u << 5)
#define DWC2_GRSTCTL_TXFNUM_ALL (0x10u << 6)
#define DWC2_GRSTCTL_AHBIDL (1u << 31)
#define DWC2_GINTSTS_CMOD (1u << 0)
#define DWC2_GINTSTS_OTGINT (1u << 2)
#define DWC2_GINTSTS_SOF (1u << 3)
#define DWC2_GINTSTS_RXFLVL (1u << 4)
#define DWC2_GINTSTS_USBSUSP (1u << 11)
#define DWC2_GINTSTS_USBRST (1u << 12)
#define DWC2_GINTSTS_ENUMDNE (1u << 13)
#define DWC2_GINTSTS_IEPINT (1u << 18)
#define DWC2_GINTSTS_OEPINT (1u << 19)
#define DWC2_GINTSTS_SRQINT (1u << 30)
#define DWC2_GINTSTS_WKUPINT (1u << 31)
/* GRXSTSP fields (device mode). */
#define DWC2_GRXSTS_EPNUM(v) ((v)&0xFu)
#define DWC2_GRXSTS_BCNT(v) (((v) >> 4) & 0x7FFu)
#define DWC2_GRXSTS_PKTSTS(v) (((v) >> 17) & 0xFu)
#define DWC2_PKTSTS_GLOBAL_OUT_NAK 1u
#define DWC2_PKTSTS_OUT_DATA 2u
#define DWC2_PKTSTS_OUT_DONE 3u
#define DWC2_PKTSTS_SETUP_DONE 4u
#define DWC2_PKTSTS_SETUP_DATA 6u
#define DWC2_GCCFG_PWRDWN (1u << 16) /* 1 = transceiver on */
#define DWC2_GCCFG_VBUSASEN (1u << 18)
#define DWC2_GCCFG_VBUSBSEN (1u << 19)
#define DWC2_GCCFG_NOVBUSSENS (1u << 21)
#define DWC2_DCFG_DSPD_FS (3u << 0)
#define DWC2_DCFG_DAD_POS 4u
#define DWC2_DCFG_DAD_MASK (0x7Fu << 4)
#define DWC2_DCTL_SDIS (1u << 1)
#define DWC2_DCTL_CGINAK (1u << 8)
#define DWC2_DCTL_CGONAK (1u << 10)
/* DIEPCTLx / DOEPCTLx */
#define DWC2_EPCTL_MPSIZ_MASK 0x7FFu /* EP0: 2 bits, 00 = 64 bytes */
#define DWC2_EPCTL_USBAEP (1u << 15)
#define DWC2_EPCTL_NAKSTS (1u << 17)
#define DWC2_EPCTL_EPTYP_POS 18u
#define DWC2_EPCTL_EPTYP_BULK (2u << 18)
#define DWC2_EPCTL_STALL (1u << 21)
#define DWC2_EPCTL_TXFNUM_POS 22u
#define DWC2_EPCTL_CNAK (1u << 26)
#define DWC2_EPCTL_SNAK (1u << 27)
#define DWC2_EPCTL_SD0PID (1u << 28)
#define DWC2_EPCTL_EPDIS (1u << 30)
#define DWC2_EPCTL_EPENA (1u << 31)
/* DIEPINTx / DOEPINTx */
#define DWC2_EPINT_XFRC (1u << 0)
#define DWC2_EPINT_EPDISD (1u << 1)
#define DWC2_DOEPINT_STUP (1u << 3)
#define DWC2_DOEPINT_OTEPDIS (1u << 4)
#define DWC2_DOEPINT_B2BSTUP (1u << 6)
#define DWC2_DIEPINT_TOC (1u << 3)
#define DWC2_DIEPINT_TXFE (1u << 7)
/* DIEPTSIZx / DOEPTSIZx */
#define DWC2_TSIZ_XFRSIZ_MASK 0x7FFFFu /* EP0: 7 bits */
#define DWC2_TSIZ_PKTCNT_POS 19u
#define DWC2_TSIZ_PKTCNT_MASK (0x3FFu << 19) /* EP0 IN: 2 bits, EP0 OUT: 1 bit */
#define DWC2_DOEPTSIZ0_STUPCNT_POS 29u
#define DWC2_DOEPTSIZ0_STUPCNT_MASK (3u << 29)

#endif /* ROTOSCAN_FIRMWARE_DWC2_REGS_H_ */

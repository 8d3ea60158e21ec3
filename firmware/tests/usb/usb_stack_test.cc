// The firmware's USB device stack (firmware/usb: dcd_dwc2.c, usbd.c, usb_link.c) driven through a
// register-level model of the DWC2 core (dwc2_model.c) by a host that replays what Linux sends at enumeration,
// then bulk traffic. The core's link queues (fw_usb_rx / fw_usb_tx) are replaced by test queues here, so that
// byte counts (whole multiples of 64 for the zero-length packets, a full receive queue) are exact.
#include <gtest/gtest.h>

#include <cstdint>
#include <cstring>
#include <deque>
#include <string>
#include <vector>

extern "C" {
#include "dcd.h"
#include "dwc2_model.h"
#include "usb_link.h"
#include "usbd.h"
}

namespace {

dwc2_model_t* g_model = nullptr;
std::deque<uint8_t> g_rx;  // what fw_usb_rx took (the core's receive queue)
size_t g_rx_room = 1u << 20;
std::deque<uint8_t> g_tx;  // what the core wants to send

}  // namespace

extern "C" {
uint32_t dwc2_io_read(uint32_t offset) {
  return dwc2_model_read(g_model, offset);
}
void dwc2_io_write(uint32_t offset, uint32_t value) {
  dwc2_model_write(g_model, offset, value);
}
size_t fw_usb_rx(const uint8_t* data, size_t len) {
  const size_t n = len < g_rx_room - g_rx.size() ? len : g_rx_room - g_rx.size();
  g_rx.insert(g_rx.end(), data, data + n);
  return n;
}
size_t fw_usb_tx(uint8_t* out, size_t max) {
  size_t n = 0;
  while (n < max && !g_tx.empty()) {
    out[n++] = g_tx.front();
    g_tx.pop_front();
  }
  return n;
}
size_t fw_usb_tx_pending(void) {
  return g_tx.size();
}
}

namespace {

using Bytes = std::vector<uint8_t>;

constexpr uint8_t kUid[12] = {0x10, 0x32, 0x54, 0x76, 0x98, 0xBA, 0xDC, 0xFE, 0x01, 0x23, 0x45, 0x67};

struct ControlResult {
  bool stalled = false;
  Bytes data;
};

class UsbStack : public ::testing::Test {
 protected:
  void SetUp() override {
    g_model = dwc2_model_create();
    ASSERT_NE(g_model, nullptr);
    g_rx.clear();
    g_tx.clear();
    g_rx_room = 1u << 20;
    usb_link_init(kUid);
    ASSERT_EQ(dcd_init(), 0);
    EXPECT_FALSE(dwc2_model_connected(g_model)) << "connected before dcd_connect";
    dcd_connect();
    ASSERT_TRUE(dwc2_model_connected(g_model)) << "no D+ pull-up: VBUS sensing not set for this board";
  }
  void TearDown() override {
    EXPECT_EQ(dwc2_model_error(g_model), nullptr) << dwc2_model_error(g_model);
    dwc2_model_destroy(g_model);
    g_model = nullptr;
  }

  // The USB interrupt handler, run while the core's interrupt line is up, then once more if the main loop
  // would kick it (usb_link_wants_service: bytes to send, or bytes held back from a full receive queue).
  void Service() {
    for (int pass = 0; pass < 2; ++pass) {
      for (int i = 0; dwc2_model_irq(g_model); ++i) {
        if (i == 100) {
          FAIL() << "interrupt line still up after 100 handler runs";
        }
        dcd_irq();
      }
      if (pass == 0 && usb_link_wants_service()) usb_link_service();
    }
  }

  void Reset() {
    dwc2_model_bus_reset(g_model);
    Service();
    address_ = 0;
  }

  // One IN transaction, retried on NAK as a host does (a device that NAKs forever is a hang: fails).
  int In(uint8_t ep, Bytes* packet, size_t max = 64) {
    uint8_t buf[64];
    for (int tries = 0; tries < 50; ++tries) {
      size_t n = 0;
      const int r = dwc2_model_in(g_model, address_, ep, buf, max, &n);
      if (r == DWC2_MODEL_NAK) {
        Service();
        continue;
      }
      if (r == DWC2_MODEL_ACK) packet->assign(buf, buf + n);
      return r;
    }
    ADD_FAILURE() << "endpoint " << int(ep) << " NAKs an IN forever";
    return DWC2_MODEL_NAK;
  }
  int Out(uint8_t ep, const Bytes& data) {
    for (int tries = 0; tries < 50; ++tries) {
      const int r = dwc2_model_out(g_model, address_, ep, data.data(), data.size());
      if (r != DWC2_MODEL_NAK) {
        Service();
        return r;
      }
      Service();
    }
    ADD_FAILURE() << "endpoint " << int(ep) << " NAKs an OUT forever";
    return DWC2_MODEL_NAK;
  }

  // A whole control transfer as the host runs it: SETUP, data stage (IN: until a short packet or wLength),
  // status stage.
  ControlResult Control(uint8_t bm, uint8_t req, uint16_t value, uint16_t index, uint16_t length) {
    const uint8_t setup[8] = {bm,
                              req,
                              uint8_t(value & 0xFF),
                              uint8_t(value >> 8),
                              uint8_t(index & 0xFF),
                              uint8_t(index >> 8),
                              uint8_t(length & 0xFF),
                              uint8_t(length >> 8)};
    ControlResult res;
    EXPECT_EQ(dwc2_model_setup(g_model, address_, setup), DWC2_MODEL_ACK);
    Service();
    if ((bm & 0x80) && length > 0) {
      for (;;) {
        Bytes packet;
        const int r = In(0, &packet);
        if (r == DWC2_MODEL_STALL) {
          res.stalled = true;
          return res;
        }
        if (r != DWC2_MODEL_ACK) {
          ADD_FAILURE() << "data stage: result " << r;
          return res;
        }
        Service();
        res.data.insert(res.data.end(), packet.begin(), packet.end());
        if (packet.size() < 64 || res.data.size() >= length) break;
      }
      const int r = Out(0, {});
      if (r == DWC2_MODEL_STALL) res.stalled = true;
      EXPECT_TRUE(r == DWC2_MODEL_ACK || r == DWC2_MODEL_STALL) << "status stage: " << r;
      return res;
    }
    Bytes zlp;
    const int r = In(0, &zlp);
    if (r == DWC2_MODEL_STALL) {
      res.stalled = true;
    } else {
      EXPECT_EQ(r, DWC2_MODEL_ACK);
      EXPECT_TRUE(zlp.empty()) << "status stage must be a zero-length packet";
    }
    Service();
    return res;
  }
  ControlResult GetDescriptor(uint8_t type, uint8_t index, uint16_t length, uint16_t lang = 0) {
    return Control(0x80, 6, uint16_t(type << 8 | index), lang, length);
  }

  // Linux's enumeration (drivers/usb/core/hub.c, hub_port_init with the "new scheme", then usb_new_device).
  void Enumerate() {
    Reset();
    const ControlResult first = GetDescriptor(1, 0, 64);  // at address 0, 64 bytes asked
    ASSERT_FALSE(first.stalled);
    ASSERT_EQ(first.data.size(), 18u);
    Reset();
    ASSERT_FALSE(Control(0x00, 5, 7, 0, 0).stalled);  // SET_ADDRESS 7
    address_ = 7;
    EXPECT_EQ(dwc2_model_address(g_model), 7) << "the core is not at the new address after the status stage";
    const ControlResult dev = GetDescriptor(1, 0, 18);
    ASSERT_FALSE(dev.stalled);
    device_ = dev.data;
    EXPECT_TRUE(GetDescriptor(15, 0, 5).stalled) << "BOS: none on a USB 2.00 device";
    EXPECT_TRUE(GetDescriptor(6, 0, 10).stalled) << "device qualifier: a full-speed-only device must stall";
    const ControlResult head = GetDescriptor(2, 0, 9);
    ASSERT_EQ(head.data.size(), 9u);
    const uint16_t total = uint16_t(head.data[2] | head.data[3] << 8);
    const ControlResult config = GetDescriptor(2, 0, total);
    config_ = config.data;
    ASSERT_EQ(config_.size(), total);
    const ControlResult langs = GetDescriptor(3, 0, 255);
    ASSERT_EQ(langs.data, (Bytes{4, 3, 0x09, 0x04}));
    for (uint8_t i = 1; i <= 3; ++i) {
      const ControlResult s = GetDescriptor(3, i, 255, 0x0409);
      ASSERT_FALSE(s.stalled) << "string " << int(i);
      strings_.push_back(Utf16(s.data));
    }
    ASSERT_FALSE(Control(0x00, 9, 1, 0, 0).stalled);  // SET_CONFIGURATION 1
    ASSERT_EQ(usbd_configuration(), 1);
  }

  static std::string Utf16(const Bytes& d) {
    std::string s;
    EXPECT_GE(d.size(), 2u);
    EXPECT_EQ(d[0], d.size());
    EXPECT_EQ(d[1], 3);
    for (size_t i = 2; i + 1 < d.size(); i += 2) s.push_back(char(d[i]));
    return s;
  }

  // Reads bulk IN until a short packet (a zero-length one included), as a host read of `max` bytes does.
  Bytes BulkRead(size_t max, int* packets = nullptr, bool* ended_by_zlp = nullptr) {
    Bytes all;
    int count = 0;
    for (;;) {
      Bytes packet;
      if (In(1, &packet) != DWC2_MODEL_ACK) break;
      ++count;
      Service();
      all.insert(all.end(), packet.begin(), packet.end());
      if (ended_by_zlp != nullptr) *ended_by_zlp = packet.empty();
      if (packet.size() < 64 || all.size() >= max) break;
    }
    if (packets != nullptr) *packets = count;
    return all;
  }

  uint8_t address_ = 0;
  Bytes device_;
  Bytes config_;
  std::vector<std::string> strings_;
};

TEST_F(UsbStack, LinuxEnumerationSequence) {
  Enumerate();
  // Device descriptor: what host/lib/include/rotoscan/device/usb_ids.h expects (VID 0x1209, PID 0x0001).
  ASSERT_EQ(device_.size(), 18u);
  EXPECT_EQ(device_[1], 1);
  EXPECT_EQ(device_[2] | device_[3] << 8, 0x0200);
  EXPECT_EQ(device_[7], 64);
  EXPECT_EQ(device_[8] | device_[9] << 8, 0x1209);
  EXPECT_EQ(device_[10] | device_[11] << 8, 0x0001);
  EXPECT_EQ(device_[17], 1);
  // Configuration: one vendor-class interface, bulk OUT 0x01 and bulk IN 0x81 of 64 bytes.
  ASSERT_EQ(config_.size(), 32u);
  EXPECT_EQ(config_[9 + 5], 0xFF);
  EXPECT_EQ(config_[9 + 4], 2);
  EXPECT_EQ(config_[18 + 2], 0x01);
  EXPECT_EQ(config_[18 + 3], 2);
  EXPECT_EQ(config_[25 + 2], 0x81);
  EXPECT_EQ(config_[25 + 4], 64);
  ASSERT_EQ(strings_.size(), 3u);
  EXPECT_EQ(strings_[0], "Rotoscan");
  EXPECT_EQ(strings_[1], "Rotoscan scanner board");
  EXPECT_EQ(strings_[2], "1032547698BADCFE01234567");  // the unique id, byte by byte in hex
  EXPECT_EQ(usbd_stalls(), 2u);                          // BOS and device qualifier
}

TEST_F(UsbStack, StandardRequestsAfterConfiguration) {
  Enumerate();
  EXPECT_EQ(Control(0x80, 8, 0, 0, 1).data, Bytes{1});          // GET_CONFIGURATION
  EXPECT_EQ(Control(0x80, 0, 0, 0, 2).data, (Bytes{0, 0}));     // GET_STATUS device
  EXPECT_EQ(Control(0x81, 0, 0, 0, 2).data, (Bytes{0, 0}));     // GET_STATUS interface
  EXPECT_EQ(Control(0x82, 0, 0, 0x81, 2).data, (Bytes{0, 0}));  // GET_STATUS endpoint: not halted
  EXPECT_EQ(Control(0x81, 10, 0, 0, 1).data, Bytes{0});         // GET_INTERFACE
  EXPECT_FALSE(Control(0x01, 11, 0, 0, 0).stalled);             // SET_INTERFACE 0, alt 0
  // SET_FEATURE(ENDPOINT_HALT) on bulk IN: the endpoint stalls until CLEAR_FEATURE(ENDPOINT_HALT).
  EXPECT_FALSE(Control(0x02, 3, 0, 0x81, 0).stalled);
  EXPECT_EQ(Control(0x82, 0, 0, 0x81, 2).data, (Bytes{1, 0}));
  g_tx.assign({1, 2, 3});
  uint8_t buf[64];
  size_t n = 0;
  EXPECT_EQ(dwc2_model_in(g_model, address_, 1, buf, sizeof(buf), &n), DWC2_MODEL_STALL);
  EXPECT_FALSE(Control(0x02, 1, 0, 0x81, 0).stalled);
  EXPECT_EQ(Control(0x82, 0, 0, 0x81, 2).data, (Bytes{0, 0}));
  Service();
  EXPECT_EQ(BulkRead(512), (Bytes{1, 2, 3}));
  // The vendor request: the firmware version.
  EXPECT_EQ(Control(0xC0, USB_LINK_REQ_VERSION, 0, 0, 3).data.size(), 3u);
}

// A bus reset (a re-plug of the self-powered board) flushes the transmit FIFO: the packet that was in flight,
// never acknowledged, is sent again once the host has configured the board again, before anything newer.
// Found by the emulator test of issue 18 (an event lost at every re-plug).
TEST_F(UsbStack, PacketInFlightAtABusResetIsSentAgain) {
  Enumerate();
  g_tx.assign({10, 11, 12, 13});
  Service();  // the packet is in the transmit FIFO, the host has not read it
  g_tx.assign({20, 21});
  Enumerate();  // bus reset, enumeration, SET_CONFIGURATION 1
  EXPECT_EQ(BulkRead(512), (Bytes{10, 11, 12, 13}));
  Service();
  EXPECT_EQ(BulkRead(512), (Bytes{20, 21}));
}

TEST_F(UsbStack, MalformedAndUnexpectedRequestsStall) {
  Enumerate();
  const uint32_t before = usbd_stalls();
  struct Case {
    uint8_t bm, req;
    uint16_t value, index, length;
    const char* what;
  };
  const Case cases[] = {
      {0x80, 6, 0x0400, 0, 9, "GET_DESCRIPTOR interface (not standalone)"},
      {0x80, 6, 0x0304, 0x0409, 255, "string index 4: none"},
      {0x80, 6, 0x0301, 0x0407, 255, "string in a language we do not have"},
      {0x80, 6, 0x0201, 0, 9, "configuration index 1: only one"},
      {0x80, 6, 0x0100, 0, 0, "GET_DESCRIPTOR with wLength 0"},
      {0x00, 6, 0x0100, 0, 18, "GET_DESCRIPTOR host-to-device"},
      {0x00, 9, 2, 0, 0, "SET_CONFIGURATION 2"},
      {0x00, 5, 200, 0, 0, "SET_ADDRESS 200 (> 127)"},
      {0x00, 5, 3, 0, 0, "SET_ADDRESS while configured"},
      {0x80, 0, 0, 0, 4, "GET_STATUS wLength 4"},
      {0x82, 0, 0, 0x85, 2, "GET_STATUS of an endpoint we do not have"},
      {0x02, 1, 0, 0x02, 0, "CLEAR_FEATURE(ENDPOINT_HALT) of an endpoint we do not have"},
      {0x02, 1, 1, 0x81, 0, "CLEAR_FEATURE of a feature other than ENDPOINT_HALT"},
      {0x01, 11, 1, 0, 0, "SET_INTERFACE alternate 1"},
      {0x80, 0x33, 0, 0, 8, "unknown standard request"},
      {0xA1, 0x01, 0, 0, 8, "class request"},
      {0xC0, 0x7E, 0, 0, 8, "unknown vendor request"},
      {0x40, USB_LINK_REQ_VERSION, 0, 0, 0, "the version request host-to-device"},
      {0xC0, USB_LINK_REQ_VERSION, 0, 0, 0, "the version request with wLength 0"},
      {0x40, 0x01, 0, 0, 16, "vendor OUT with a data stage"},
  };
  uint32_t expected = before;
  for (const Case& c : cases) {
    const uint8_t setup[8] = {c.bm,
                              c.req,
                              uint8_t(c.value),
                              uint8_t(c.value >> 8),
                              uint8_t(c.index),
                              uint8_t(c.index >> 8),
                              uint8_t(c.length),
                              uint8_t(c.length >> 8)};
    ASSERT_EQ(dwc2_model_setup(g_model, address_, setup), DWC2_MODEL_ACK) << c.what;
    Service();
    Bytes packet;
    // Whatever stage the host goes to next, the device answers STALL.
    if (c.bm & 0x80) {
      EXPECT_EQ(In(0, &packet), DWC2_MODEL_STALL) << c.what;
    } else if (c.length > 0) {
      EXPECT_EQ(Out(0, Bytes(8, 0xAA)), DWC2_MODEL_STALL) << c.what;
    } else {
      EXPECT_EQ(In(0, &packet), DWC2_MODEL_STALL) << c.what;
    }
    EXPECT_EQ(usbd_stalls(), ++expected) << c.what;
  }
  // A stall lasts until the next SETUP: the device still enumerates and answers afterwards.
  EXPECT_EQ(GetDescriptor(1, 0, 18).data.size(), 18u);
  EXPECT_EQ(usbd_configuration(), 1);
}

TEST_F(UsbStack, BackToBackSetupsOnlyTheLastCounts) {
  Reset();
  // The host sent a SETUP, lost the ACK and sent another before the device ran: GET_DESCRIPTOR(config),
  // then GET_DESCRIPTOR(device). Only the second must be answered.
  const uint8_t config_req[8] = {0x80, 6, 0, 2, 0, 0, 9, 0};
  const uint8_t device_req[8] = {0x80, 6, 0, 1, 0, 0, 18, 0};
  ASSERT_EQ(dwc2_model_setup(g_model, 0, config_req), DWC2_MODEL_ACK);
  ASSERT_EQ(dwc2_model_setup(g_model, 0, device_req), DWC2_MODEL_ACK);
  Service();
  Bytes packet;
  ASSERT_EQ(In(0, &packet), DWC2_MODEL_ACK);
  ASSERT_EQ(packet.size(), 18u);
  EXPECT_EQ(packet[1], 1) << "answered the first SETUP";
  Service();
  EXPECT_EQ(Out(0, {}), DWC2_MODEL_ACK);
  // And a third, after three in a row: STUPCNT was re-armed.
  for (int i = 0; i < 3; ++i) ASSERT_EQ(dwc2_model_setup(g_model, 0, config_req), DWC2_MODEL_ACK);
  Service();
  ASSERT_EQ(In(0, &packet), DWC2_MODEL_ACK);
  EXPECT_EQ(packet.size(), 9u);
}

TEST_F(UsbStack, BulkInZeroLengthPacketAfterWholeMultipleOf64) {
  Enumerate();
  for (size_t size : {1u, 63u, 64u, 65u, 128u, 200u, 256u}) {
    Bytes data(size);
    for (size_t i = 0; i < size; ++i) data[i] = uint8_t(i * 7 + size);
    g_tx.assign(data.begin(), data.end());
    Service();
    int packets = 0;
    bool zlp = false;
    const Bytes got = BulkRead(4096, &packets, &zlp);
    EXPECT_EQ(got, data) << size;
    EXPECT_EQ(zlp, size % 64 == 0) << size << " bytes: zero-length packet";
    EXPECT_EQ(packets, int(size / 64 + 1)) << size;
    // Nothing more: the endpoint NAKs (no stray zero-length packet).
    size_t n = 1;
    uint8_t buf[64];
    EXPECT_EQ(dwc2_model_in(g_model, address_, 1, buf, sizeof(buf), &n), DWC2_MODEL_NAK) << size;
  }
}

TEST_F(UsbStack, BulkOutWithFlowControl) {
  Enumerate();
  Bytes sent;
  for (int p = 0; p < 5; ++p) {
    Bytes packet(p == 4 ? 10 : 64);
    for (size_t i = 0; i < packet.size(); ++i) packet[i] = uint8_t(p * 64 + i);
    ASSERT_EQ(Out(1, packet), DWC2_MODEL_ACK);
    sent.insert(sent.end(), packet.begin(), packet.end());
  }
  EXPECT_EQ(Bytes(g_rx.begin(), g_rx.end()), sent);
  // A full receive queue: the endpoint NAKs until the core has room, and nothing is lost.
  g_rx.clear();
  g_rx_room = 100;
  ASSERT_EQ(Out(1, Bytes(64, 0x11)), DWC2_MODEL_ACK);
  Service();
  ASSERT_EQ(Out(1, Bytes(64, 0x22)), DWC2_MODEL_ACK);  // 36 of these taken, 28 held back
  Service();
  EXPECT_EQ(g_rx.size(), 100u);
  EXPECT_EQ(dwc2_model_out(g_model, address_, 1, Bytes(64, 0x33).data(), 64), DWC2_MODEL_NAK);
  g_rx.erase(g_rx.begin(), g_rx.begin() + 64);  // the core reads 64 bytes
  Service();                                     // the main loop's kick delivers the 28 held back
  EXPECT_EQ(g_rx.size(), 64u);
  EXPECT_EQ(dwc2_model_out(g_model, address_, 1, Bytes(8, 0x33).data(), 8), DWC2_MODEL_ACK);
  Service();
  EXPECT_EQ(g_rx.size(), 72u);
  EXPECT_EQ(g_rx.back(), 0x33);
}

TEST_F(UsbStack, BusResetUnconfigures) {
  Enumerate();
  g_tx.assign(10, 0x5A);
  Reset();
  EXPECT_EQ(usbd_configuration(), 0);
  EXPECT_EQ(usbd_address(), 0);
  EXPECT_EQ(dwc2_model_address(g_model), 0);
  // Bulk endpoints are gone until configured again.
  uint8_t buf[64];
  size_t n = 0;
  EXPECT_EQ(dwc2_model_in(g_model, 0, 1, buf, sizeof(buf), &n), DWC2_MODEL_NO_ANSWER);
  Enumerate();
  EXPECT_EQ(BulkRead(512).size(), 10u);
}

}  // namespace

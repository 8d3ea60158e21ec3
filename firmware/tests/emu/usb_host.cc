// See usb_host.h.
#include "usb_host.h"

namespace rotoscan::fw_emu {

namespace {
constexpr uint64_t kControlTimeoutUs = 50000;  // USB 2.0 9.2.6.4: 50 ms for a control request's data stage
}

int UsbHost::In(uint8_t ep, Bytes* packet, size_t max, uint64_t timeout_us) {
  uint8_t buf[64];
  for (uint64_t waited = 0;; waited += retry_us) {
    size_t n = 0;
    const int r = dwc2_model_in(emu_->usb(), address_, ep, buf, max < 64 ? max : 64, &n);
    if (r == DWC2_MODEL_ACK) packet->assign(buf, buf + n);
    if (r != DWC2_MODEL_NAK) {
      if (!emu_->RunUs(retry_us)) error_ = emu_->error();
      return r;
    }
    if (waited >= timeout_us) return r;
    if (!emu_->RunUs(retry_us)) {
      error_ = emu_->error();
      return DWC2_MODEL_NO_ANSWER;
    }
  }
}

int UsbHost::Out(uint8_t ep, const uint8_t* data, size_t size, uint64_t timeout_us) {
  for (uint64_t waited = 0;; waited += retry_us) {
    const int r = dwc2_model_out(emu_->usb(), address_, ep, data, size);
    if (!emu_->RunUs(retry_us)) {
      error_ = emu_->error();
      return DWC2_MODEL_NO_ANSWER;
    }
    if (r != DWC2_MODEL_NAK || waited >= timeout_us) return r;
  }
}

UsbHost::Control UsbHost::ControlTransfer(uint8_t bm, uint8_t req, uint16_t value, uint16_t index,
                                          uint16_t length) {
  Control c;
  const uint8_t setup[8] = {bm,
                            req,
                            uint8_t(value),
                            uint8_t(value >> 8),
                            uint8_t(index),
                            uint8_t(index >> 8),
                            uint8_t(length),
                            uint8_t(length >> 8)};
  if (dwc2_model_setup(emu_->usb(), address_, setup) != DWC2_MODEL_ACK) {
    c.error = "SETUP not acknowledged";
    return c;
  }
  if (!emu_->RunUs(retry_us)) {
    c.error = emu_->error();
    return c;
  }
  if ((bm & 0x80) && length > 0) {
    for (;;) {
      Bytes packet;
      const int r = In(0, &packet, 64, kControlTimeoutUs);
      if (r == DWC2_MODEL_STALL) {
        c.stalled = true;
        return c;
      }
      if (r != DWC2_MODEL_ACK) {
        c.error = error_.empty() ? "data stage: no answer (" + std::to_string(r) + ")" : error_;
        return c;
      }
      c.data.insert(c.data.end(), packet.begin(), packet.end());
      if (packet.size() < 64 || c.data.size() >= length) break;
    }
    const int r = Out(0, nullptr, 0, kControlTimeoutUs);
    c.stalled = r == DWC2_MODEL_STALL;
    c.ok = r == DWC2_MODEL_ACK;
    if (!c.ok && !c.stalled) c.error = "status stage: " + std::to_string(r);
    return c;
  }
  Bytes zlp;
  const int r = In(0, &zlp, 64, kControlTimeoutUs);
  c.stalled = r == DWC2_MODEL_STALL;
  c.ok = r == DWC2_MODEL_ACK && zlp.empty();
  if (!c.ok && !c.stalled) c.error = error_.empty() ? "status stage: " + std::to_string(r) : error_;
  return c;
}

UsbHost::Enumeration UsbHost::Enumerate(uint8_t address) {
  Enumeration e;
  auto fail = [&](const std::string& what, const Control& c) {
    e.error = what + (c.stalled ? ": stalled" : ": " + c.error);
    return e;
  };
  // The hub sees D+ pulled up (USB 2.0 7.1.7.3: the host then waits 100 ms before the reset).
  for (int i = 0; i < 1000 && !dwc2_model_connected(emu_->usb()); ++i) {
    if (!emu_->RunUs(1000)) {
      e.error = emu_->error();
      return e;
    }
  }
  if (!dwc2_model_connected(emu_->usb())) {
    e.error = "the device never connected (no D+ pull-up within 1 s)";
    return e;
  }
  address_ = 0;
  dwc2_model_bus_reset(emu_->usb());
  if (!emu_->RunUs(100)) return e.error = emu_->error(), e;
  const Control first = GetDescriptor(1, 0, 64);
  if (!first.ok || first.data.size() != 18)
    return fail("first device descriptor read (64 bytes at address 0)", first);
  dwc2_model_bus_reset(emu_->usb());
  if (!emu_->RunUs(100)) return e.error = emu_->error(), e;
  const Control set = ControlTransfer(0x00, 5, address, 0, 0);
  if (!set.ok) return fail("SET_ADDRESS", set);
  address_ = address;
  if (!emu_->RunUs(2000)) return e.error = emu_->error(), e;  // USB 2.0 9.2.6.3: 2 ms of recovery
  const Control dev = GetDescriptor(1, 0, 18);
  if (!dev.ok) return fail("device descriptor at the new address", dev);
  e.device = dev.data;
  const Control bos = GetDescriptor(15, 0, 5);
  if (!bos.stalled) return fail("BOS descriptor (a USB 2.00 device must stall it)", bos);
  const Control qualifier = GetDescriptor(6, 0, 10);
  if (!qualifier.stalled) return fail("device qualifier (a full-speed-only device must stall it)", qualifier);
  const Control head = GetDescriptor(2, 0, 9);
  if (!head.ok || head.data.size() != 9) return fail("configuration descriptor head", head);
  const uint16_t total = uint16_t(head.data[2] | head.data[3] << 8);
  const Control config = GetDescriptor(2, 0, total);
  if (!config.ok) return fail("whole configuration descriptor", config);
  e.configuration = config.data;
  const Control langs = GetDescriptor(3, 0, 255);
  if (!langs.ok || langs.data.size() < 4) return fail("string descriptor 0", langs);
  const uint16_t lang = uint16_t(langs.data[2] | langs.data[3] << 8);
  for (uint8_t index : {e.device[14], e.device[15], e.device[16]}) {
    const Control s = GetDescriptor(3, index, 255, lang);
    if (!s.ok) return fail("string descriptor " + std::to_string(index), s);
    std::string text;
    for (size_t i = 2; i + 1 < s.data.size(); i += 2) text.push_back(char(s.data[i]));
    e.strings.push_back(text);
  }
  const Control configure = ControlTransfer(0x00, 9, 1, 0, 0);
  if (!configure.ok) return fail("SET_CONFIGURATION 1", configure);
  e.ok = true;
  return e;
}

bool UsbHost::BulkOut(uint8_t ep, const uint8_t* data, size_t size, uint64_t timeout_us) {
  for (size_t at = 0; at < size; at += 64) {
    const size_t n = size - at < 64 ? size - at : 64;
    const int r = Out(ep, data + at, n, timeout_us);
    if (r != DWC2_MODEL_ACK) {
      if (error_.empty()) error_ = "bulk OUT: result " + std::to_string(r);
      return false;
    }
  }
  return true;
}

bool UsbHost::BulkIn(uint8_t ep, size_t max, Bytes* out) {
  out->clear();
  while (out->size() + 64 <= max) {
    Bytes packet;
    const int r = In(ep, &packet, 64, 0);
    if (r == DWC2_MODEL_NAK) return true;
    if (r != DWC2_MODEL_ACK) {
      if (error_.empty()) error_ = "bulk IN: result " + std::to_string(r);
      return false;
    }
    out->insert(out->end(), packet.begin(), packet.end());
    if (packet.size() < 64) return true;
  }
  return true;
}

}  // namespace rotoscan::fw_emu

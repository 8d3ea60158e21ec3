// libusb implementation of Transport.
//
// Design notes:
//  * One libusb context per transport, and one private event thread that calls
//    libusb_handle_events_timeout_completed() until Close(). All transfer callbacks run on that thread.
//  * `in_transfers` bulk IN transfers are submitted at Open() and each is resubmitted from its own callback
//    as soon as its bytes are queued, so the endpoint always has a transfer waiting: bytes the board sends
//    while the caller is busy end up in `received_`, never dropped (the board's USB FIFO is not read only
//    when every transfer is in its callback, for microseconds).
//  * Writes use the synchronous libusb_bulk_transfer(), which libusb allows beside an event thread.
//  * Unplug: an IN transfer that ends with NO_DEVICE (or any error other than a cancel) marks the transport
//    gone; Read() then reports DeviceError after the queued bytes, and Open() finds the board anew by its ids
//    (the board gets a new address when re-plugged), or by its serial number when several are attached.
//  * Close(): cancel every IN transfer, wait (on the event thread's progress) until each callback has seen
//    its cancel, then stop the thread, release the interface and close the handle. Bytes that completed
//    meanwhile (an unplugged board's last transfers are reaped after the disconnect) are kept for the
//    next Open(): the client re-opens a re-plugged board and its stream goes on without a hole.
#include <libusb.h>

#include <algorithm>
#include <atomic>
#include <cctype>
#include <chrono>
#include <condition_variable>
#include <cstdio>
#include <cstring>
#include <fstream>
#include <mutex>
#include <sstream>
#include <thread>

#include "rotoscan/core/check.h"
#include "rotoscan/core/logging.h"
#include "rotoscan/device/transport.h"

namespace rotoscan::device {

Status LibusbTransportOptions::Check() const {
  if (in_transfers < 2) return InvalidArgumentError("libusb transport: in_transfers must be >= 2");
  if (in_transfer_size < kUsbMaxPacketSize || in_transfer_size % kUsbMaxPacketSize != 0) {
    return InvalidArgumentError("libusb transport: in_transfer_size must be a positive multiple of " +
                                std::to_string(kUsbMaxPacketSize));
  }
  if (write_timeout_ms <= 0) return InvalidArgumentError("libusb transport: write_timeout_ms must be > 0");
  if (bus < 0 || address < 0) return InvalidArgumentError("libusb transport: bus and address must be >= 0");
  return Status::Ok();
}

namespace {

std::string UsbError(int code) {
  return std::string(libusb_error_name(code));
}

std::string PortPath(libusb_device* dev) {
  uint8_t ports[8];
  const int n = libusb_get_port_numbers(dev, ports, sizeof(ports));
  std::ostringstream s;
  s << static_cast<int>(libusb_get_bus_number(dev));
  for (int i = 0; i < n; ++i) s << (i == 0 ? "-" : ".") << static_cast<int>(ports[i]);
  return s.str();
}

// The device's USB serial number string as the kernel read it at enumeration (sysfs), empty when it has
// none or sysfs is not there: opening the device to ask would disturb a board another program uses.
std::string SysfsSerial(libusb_device* dev) {
  std::ifstream in("/sys/bus/usb/devices/" + PortPath(dev) + "/serial");
  std::string serial;
  std::getline(in, serial);
  return serial;
}

bool SameSerial(const std::string& a, const std::string& b) {
  return a.size() == b.size() && std::equal(a.begin(), a.end(), b.begin(), [](char x, char y) {
           return std::tolower(static_cast<unsigned char>(x)) == std::tolower(static_cast<unsigned char>(y));
         });
}

class LibusbTransport final : public Transport {
 public:
  LibusbTransport(libusb_context* context, const LibusbTransportOptions& options)
      : context_(context), options_(options) {}
  ~LibusbTransport() override {
    Close();
    libusb_exit(context_);
  }
  LibusbTransport(const LibusbTransport&) = delete;
  LibusbTransport& operator=(const LibusbTransport&) = delete;

  Status Open() override {
    Close();
    libusb_device** list = nullptr;
    const ssize_t count = libusb_get_device_list(context_, &list);
    if (count < 0) return IoError("listing USB devices: " + UsbError(static_cast<int>(count)));
    libusb_device* found = nullptr;
    for (ssize_t i = 0; i < count; ++i) {
      libusb_device_descriptor desc;
      if (libusb_get_device_descriptor(list[i], &desc) != 0) continue;
      if (desc.idVendor != options_.vendor_id || desc.idProduct != options_.product_id) continue;
      if (options_.bus != 0 && libusb_get_bus_number(list[i]) != options_.bus) continue;
      if (options_.address != 0 && libusb_get_device_address(list[i]) != options_.address) continue;
      if (!options_.serial.empty() && !SameSerial(SysfsSerial(list[i]), options_.serial)) continue;
      found = list[i];
      break;
    }
    if (found == nullptr) {
      libusb_free_device_list(list, 1);
      return NotFoundError("no Rotoscan board found (USB " + IdString() +
                           (options_.serial.empty() ? "" : ", serial " + options_.serial) + ")");
    }
    std::ostringstream desc;
    desc << "usb " << IdString() << " bus " << static_cast<int>(libusb_get_bus_number(found)) << " address "
         << static_cast<int>(libusb_get_device_address(found));
    description_ = desc.str();
    const int open_result = libusb_open(found, &handle_);
    libusb_free_device_list(list, 1);
    if (open_result != 0) {
      handle_ = nullptr;
      return DeviceError("opening " + description_ + ": " + UsbError(open_result) +
                         (open_result == LIBUSB_ERROR_ACCESS
                              ? " (no permission on the device node: a udev rule must give your user "
                                "access to USB " +
                                    IdString() + ")"
                              : ""));
    }
    const int claim = libusb_claim_interface(handle_, kUsbInterface);
    if (claim != 0) {
      libusb_close(handle_);
      handle_ = nullptr;
      return DeviceError("claiming interface 0 of " + description_ + ": " + UsbError(claim));
    }
    gone_ = false;
    running_ = true;
    event_thread_ = std::thread([this] { EventLoop(); });
    for (int i = 0; i < options_.in_transfers; ++i) {
      InTransfer* in = new InTransfer;
      in->owner = this;
      in->buffer.resize(static_cast<size_t>(options_.in_transfer_size));
      in->transfer = libusb_alloc_transfer(0);
      libusb_fill_bulk_transfer(in->transfer, handle_, kUsbEndpointIn, in->buffer.data(),
                                options_.in_transfer_size, &LibusbTransport::OnIn, in, 0);
      const int submitted = libusb_submit_transfer(in->transfer);
      if (submitted != 0) {
        libusb_free_transfer(in->transfer);
        delete in;
        Close();
        return DeviceError("starting bulk IN on " + description_ + ": " + UsbError(submitted));
      }
      std::lock_guard<std::mutex> lock(mutex_);
      ++active_in_;
      in_flight_.push_back(in);
    }
    return Status::Ok();
  }

  void Close() override {
    if (handle_ == nullptr) return;
    {
      std::unique_lock<std::mutex> lock(mutex_);
      closing_ = true;
      for (InTransfer* in : in_flight_) libusb_cancel_transfer(in->transfer);
      // The event thread delivers the cancellations; a gone board may complete them with an error instead.
      cv_.wait_for(lock, std::chrono::seconds(2), [this] { return active_in_ == 0; });
      if (active_in_ != 0) {
        ROTOSCAN_LOG(kWarning) << description_ << ": IN transfers did not finish on close";
      }
    }
    running_ = false;
    libusb_interrupt_event_handler(context_);
    if (event_thread_.joinable()) event_thread_.join();
    {
      std::lock_guard<std::mutex> lock(mutex_);
      // A transfer libusb still holds cannot be freed: leak it rather than corrupt libusb's state.
      if (active_in_ == 0) {
        for (InTransfer* in : in_flight_) {
          libusb_free_transfer(in->transfer);
          delete in;
        }
      }
      in_flight_.clear();
      active_in_ = 0;
      closing_ = false;
      // received_ is kept: bytes that arrived while closing are read after the next Open().
    }
    libusb_release_interface(handle_, kUsbInterface);  // fails harmlessly on a gone board
    libusb_close(handle_);
    handle_ = nullptr;
  }

  bool IsOpen() const override { return handle_ != nullptr && !gone_; }

  Status Write(const std::vector<uint8_t>& bytes) override {
    if (handle_ == nullptr) return FailedPreconditionError("write to a closed transport");
    if (gone_) return DeviceError(description_ + ": the board is gone (unplugged?)");
    size_t sent = 0;
    while (sent < bytes.size()) {
      int done = 0;
      const int result = libusb_bulk_transfer(
          handle_, kUsbEndpointOut, const_cast<uint8_t*>(bytes.data() + sent),
          static_cast<int>(bytes.size() - sent), &done, static_cast<unsigned>(options_.write_timeout_ms));
      sent += static_cast<size_t>(done);
      if (result == LIBUSB_ERROR_TIMEOUT) {
        return TimeoutError(description_ + ": bulk OUT took longer than " +
                            std::to_string(options_.write_timeout_ms) + " ms");
      }
      if (result != 0) {
        if (result == LIBUSB_ERROR_NO_DEVICE || result == LIBUSB_ERROR_IO) gone_ = true;
        return DeviceError(description_ + ": bulk OUT failed: " + UsbError(result));
      }
    }
    return Status::Ok();
  }

  Status Read(std::vector<uint8_t>* bytes, int64_t timeout_us) override {
    ROTOSCAN_CHECK(bytes != nullptr);
    std::unique_lock<std::mutex> lock(mutex_);
    cv_.wait_for(lock, std::chrono::microseconds(std::max<int64_t>(timeout_us, 0)),
                 [this] { return !received_.empty() || gone_ || handle_ == nullptr; });
    if (!received_.empty()) {
      bytes->insert(bytes->end(), received_.begin(), received_.end());
      received_.clear();
      return Status::Ok();
    }
    if (handle_ == nullptr) return FailedPreconditionError("read from a closed transport");
    if (gone_) return DeviceError(description_ + ": the board is gone (unplugged?)");
    return Status::Ok();
  }

  int64_t NowUs() const override {
    return std::chrono::duration_cast<std::chrono::microseconds>(
               std::chrono::steady_clock::now().time_since_epoch())
        .count();
  }

  std::string Description() const override {
    return description_.empty() ? "usb " + IdString() : description_;
  }

 private:
  struct InTransfer {
    LibusbTransport* owner = nullptr;
    libusb_transfer* transfer = nullptr;
    std::vector<uint8_t> buffer;
  };

  std::string IdString() const {
    char text[16];
    std::snprintf(text, sizeof(text), "%04x:%04x", options_.vendor_id, options_.product_id);
    return text;
  }

  void EventLoop() {
    while (running_) {
      timeval tv{0, 20000};
      libusb_handle_events_timeout_completed(context_, &tv, nullptr);
    }
  }

  static void LIBUSB_CALL OnIn(libusb_transfer* transfer) {
    auto* in = static_cast<InTransfer*>(transfer->user_data);
    in->owner->HandleIn(in);
  }

  void HandleIn(InTransfer* in) {
    std::lock_guard<std::mutex> lock(mutex_);
    const libusb_transfer* t = in->transfer;
    if (t->status == LIBUSB_TRANSFER_COMPLETED) {
      received_.insert(received_.end(), in->buffer.begin(), in->buffer.begin() + t->actual_length);
      if (!closing_ && libusb_submit_transfer(in->transfer) == 0) {
        cv_.notify_all();
        return;
      }
    } else if (t->status == LIBUSB_TRANSFER_TIMED_OUT) {
      if (!closing_ && libusb_submit_transfer(in->transfer) == 0) return;
    } else if (t->status != LIBUSB_TRANSFER_CANCELLED || !closing_) {
      if (!gone_) {
        ROTOSCAN_LOG(kWarning) << description_ << ": bulk IN ended (status " << t->status << "): board gone";
      }
      gone_ = true;
    }
    --active_in_;
    cv_.notify_all();
  }

  libusb_context* context_;
  LibusbTransportOptions options_;
  libusb_device_handle* handle_ = nullptr;
  std::string description_;
  std::thread event_thread_;
  std::atomic<bool> running_{false};
  std::atomic<bool> gone_{false};

  std::mutex mutex_;  // guards everything below
  std::condition_variable cv_;
  std::vector<uint8_t> received_;
  std::vector<InTransfer*> in_flight_;
  int active_in_ = 0;
  bool closing_ = false;
};

}  // namespace

Result<std::unique_ptr<Transport>> MakeLibusbTransport(const LibusbTransportOptions& options) {
  ROTOSCAN_RETURN_IF_ERROR(options.Check());
  libusb_context* context = nullptr;
  const int result = libusb_init(&context);
  if (result != 0) return DeviceError("libusb_init failed: " + UsbError(result));
  return std::unique_ptr<Transport>(new LibusbTransport(context, options));
}

Result<std::vector<UsbBoard>> ListUsbBoards(uint16_t vendor_id, uint16_t product_id) {
  libusb_context* context = nullptr;
  const int result = libusb_init(&context);
  if (result != 0) return DeviceError("libusb_init failed: " + UsbError(result));
  libusb_device** list = nullptr;
  const ssize_t count = libusb_get_device_list(context, &list);
  if (count < 0) {
    libusb_exit(context);
    return IoError("listing USB devices: " + UsbError(static_cast<int>(count)));
  }
  std::vector<UsbBoard> boards;
  for (ssize_t i = 0; i < count; ++i) {
    libusb_device_descriptor desc;
    if (libusb_get_device_descriptor(list[i], &desc) != 0) continue;
    if (desc.idVendor != vendor_id || desc.idProduct != product_id) continue;
    UsbBoard board;
    board.bus = libusb_get_bus_number(list[i]);
    board.address = libusb_get_device_address(list[i]);
    board.vendor_id = desc.idVendor;
    board.product_id = desc.idProduct;
    board.port_path = PortPath(list[i]);
    board.serial = SysfsSerial(list[i]);
    boards.push_back(board);
  }
  libusb_free_device_list(list, 1);
  libusb_exit(context);
  return boards;
}

}  // namespace rotoscan::device

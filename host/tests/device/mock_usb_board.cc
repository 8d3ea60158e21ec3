// See mock_usb_board.h. The usbdevfs structures and ioctl numbers are the kernel's (linux/usbdevice_fs.h).
#include "mock_usb_board.h"

#include <sys/ioctl.h>

#include <linux/usbdevice_fs.h>
#include <umockdev.h>

#include <atomic>
#include <cerrno>
#include <chrono>
#include <cstddef>
#include <cstdlib>
#include <deque>
#include <fstream>
#include <mutex>
#include <set>
#include <sstream>
#include <stdexcept>
#include <thread>
#include <vector>

#include "rotoscan/device/usb_ids.h"

namespace rotoscan::device::testing {

namespace {

std::string ReadDescription() {
  const std::string path =
      std::string(ROTOSCAN_SOURCE_DIR) + "/host/tests/device/data/rotoscan-board.umockdev";
  std::ifstream in(path);
  if (!in) throw std::runtime_error("cannot read " + path);
  std::stringstream s;
  s << in.rdbuf();
  return s.str();
}

// The process's one umockdev testbed (umockdev_testbed_new() points the preload at a new sysfs tree, so a
// second testbed would hide the first's devices), shared by the MockUsbBoards alive, and the addresses they
// hold (a re-plugged board takes the next free one).
struct SharedBed {
  std::mutex mutex;
  UMockdevTestbed* testbed = nullptr;
  int users = 0;
  std::set<int> addresses;
};
SharedBed& Bed() {
  static SharedBed* bed = new SharedBed;  // never destroyed: boards may outlive static destruction order
  return *bed;
}
UMockdevTestbed* AcquireTestbed() {
  std::lock_guard<std::mutex> lock(Bed().mutex);
  if (Bed().users++ == 0) Bed().testbed = umockdev_testbed_new();
  return Bed().testbed;
}
void ReleaseTestbed() {
  std::lock_guard<std::mutex> lock(Bed().mutex);
  if (--Bed().users == 0) {
    g_object_unref(Bed().testbed);
    Bed().testbed = nullptr;
    Bed().addresses.clear();
  }
}
// Takes `want` if free, else the next free address after it; gives `release` (when > 0) back first.
int TakeAddress(int want, int release) {
  std::lock_guard<std::mutex> lock(Bed().mutex);
  if (release > 0) Bed().addresses.erase(release);
  while (Bed().addresses.count(want) != 0) ++want;
  Bed().addresses.insert(want);
  return want;
}
void ReleaseAddress(int address) {
  std::lock_guard<std::mutex> lock(Bed().mutex);
  Bed().addresses.erase(address);
}

void ReplaceAll(std::string* s, const std::string& from, const std::string& to) {
  for (size_t pos = s->find(from); pos != std::string::npos; pos = s->find(from, pos + to.size())) {
    s->replace(pos, from.size(), to);
  }
}

// A URB the host submitted and has not reaped yet. The IoctlData objects keep umockdev's copies of the
// client's usbdevfs_urb and of its buffer; updating them writes back into the client's memory when the
// URB is reaped.
struct Urb {
  UMockdevIoctlData* urb = nullptr;
  UMockdevIoctlData* buffer = nullptr;
  bool in = false;
  int generation = 0;
};

}  // namespace

struct MockUsbBoard::Impl {
  VirtualBoard* board;
  Options options;
  UMockdevTestbed* testbed = nullptr;
  UMockdevIoctlBase* handler = nullptr;
  std::string description;
  std::string syspath;
  std::vector<std::string> attached;  // device nodes the handler serves (old ones answer ENODEV)
  int address = 2;
  std::thread clock;
  std::atomic<bool> stop{false};
  std::atomic<bool> paused{false};
  int64_t zero_host_us = 0;  // real_time: CLOCK_MONOTONIC when the board's time was 0
  int64_t board_us = 0;      // real_time: how far the board's time has been run

  mutable std::mutex mutex;  // guards the board and everything below
  bool plugged = true;
  int generation = 0;  // bumped by Unplug(): URBs and fds of an older generation see ENODEV
  std::deque<Urb> pending_in;
  std::deque<Urb> done;
  bool drop_next_out = false, corrupt_next_out = false, duplicate_next_out = false, corrupt_next_in = false;
  Counters counters;

  std::string DevNode() const {
    char node[32];
    std::snprintf(node, sizeof(node), "/dev/bus/usb/001/%03d", address);
    return node;
  }

  void Plug() {
    std::string text = description;
    const std::string port_name = "1-" + std::to_string(options.port);
    if (options.port != 1) {
      ReplaceAll(&text, "usb1/1-1\n", "usb1/" + port_name + "\n");
      ReplaceAll(&text, "A: devpath=1\n", "A: devpath=" + std::to_string(options.port) + "\n");
    }
    if (!options.serial.empty()) {
      const size_t at = text.find("A: serial=");
      if (at != std::string::npos) text.replace(at, text.find('\n', at) - at, "A: serial=" + options.serial);
    }
    if (address != 2) {
      char num[8];
      std::snprintf(num, sizeof(num), "%03d", address);
      ReplaceAll(&text, "bus/usb/001/002", std::string("bus/usb/001/") + num);
      ReplaceAll(&text, "DEVNUM=002", std::string("DEVNUM=") + num);
      ReplaceAll(&text, "devnum=2\n", "devnum=" + std::to_string(address) + "\n");
    }
    // The ioctl socket must listen before the device node exists: a host polling for the re-plugged board
    // may open the node the moment it appears, and the umockdev preload exits the process when a mocked
    // node has no socket to connect to (seen once in 40 runs with the other order).
    GError* error = nullptr;
    if (!umockdev_testbed_attach_ioctl(testbed, DevNode().c_str(), handler, &error)) {
      std::string message = error->message;
      g_error_free(error);
      throw std::runtime_error("umockdev: attaching the ioctl handler: " + message);
    }
    attached.push_back(DevNode());
    if (!umockdev_testbed_add_from_string(testbed, text.c_str(), &error)) {
      std::string message = error->message;
      g_error_free(error);
      throw std::runtime_error("umockdev: adding the board: " + message);
    }
    syspath = "/sys/devices/pci0000:00/0000:00:14.0/usb1/" + port_name;
    umockdev_testbed_uevent(testbed, syspath.c_str(), "add");
  }

  static void Free(Urb* u) {
    if (u->buffer) g_object_unref(u->buffer);
    if (u->urb) g_object_unref(u->urb);
    u->buffer = u->urb = nullptr;
  }

  static void SetResult(Urb* u, int status, int actual) {
    auto* k = reinterpret_cast<usbdevfs_urb*>(u->urb->data);
    k->status = status;
    k->actual_length = actual;
    umockdev_ioctl_data_update(u->urb, 0, u->urb->data, u->urb->data_len);
  }

  // Fills waiting IN URBs with what the board has queued. Called with the mutex held.
  void FillIn() {
    while (plugged && !pending_in.empty()) {
      Urb& u = pending_in.front();
      std::vector<uint8_t> bytes(static_cast<size_t>(u.buffer ? u.buffer->data_len : 0));
      const size_t n = bytes.empty() ? 0 : board->Transmit(bytes.data(), bytes.size());
      if (n == 0) return;
      if (corrupt_next_in) {
        corrupt_next_in = false;
        bytes[n / 2] ^= 0x10;
        ++counters.corrupted;
      }
      ++counters.in_packets;
      umockdev_ioctl_data_update(u.buffer, 0, bytes.data(), static_cast<int>(n));
      SetResult(&u, 0, static_cast<int>(n));
      done.push_back(u);
      pending_in.pop_front();
    }
  }

  void Complete(UMockdevIoctlClient* client, long result, int error) {
    umockdev_ioctl_client_complete(client, result, error);
  }

  // The client's fd belongs to an unplugged device if it was opened on an older device node.
  bool Stale(UMockdevIoctlClient* client) const {
    return !plugged || DevNode() != umockdev_ioctl_client_get_devnode(client);
  }

  gboolean HandleIoctl(UMockdevIoctlClient* client) {
    const unsigned long request = umockdev_ioctl_client_get_request(client);
    UMockdevIoctlData* arg = umockdev_ioctl_client_get_arg(client);
    GError* error = nullptr;
    std::lock_guard<std::mutex> lock(mutex);
    if (Stale(client)) {
      // A disconnected device: URBs already completed (with -ESHUTDOWN) can still be reaped, then ENODEV.
      if ((request == USBDEVFS_REAPURB || request == USBDEVFS_REAPURBNDELAY) && !done.empty() &&
          done.front().generation != generation) {
        Reap(client, arg);
      } else {
        Complete(client, -1, ENODEV);
      }
      return TRUE;
    }
    switch (request) {
      case USBDEVFS_GET_CAPABILITIES: {
        UMockdevIoctlData* caps = umockdev_ioctl_data_resolve(arg, 0, sizeof(uint32_t), &error);
        uint32_t value = USBDEVFS_CAP_BULK_CONTINUATION | USBDEVFS_CAP_NO_PACKET_SIZE_LIM |
                         USBDEVFS_CAP_REAP_AFTER_DISCONNECT;
        umockdev_ioctl_data_update(caps, 0, reinterpret_cast<guint8*>(&value), sizeof(value));
        g_object_unref(caps);
        Complete(client, 0, 0);
        return TRUE;
      }
      case USBDEVFS_CLAIMINTERFACE:
      case USBDEVFS_RELEASEINTERFACE:
      case USBDEVFS_SETINTERFACE:
      case USBDEVFS_CLEAR_HALT: Complete(client, 0, 0); return TRUE;
      case USBDEVFS_SUBMITURB: {
        UMockdevIoctlData* urb = umockdev_ioctl_data_resolve(arg, 0, sizeof(usbdevfs_urb), &error);
        const auto* k = reinterpret_cast<const usbdevfs_urb*>(urb->data);
        if (k->type != USBDEVFS_URB_TYPE_BULK ||
            (k->endpoint != kUsbEndpointOut && k->endpoint != kUsbEndpointIn)) {
          g_object_unref(urb);
          Complete(client, -1, EINVAL);
          return TRUE;
        }
        Urb u;
        u.urb = urb;
        u.in = (k->endpoint & 0x80) != 0;
        u.generation = generation;
        if (k->buffer_length > 0) {
          u.buffer = umockdev_ioctl_data_resolve(urb, offsetof(usbdevfs_urb, buffer),
                                                 static_cast<size_t>(k->buffer_length), &error);
        }
        if (u.in) {
          pending_in.push_back(u);
          FillIn();
        } else {
          const int length = u.buffer ? u.buffer->data_len : 0;
          std::vector<uint8_t> bytes(u.buffer ? u.buffer->data : nullptr,
                                     u.buffer ? u.buffer->data + length : nullptr);
          ++counters.out_packets;
          if (corrupt_next_out && !bytes.empty()) {
            corrupt_next_out = false;
            bytes[bytes.size() / 2] ^= 0x10;
            ++counters.corrupted;
          }
          if (drop_next_out) {
            drop_next_out = false;
            ++counters.dropped;
          } else {
            if (options.real_time) CatchUp();
            board->Receive(bytes.data(), bytes.size());
            if (duplicate_next_out) {
              duplicate_next_out = false;
              ++counters.duplicated;
              board->Receive(bytes.data(), bytes.size());
            }
          }
          SetResult(&u, 0, length);
          done.push_back(u);
        }
        Complete(client, 0, 0);
        return TRUE;
      }
      case USBDEVFS_REAPURB:
      case USBDEVFS_REAPURBNDELAY: {
        FillIn();
        if (done.empty()) {
          Complete(client, -1, EAGAIN);
          return TRUE;
        }
        Reap(client, arg);
        return TRUE;
      }
      case USBDEVFS_DISCARDURB: {
        const unsigned long address_in_client = *reinterpret_cast<const unsigned long*>(arg->data);
        for (auto it = pending_in.begin(); it != pending_in.end(); ++it) {
          if (it->urb->client_addr == address_in_client) {
            SetResult(&*it, -ENOENT, 0);
            done.push_back(*it);
            pending_in.erase(it);
            Complete(client, 0, 0);
            return TRUE;
          }
        }
        Complete(client, -1, EINVAL);
        return TRUE;
      }
      default: Complete(client, -1, ENOTTY); return TRUE;
    }
  }

  // Hands the oldest completed URB back to the host: *arg = the client's own urb pointer.
  void Reap(UMockdevIoctlClient* client, UMockdevIoctlData* arg) {
    GError* error = nullptr;
    Urb u = done.front();
    done.pop_front();
    UMockdevIoctlData* out = umockdev_ioctl_data_resolve(arg, 0, sizeof(void*), &error);
    umockdev_ioctl_data_set_ptr(out, 0, u.urb);
    g_object_unref(out);
    Complete(client, 0, 0);
    Free(&u);
  }

  static gboolean OnIoctl(UMockdevIoctlBase*, UMockdevIoctlClient* client, gpointer self) {
    return static_cast<Impl*>(self)->HandleIoctl(client);
  }

  static int64_t MonotonicUs() {
    return std::chrono::duration_cast<std::chrono::microseconds>(
               std::chrono::steady_clock::now().time_since_epoch())
        .count();
  }

  // Options::real_time: runs the board up to the host's time. Called with the mutex held, from the clock
  // thread and around each OUT packet, so that the board handles a command at the time it arrives (a late
  // clock tick under load would otherwise stamp a PONG with a stale time).
  void CatchUp() {
    const int64_t target = MonotonicUs() - zero_host_us;
    if (target > board_us) {
      board->Advance(target - board_us);
      board_us = target;
    }
  }

  void RunClock() {
    while (!stop) {
      if (options.real_time) {
        std::lock_guard<std::mutex> lock(mutex);
        CatchUp();
        FillIn();
      } else if (!paused) {
        std::lock_guard<std::mutex> lock(mutex);
        board->Advance(options.virtual_us_per_tick);
      }
      std::this_thread::sleep_for(std::chrono::microseconds(options.real_us_per_tick));
    }
  }
};

bool MockUsbBoard::InMockEnvironment() {
  // umockdev_in_mock_environment() only becomes true once a testbed exists; the preload must be there first.
  const char* preload = std::getenv("LD_PRELOAD");
  return preload != nullptr && std::string(preload).find("libumockdev-preload") != std::string::npos;
}

MockUsbBoard::MockUsbBoard(VirtualBoard* board, const Options& options) : impl_(new Impl) {
  impl_->board = board;
  impl_->options = options;
  impl_->description = ReadDescription();
  impl_->testbed = AcquireTestbed();
  impl_->address = TakeAddress(options.address, 0);
  impl_->handler = umockdev_ioctl_base_new();
  g_signal_connect(impl_->handler, "handle-ioctl", G_CALLBACK(&Impl::OnIoctl), impl_.get());
  impl_->Plug();
  impl_->zero_host_us = Impl::MonotonicUs();
  impl_->clock = std::thread([this] { impl_->RunClock(); });
}

MockUsbBoard::~MockUsbBoard() {
  impl_->stop = true;
  impl_->clock.join();
  {
    std::lock_guard<std::mutex> lock(impl_->mutex);
    for (Urb& u : impl_->pending_in) Impl::Free(&u);
    for (Urb& u : impl_->done) Impl::Free(&u);
    impl_->pending_in.clear();
    impl_->done.clear();
  }
  {
    std::lock_guard<std::mutex> lock(impl_->mutex);
    if (impl_->plugged) {
      umockdev_testbed_uevent(impl_->testbed, impl_->syspath.c_str(), "remove");
      umockdev_testbed_remove_device(impl_->testbed, impl_->syspath.c_str());
    }
  }
  for (const std::string& node : impl_->attached) {
    GError* error = nullptr;
    if (!umockdev_testbed_detach_ioctl(impl_->testbed, node.c_str(), &error) && error != nullptr) g_error_free(error);
  }
  ReleaseAddress(impl_->address);
  ReleaseTestbed();
  g_object_unref(impl_->handler);
}

void MockUsbBoard::DropNextOut() {
  std::lock_guard<std::mutex> lock(impl_->mutex);
  impl_->drop_next_out = true;
}
void MockUsbBoard::CorruptNextOut() {
  std::lock_guard<std::mutex> lock(impl_->mutex);
  impl_->corrupt_next_out = true;
}
void MockUsbBoard::DuplicateNextOut() {
  std::lock_guard<std::mutex> lock(impl_->mutex);
  impl_->duplicate_next_out = true;
}
void MockUsbBoard::CorruptNextIn() {
  std::lock_guard<std::mutex> lock(impl_->mutex);
  impl_->corrupt_next_in = true;
}

void MockUsbBoard::Unplug() {
  std::lock_guard<std::mutex> lock(impl_->mutex);
  if (!impl_->plugged) return;
  impl_->plugged = false;
  ++impl_->generation;
  ++impl_->counters.unplugs;
  // The kernel completes every URB of a disconnected device with -ESHUTDOWN; the host reaps them.
  for (Urb& u : impl_->pending_in) {
    Impl::SetResult(&u, -ESHUTDOWN, 0);
    impl_->done.push_back(u);
  }
  impl_->pending_in.clear();
  umockdev_testbed_uevent(impl_->testbed, impl_->syspath.c_str(), "remove");
  umockdev_testbed_remove_device(impl_->testbed, impl_->syspath.c_str());
}

void MockUsbBoard::Replug() {
  std::lock_guard<std::mutex> lock(impl_->mutex);
  if (impl_->plugged) return;
  // URBs of the old device node the host never reaped (it closed the fd) are gone with it.
  for (auto it = impl_->done.begin(); it != impl_->done.end();) {
    if (it->generation != impl_->generation) {
      Impl::Free(&*it);
      it = impl_->done.erase(it);
    } else {
      ++it;
    }
  }
  impl_->address = TakeAddress(impl_->address + 1, impl_->address);  // a re-plugged device gets a new address
  impl_->plugged = true;
  impl_->Plug();
}

int MockUsbBoard::address() const {
  std::lock_guard<std::mutex> lock(impl_->mutex);
  return impl_->address;
}

void MockUsbBoard::WithBoardLocked(const std::function<void()>& f) {
  std::lock_guard<std::mutex> lock(impl_->mutex);
  f();
}

void MockUsbBoard::WithBoardAtNow(const std::function<void()>& f) {
  std::lock_guard<std::mutex> lock(impl_->mutex);
  if (impl_->options.real_time) impl_->CatchUp();
  f();
}

void MockUsbBoard::PauseTime(bool paused) {
  impl_->paused = paused;
}

int64_t MockUsbBoard::device_zero_host_us() const { return impl_->zero_host_us; }

MockUsbBoard::Counters MockUsbBoard::counters() const {
  std::lock_guard<std::mutex> lock(impl_->mutex);
  return impl_->counters;
}

}  // namespace rotoscan::device::testing

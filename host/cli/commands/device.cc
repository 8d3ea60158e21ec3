// rotoscan device: bench work with the scanner board (list, info, ping, move, laser, flash).
#include "device.h"

#include <spawn.h>
#include <sys/wait.h>

#include <algorithm>
#include <cerrno>
#include <chrono>
#include <cmath>
#include <cstring>
#include <fstream>
#include <iomanip>
#include <iterator>
#include <memory>
#include <ostream>
#include <sstream>
#include <thread>
#include <vector>

#include "rotoscan/device/client.h"
#include "rotoscan/device/transport.h"
#include "rotoscan/device/usb_ids.h"

extern char** environ;

namespace rotoscan::cli {

namespace {

Result<std::unique_ptr<device::Client>> ConnectBoard(const DeviceOptions& options) {
  if (options.bus < 0 || options.address < 0) return InvalidArgumentError("--bus and --address must be >= 0");
  if (!(options.ack_timeout_ms > 0)) return InvalidArgumentError("--ack-timeout must be > 0 ms");
  device::LibusbTransportOptions usb;
  usb.bus = options.bus;
  usb.address = options.address;
  Result<std::unique_ptr<device::Transport>> transport = device::MakeLibusbTransport(usb);
  if (!transport.ok()) return transport.status();
  ROTOSCAN_RETURN_IF_ERROR((*transport)->Open());
  device::ClientOptions client;
  client.ack_timeout_us = static_cast<int64_t>(options.ack_timeout_ms * 1000);
  client.reconnect_timeout_us = 0;  // bench commands fail at once when the board goes away
  return device::Client::Connect(std::move(transport).value(), client);
}

std::string Capabilities(uint32_t caps) {
  static const std::pair<uint32_t, const char*> kNames[] = {
      {1u << 0, "stepper"}, {1u << 1, "lasers"},       {1u << 2, "trigger-out"}, {1u << 3, "exposure-in"},
      {1u << 4, "program"}, {1u << 5, "laser-safety"}, {1u << 6, "diag"},        {1u << 31, "simulated"}};
  std::string out;
  for (const auto& [bit, name] : kNames) {
    if (caps & bit) out += (out.empty() ? "" : " ") + std::string(name);
  }
  return out.empty() ? "none" : out;
}

}  // namespace

int RunDeviceList(const Context& context) {
  Result<std::vector<device::UsbBoard>> boards = device::ListUsbBoards();
  if (!boards.ok()) return ReportStatus(context, "device list", boards.status());
  if (boards->empty()) {
    return ReportStatus(context, "device list", NotFoundError("no Rotoscan board found"));
  }
  for (const device::UsbBoard& b : *boards) {
    *context.out << "bus " << b.bus << " address " << b.address << " port " << b.port_path << " usb "
                 << std::hex << std::setfill('0') << std::setw(4) << b.vendor_id << ":" << std::setw(4)
                 << b.product_id << std::dec << std::setfill(' ') << "\n";
  }
  return kExitOk;
}

int RunDeviceInfo(const Context& context, const DeviceOptions& options) {
  auto client = ConnectBoard(options);
  if (!client.ok()) return ReportStatus(context, "device info", client.status());
  const device::DeviceInfo& info = (*client)->info();
  *context.out << "board:        " << (*client)->transport().Description() << "\n"
               << "protocol:     " << info.protocol_major << "." << info.protocol_minor << "\n"
               << "firmware:     " << info.firmware_version << "\n"
               << "serial:       " << info.uid << "\n"
               << "capabilities: " << Capabilities(info.capabilities) << "\n"
               << "max shots:    " << info.max_shots << " per step\n";
  return kExitOk;
}

int RunDeviceStatus(const Context& context, const DeviceOptions& options) {
  auto client = ConnectBoard(options);
  if (!client.ok()) return ReportStatus(context, "device status", client.status());
  auto status = (*client)->GetStatus();
  if (!status.ok()) return ReportStatus(context, "device status", status.status());
  static const char* const kStates[] = {"idle", "moving", "running a program", "triggering"};
  const int state = static_cast<int>(status->state);
  *context.out << "state:        " << (state >= 0 && state < 4 ? kStates[state] : "unknown")
               << (status->safety_tripped ? " (laser safety tripped)" : "") << "\n"
               << "time:         " << status->time_us << " us since power-on\n"
               << "position:     " << status->position << " steps, motor "
               << (status->motor_enabled ? "enabled" : "disabled") << ", lasers 0x" << std::hex
               << int(status->lasers) << std::dec << "\n"
               << "program:      "
               << (status->program_loaded ? "step " + std::to_string(status->program_next_step) + " of " +
                                                std::to_string(status->program_steps)
                                          : std::string("none"))
               << "\n"
               << "counters:     " << status->trigger_count << " triggers, " << status->rx_errors
               << " bad frames, " << status->events_dropped << " events dropped\n";
  auto diag = (*client)->GetDiag();
  if (!diag.ok() && diag.status().code() == StatusCode::kFailedPrecondition) {  // a protocol 1.0 board
    *context.out << "diagnostics:  not reported by this firmware (protocol "
                 << (*client)->info().protocol_major << "." << (*client)->info().protocol_minor << ")\n";
    return kExitOk;
  }
  if (!diag.ok()) return ReportStatus(context, "device status", diag.status());
  if (diag->step_isr_cycles_max.has_value() && diag->cpu_hz.has_value() && *diag->cpu_hz > 0) {
    const double us = 1e6 / double(*diag->cpu_hz);
    *context.out << "step irq:     worst " << *diag->step_isr_cycles_max << " cycles (" << std::fixed
                 << std::setprecision(2) << *diag->step_isr_cycles_max * us << " us), last "
                 << *diag->step_isr_cycles_last << " cycles, at " << *diag->cpu_hz / 1000000.0 << " MHz\n"
                 << std::defaultfloat;
  } else {
    *context.out << "step irq:     not measured on this board\n";
  }
  if (diag->fault.has_value()) {
    const device::BoardDiag::Fault& f = *diag->fault;
    *context.out << "last fault:   "
                 << (f.vector == 3    ? std::string("HardFault")
                     : f.vector >= 16 ? "interrupt " + std::to_string(f.vector - 16) + " without a handler"
                                      : "exception " + std::to_string(f.vector))
                 << " before the last reset (" << f.count << " since power-on): pc 0x" << std::hex << f.pc
                 << ", lr 0x" << f.lr << ", xpsr 0x" << f.psr << ", cfsr 0x" << f.cfsr << ", hfsr 0x"
                 << f.hfsr << std::dec << "\n";
  } else {
    *context.out << "last fault:   none recorded\n";
  }
  return kExitOk;
}

int RunDevicePing(const Context& context, const DeviceOptions& options, int count) {
  if (count < 3) return ReportStatus(context, "device ping", InvalidArgumentError("--count must be >= 3"));
  auto client = ConnectBoard(options);
  if (!client.ok()) return ReportStatus(context, "device ping", client.status());
  std::vector<device::PingSample> samples;
  for (int i = 0; i < count; ++i) {
    auto sample = (*client)->Ping();
    if (!sample.ok()) return ReportStatus(context, "device ping", sample.status());
    samples.push_back(*sample);
  }
  std::vector<int64_t> trips;
  for (const auto& s : samples) trips.push_back(s.host_receive_us - s.host_send_us);
  std::sort(trips.begin(), trips.end());
  *context.out << count << " pings: round trip min " << trips.front() << " us, median "
               << trips[trips.size() / 2] << " us, max " << trips.back() << " us\n";
  auto fit = device::FitClock(samples);
  if (fit.ok()) {
    *context.out << "clock: board = host + " << std::fixed << std::setprecision(1) << fit->offset_us
                 << " us, drift " << std::setprecision(2) << fit->drift * 1e6 << " ppm (from "
                 << fit->samples_used << " fastest pings, residual " << std::setprecision(1)
                 << fit->residual_rms_us << " us)\n";
  } else {
    *context.out << "clock: " << fit.status().message() << "\n";
  }
  return kExitOk;
}

int RunDeviceMove(const Context& context, const DeviceOptions& options, double degrees, int steps_per_rev) {
  if (!std::isfinite(degrees) || std::abs(degrees) > 36000) {
    return ReportStatus(context, "device move",
                        InvalidArgumentError("the angle must be within +-36000 degrees"));
  }
  if (steps_per_rev <= 0) {
    return ReportStatus(context, "device move", InvalidArgumentError("--steps-per-rev must be > 0"));
  }
  const auto steps = static_cast<int32_t>(std::lround(degrees / 360.0 * steps_per_rev));
  auto client = ConnectBoard(options);
  if (!client.ok()) return ReportStatus(context, "device move", client.status());
  Status status = (*client)->EnableMotor(true);
  if (!status.ok()) return ReportStatus(context, "device move", status);
  // Generous: the slowest configurable profile is 1 step/s.
  auto done = (*client)->MoveAndWait(steps, (std::abs(static_cast<int64_t>(steps)) + 10) * 1'000'000);
  if (!done.ok()) return ReportStatus(context, "device move", done.status());
  *context.out << "moved " << steps << " steps (" << degrees << " deg); table at " << done->position
               << " steps\n";
  return kExitOk;
}

int RunDeviceLaser(const Context& context, const DeviceOptions& options, const std::string& which) {
  uint8_t mask;
  if (which == "left") {
    mask = device::kLaserLeft;
  } else if (which == "right") {
    mask = device::kLaserRight;
  } else if (which == "both") {
    mask = device::kLaserLeft | device::kLaserRight;
  } else if (which == "off") {
    mask = 0;
  } else {
    return ReportStatus(context, "device laser",
                        InvalidArgumentError("laser must be left, right, both or off, not '" + which + "'"));
  }
  auto client = ConnectBoard(options);
  if (!client.ok()) return ReportStatus(context, "device laser", client.status());
  Status status = (*client)->SetLasers(mask);
  if (!status.ok()) return ReportStatus(context, "device laser", status);
  *context.out << "lasers: " << which << (mask ? " (the board turns them off after its laser timeout)" : "")
               << "\n";
  return kExitOk;
}

namespace {

constexpr size_t kMaxImageBytes = 32 * 1024;  // DESIGN.md's flash budget (sectors 0-1)

uint32_t Word(const std::string& b, size_t at) {
  return uint32_t(uint8_t(b[at])) | uint32_t(uint8_t(b[at + 1])) << 8 | uint32_t(uint8_t(b[at + 2])) << 16 |
         uint32_t(uint8_t(b[at + 3])) << 24;
}

// Runs argv[0] (PATH lookup) and waits for it; its exit status, or an error when it could not be started.
Result<int> RunProgram(const std::vector<std::string>& args) {
  std::vector<char*> argv;
  for (const std::string& a : args) argv.push_back(const_cast<char*>(a.c_str()));
  argv.push_back(nullptr);
  pid_t pid = 0;
  const int rc = posix_spawnp(&pid, argv[0], nullptr, nullptr, argv.data(), environ);
  if (rc != 0) {
    return NotFoundError(args[0] + ": " + std::strerror(rc) +
                         (rc == ENOENT ? " (install it: apt-get install dfu-util)" : ""));
  }
  int status = 0;
  while (waitpid(pid, &status, 0) < 0) {
    if (errno != EINTR) return InternalError(std::string("waitpid: ") + std::strerror(errno));
  }
  if (WIFSIGNALED(status)) return 128 + WTERMSIG(status);
  return WEXITSTATUS(status);
}

}  // namespace

Result<std::string> FirmwareImageVersion(const std::string& image) {
  std::ifstream in(image, std::ios::binary);
  if (!in) return NotFoundError("cannot read " + image);
  std::string bytes((std::istreambuf_iterator<char>(in)), std::istreambuf_iterator<char>());
  if (bytes.size() < 8 || bytes.size() > kMaxImageBytes) {
    return InvalidArgumentError(image + ": " + std::to_string(bytes.size()) +
                                " bytes, not a firmware image (8 B to 32 KB; flash the .bin, not the .elf)");
  }
  // The vector table: initial stack pointer in the F411's RAM, reset handler in its flash (Thumb bit set).
  const uint32_t sp = Word(bytes, 0);
  const uint32_t reset = Word(bytes, 4);
  if (sp < 0x20000000u || sp > 0x20020000u || reset < 0x08000000u || reset >= 0x08080000u || !(reset & 1u)) {
    return InvalidArgumentError(image + ": does not start with an STM32F411 vector table (flash the .bin, not "
                                "the .elf)");
  }
  // The USB device descriptor: 18 bytes, bcdUSB 2.00, bMaxPacketSize0 64, then our VID and PID.
  const uint8_t head[] = {18, 1, 0x00, 0x02, 0, 0, 0, 64, uint8_t(device::kUsbVendorId & 0xFF),
                          uint8_t(device::kUsbVendorId >> 8), uint8_t(device::kUsbProductId & 0xFF),
                          uint8_t(device::kUsbProductId >> 8)};
  const std::string needle(reinterpret_cast<const char*>(head), sizeof(head));
  const size_t at = bytes.find(needle);
  if (at == std::string::npos || at + 18 > bytes.size()) {
    return InvalidArgumentError(image + ": no Rotoscan USB device descriptor in it (another board's firmware?)");
  }
  const unsigned bcd = uint8_t(bytes[at + 12]) | uint8_t(bytes[at + 13]) << 8;
  return std::to_string(bcd >> 8) + "." + std::to_string((bcd >> 4) & 0xF) + "." + std::to_string(bcd & 0xF);
}

int RunDeviceFlash(const Context& context, const DeviceOptions& options, const std::string& file,
                   const FlashOptions& flash) {
  const char* what = "device flash";
  if (!(flash.wait_s > 0)) return ReportStatus(context, what, InvalidArgumentError("--wait must be > 0 s"));
  Result<std::string> version = FirmwareImageVersion(file);
  if (!version.ok()) return ReportStatus(context, what, version.status());
  *context.out << "flashing " << file << " (firmware " << *version << ") through the DFU bootloader 0483:df11\n";
  Result<int> rc = RunProgram({flash.dfu_util, "-a", "0", "-d", "0483:df11", "-s", "0x08000000:leave", "-D", file});
  if (!rc.ok()) return ReportStatus(context, what, rc.status());
  if (*rc != 0) {
    return ReportStatus(context, what,
                        DeviceError(flash.dfu_util + " failed (exit " + std::to_string(*rc) +
                                         "): is the board in its bootloader? Hold BOOT0, press and release "
                                         "NRST, release BOOT0; `dfu-util -l` should list 0483:df11"));
  }
  // The bootloader jumps to the new image (:leave); the board enumerates again as a Rotoscan board.
  const auto deadline = std::chrono::steady_clock::now() + std::chrono::duration<double>(flash.wait_s);
  Result<std::unique_ptr<device::Client>> client = DeviceError("not tried");
  for (;;) {
    Result<std::vector<device::UsbBoard>> boards = device::ListUsbBoards();
    if (boards.ok() && !boards->empty()) {
      client = ConnectBoard(options);
      if (client.ok()) break;
    }
    if (std::chrono::steady_clock::now() >= deadline) {
      return ReportStatus(context, what,
                          TimeoutError("flashed, but the board did not come back on USB within " +
                                           std::to_string(flash.wait_s) + " s" +
                                           (client.ok() ? std::string() : ": " + client.status().message())));
    }
    std::this_thread::sleep_for(std::chrono::milliseconds(200));
  }
  const std::string running = (*client)->info().firmware_version;
  if (running != *version) {
    return ReportStatus(context, what,
                        DeviceError("the board runs firmware " + running + " but the image is " + *version +
                                      ": the flash did not take"));
  }
  *context.out << "board back: firmware " << running << ", serial " << (*client)->info().uid << "\n";
  return kExitOk;
}

void RegisterDevice(CLI::App& app, const Context& context, int* exit_code) {
  CLI::App* sub =
      app.add_subcommand("device", "Talk to the scanner board: list, info, status, ping, move, laser, flash");
  sub->require_subcommand(1);
  static DeviceOptions options;
  static int count = 20;
  static double degrees = 0;
  static int steps_per_rev = 3200;
  static std::string which;
  auto add_common = [](CLI::App* command) {
    command->add_option("--bus", options.bus, "USB bus of the board (with --address, when several)");
    command->add_option("--address", options.address, "USB address of the board");
    command->add_option("--ack-timeout", options.ack_timeout_ms, "ms to wait for an answer before resending");
  };
  sub->add_subcommand("list", "List connected scanner boards")->callback([&context, exit_code] {
    *exit_code = RunDeviceList(context);
  });
  CLI::App* info = sub->add_subcommand("info", "Show the board's firmware version and capabilities");
  add_common(info);
  info->callback([&context, exit_code] { *exit_code = RunDeviceInfo(context, options); });
  CLI::App* status = sub->add_subcommand(
      "status", "Show the board's state and its diagnostics (step interrupt cycles, the last fault)");
  add_common(status);
  status->callback([&context, exit_code] { *exit_code = RunDeviceStatus(context, options); });
  CLI::App* ping = sub->add_subcommand("ping", "Measure the round trip and the clock offset to the board");
  add_common(ping);
  ping->add_option("--count", count, "number of round trips (>= 3)");
  ping->callback([&context, exit_code] { *exit_code = RunDevicePing(context, options, count); });
  CLI::App* move = sub->add_subcommand("move", "Turn the table by an angle in degrees");
  add_common(move);
  move->add_option("degrees", degrees, "angle, degrees (negative: the other way)")->required();
  move->add_option("--steps-per-rev", steps_per_rev,
                   "motor steps per table revolution (microsteps included)");
  move->callback(
      [&context, exit_code] { *exit_code = RunDeviceMove(context, options, degrees, steps_per_rev); });
  CLI::App* laser = sub->add_subcommand("laser", "Switch the lasers (left, right, both, off)");
  add_common(laser);
  laser->add_option("which", which, "left, right, both or off")->required();
  laser->callback([&context, exit_code] { *exit_code = RunDeviceLaser(context, options, which); });
  static std::string image;
  static FlashOptions flash;
  CLI::App* flash_cmd = sub->add_subcommand(
      "flash", "Flash rotoscan-fw.bin through the STM32 DFU bootloader (BOOT0 high at reset), check the version");
  add_common(flash_cmd);
  flash_cmd->add_option("file", image, "firmware image (.bin), e.g. build-fw/rotoscan-fw.bin")->required();
  flash_cmd->add_option("--dfu-util", flash.dfu_util, "the dfu-util program to run");
  flash_cmd->add_option("--wait", flash.wait_s, "seconds to wait for the board to come back");
  flash_cmd->callback([&context, exit_code] { *exit_code = RunDeviceFlash(context, options, image, flash); });
}

}  // namespace rotoscan::cli

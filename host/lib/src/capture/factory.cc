#include "rotoscan/capture/factory.h"

#include <mutex>

namespace rotoscan::capture {

// Every backend's registration function, from the list CMake generated (CMakeLists.txt).
#define ROTOSCAN_CAPTURE_BACKEND(name) void RegisterCaptureBackend_##name(BackendRegistry* registry);
#include "capture_backends.inc"
#undef ROTOSCAN_CAPTURE_BACKEND

namespace {

// The backends of the project, with what a build needs to have them: for the message when one is missing.
struct KnownBackend {
  const char* name;
  bool camera;
  const char* needs;
};
constexpr KnownBackend kKnown[] = {
    {"virtual", true, "the virtual scanner (module sim)"},
    {"v4l2", true, "Linux's V4L2 headers (linux/videodev2.h) and libv4l (Debian libv4l-dev)"},
    {"aravis", true, "libaravis (Debian libaravis-dev)"},
    {"usb", false, "libusb (Debian libusb-1.0-0-dev)"},
    {"sim", false, "the firmware core built for the host (ROTOSCAN_BUILD_FIRMWARE_HOST=ON)"},
    {"ciclop", false, "the G-code board backend (POSIX serial ports)"},
};

template <typename Backend>
std::string Names(const std::vector<Backend>& backends) {
  std::string names;
  for (const auto& b : backends) names += (names.empty() ? "" : ", ") + b.name;
  return names.empty() ? "none" : names;
}

Status NotBuilt(const std::string& name, bool camera, const std::string& built) {
  for (const auto& known : kKnown) {
    if (name == known.name && known.camera == camera) {
      return UnimplementedError(std::string(camera ? "camera" : "board") + " backend '" + name +
                                "' is not built into this rotoscan (it needs " + known.needs +
                                " at build time); built: " + built);
    }
  }
  return InvalidArgumentError(std::string("unknown ") + (camera ? "camera" : "board") + " '" + name +
                              "'; built: " + built);
}

}  // namespace

Result<Spec> ParseSpec(const std::string& text) {
  const auto colon = text.find(':');
  Spec spec;
  spec.backend = text.substr(0, colon);
  if (colon != std::string::npos) spec.argument = text.substr(colon + 1);
  if (spec.backend.empty()) return InvalidArgumentError("device spec '" + text + "' has no backend name");
  return spec;
}

BackendRegistry& BackendRegistry::Instance() {
  static BackendRegistry* registry = [] {
    auto* r = new BackendRegistry();  // never destroyed: backends may be used from static destructors
#define ROTOSCAN_CAPTURE_BACKEND(name) RegisterCaptureBackend_##name(r);
#include "capture_backends.inc"
#undef ROTOSCAN_CAPTURE_BACKEND
    return r;
  }();
  return *registry;
}

void BackendRegistry::AddCamera(CameraBackend backend) { cameras_.push_back(std::move(backend)); }
void BackendRegistry::AddBoard(BoardBackend backend) { boards_.push_back(std::move(backend)); }

Result<std::unique_ptr<Board>> OpenBoard(const std::string& spec_text, OpenContext* context) {
  ROTOSCAN_ASSIGN_OR_RETURN(const Spec spec, ParseSpec(spec_text));
  OpenContext local;
  if (context == nullptr) context = &local;
  const auto& boards = BackendRegistry::Instance().boards();
  for (const auto& backend : boards) {
    if (backend.name == spec.backend) return backend.open(spec.argument, context);
  }
  return NotBuilt(spec.backend, /*camera=*/false, Names(boards));
}

Result<std::unique_ptr<Camera>> OpenCamera(const std::string& spec_text, const OpenContext& context) {
  ROTOSCAN_ASSIGN_OR_RETURN(const Spec spec, ParseSpec(spec_text));
  const auto& cameras = BackendRegistry::Instance().cameras();
  for (const auto& backend : cameras) {
    if (backend.name == spec.backend) return backend.open(spec.argument, context);
  }
  return NotBuilt(spec.backend, /*camera=*/true, Names(cameras));
}

DeviceList ListDevices() {
  DeviceList list;
  const auto& registry = BackendRegistry::Instance();
  auto collect = [&list](const std::string& name, const auto& lister, std::vector<DeviceListing>* out) {
    if (!lister) return;
    auto found = lister();
    if (!found.ok()) {
      list.errors.push_back(name + ": " + found.status().message());
      return;
    }
    for (auto& d : found.value()) out->push_back(std::move(d));
  };
  for (const auto& b : registry.boards()) collect(b.name, b.list, &list.boards);
  for (const auto& c : registry.cameras()) collect(c.name, c.list, &list.cameras);
  return list;
}

std::vector<std::string> BuiltCameraBackends() {
  std::vector<std::string> names;
  for (const auto& c : BackendRegistry::Instance().cameras()) names.push_back(c.name);
  return names;
}

std::vector<std::string> BuiltBoardBackends() {
  std::vector<std::string> names;
  for (const auto& b : BackendRegistry::Instance().boards()) names.push_back(b.name);
  return names;
}

}  // namespace rotoscan::capture

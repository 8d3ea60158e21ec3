// Opening cameras and boards from a spec string, and listing what is attached.
//
//   cameras: "virtual", "v4l2:/dev/video0" (or "v4l2" for the first), "aravis" or "aravis:ID"
//   boards:  "usb" or "usb:SERIAL", "sim", "ciclop:/dev/ttyUSB0"
//
// A spec is "BACKEND[:ARGUMENT]". Backends register themselves (BackendRegistry below); the factory has
// no list of them in its logic. A backend that exists in the project but was not compiled into this
// build (its library was missing at configure time) is kUnimplemented with a message saying what to
// install; an unknown name is kInvalidArgument listing the known ones.
//
// Adding a backend: write `void RegisterCaptureBackend_NAME(BackendRegistry* registry)` in its source,
// calling AddCamera()/AddBoard(), and add one line `rotoscan_capture_backend(NAME SOURCES ...)` to
// host/lib/src/capture/CMakeLists.txt.
#pragma once

#include <functional>
#include <memory>
#include <string>
#include <vector>

#include "rotoscan/capture/board.h"
#include "rotoscan/capture/camera.h"
#include "rotoscan/capture/clock.h"
#include "rotoscan/core/status.h"

namespace rotoscan::capture {

class RigTruth;  // virtual_rig.h

struct Spec {
  std::string backend;   // "v4l2"
  std::string argument;  // "/dev/video0"; empty when none
};
// "v4l2:/dev/video0" -> {v4l2, /dev/video0}. kInvalidArgument for an empty backend name.
Result<Spec> ParseSpec(const std::string& text);

// What backends get when they open a device.
struct OpenContext {
  // The scan's clock. Real backends use a real clock; the sim board and the virtual camera share a
  // VirtualClock (OpenBoard("sim") creates one when this is null or real).
  std::shared_ptr<Clock> clock;
  // The board already opened, for a virtual camera (it renders what the board does) -- may be null.
  Board* board = nullptr;
  // Virtual camera: the scene file (sim/scene.h JSON); empty = the built-in default scene.
  std::string scene_path;
  // Virtual camera: the object's placement in the scene (sim::PlaceScene; 0 the scene as given).
  int placement = 0;
  // Virtual camera: the simulated rig, when the board is not the one that knows it (tests).
  RigTruth* truth = nullptr;
  // Free-form "key=value" options for a backend ("rolling=1", "fps=30"), from the CLI.
  std::vector<std::string> options;
};

// One device a backend found.
struct DeviceListing {
  std::string spec;         // what to pass to OpenCamera/OpenBoard: "v4l2:/dev/video0"
  std::string description;  // "Logitech C270 (uvcvideo), MJPEG 1280x960"
};

struct CameraBackend {
  std::string name;         // "v4l2"
  std::string description;  // one line for `rotoscan devices`
  std::function<Result<std::unique_ptr<Camera>>(const std::string& argument, const OpenContext& context)> open;
  std::function<Result<std::vector<DeviceListing>>()> list;  // may be empty: nothing to list
};

struct BoardBackend {
  std::string name;
  std::string description;
  std::function<Result<std::unique_ptr<Board>>(const std::string& argument, OpenContext* context)> open;
  std::function<Result<std::vector<DeviceListing>>()> list;
};

class BackendRegistry {
 public:
  // The registry with every backend built into this library.
  static BackendRegistry& Instance();
  void AddCamera(CameraBackend backend);
  void AddBoard(BoardBackend backend);
  const std::vector<CameraBackend>& cameras() const { return cameras_; }
  const std::vector<BoardBackend>& boards() const { return boards_; }

 private:
  std::vector<CameraBackend> cameras_;
  std::vector<BoardBackend> boards_;
};

// Opens a board. `context` may be updated (the sim board puts its VirtualClock there).
Result<std::unique_ptr<Board>> OpenBoard(const std::string& spec, OpenContext* context);
Result<std::unique_ptr<Camera>> OpenCamera(const std::string& spec, const OpenContext& context);

struct DeviceList {
  std::vector<DeviceListing> boards;
  std::vector<DeviceListing> cameras;
  std::vector<std::string> errors;  // a backend that could not list ("v4l2: /dev: permission denied")
};
DeviceList ListDevices();

// The backend names this project knows of, and whether this build has them.
std::vector<std::string> BuiltCameraBackends();
std::vector<std::string> BuiltBoardBackends();

}  // namespace rotoscan::capture

// libFuzzer target: the virtual scanner's scene reader (sim::ParseScene). Mesh and texture paths resolve
// under a directory that does not exist, so no file outside is read. A scene that parses has a camera whose
// lens model can be inverted (the renderer's precondition).
#include <cstddef>
#include <cstdint>
#include <cstdlib>
#include <string>

#include "rotoscan/sim/scene.h"

extern "C" int LLVMFuzzerTestOneInput(const uint8_t* data, size_t size) {
  const std::string text(reinterpret_cast<const char*>(data), size);
  const rotoscan::Result<rotoscan::sim::Scene> scene =
      rotoscan::sim::ParseScene(text, "/nonexistent-rotoscan-fuzz", "fuzz");
  if (!scene.ok()) return 0;
  if (!scene->rig.Validate().ok() || !scene->rig.camera.CheckInvertible().ok()) std::abort();
  return 0;
}

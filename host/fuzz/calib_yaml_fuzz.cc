// libFuzzer target: calib.yaml / rig.yaml as read by geometry::ParseRigYaml (OpenCV's FileStorage parser,
// then our fields). A rig that parses is valid and is written back to YAML that parses to the same rig.
#include <cstddef>
#include <cstdint>
#include <cstdlib>
#include <string>

#include <opencv2/core.hpp>

#include "rotoscan/geometry/rig.h"

extern "C" int LLVMFuzzerTestOneInput(const uint8_t* data, size_t size) {
  const std::string text(reinterpret_cast<const char*>(data), size);
  const rotoscan::Result<rotoscan::geometry::Rig> rig = rotoscan::geometry::ParseRigYaml(text, "fuzz");
  if (!rig.ok()) return 0;
  if (!rig->Validate().ok()) std::abort();
  cv::FileStorage out(".yaml", cv::FileStorage::WRITE | cv::FileStorage::MEMORY | cv::FileStorage::FORMAT_YAML);
  rotoscan::geometry::WriteRigNodes(out, *rig);
  const rotoscan::Result<rotoscan::geometry::Rig> again =
      rotoscan::geometry::ParseRigYaml(out.releaseAndGetString(), "again");
  if (!again.ok() || again->camera.width != rig->camera.width) std::abort();
  return 0;
}

// libFuzzer target: the PLY point-cloud reader (cloud::DecodePly). A cloud that decodes must encode
// (EncodePly) to bytes that decode to as many points.
#include <cstddef>
#include <cstdint>
#include <cstdlib>
#include <string>

#include "rotoscan/cloud/cloud.h"

extern "C" int LLVMFuzzerTestOneInput(const uint8_t* data, size_t size) {
  const std::string bytes(reinterpret_cast<const char*>(data), size);
  const rotoscan::Result<rotoscan::cloud::PointCloud> cloud = rotoscan::cloud::DecodePly(bytes, "fuzz");
  if (!cloud.ok()) return 0;
  for (const auto& p : cloud->points) {
    if (!p.position_in_table.allFinite()) return 0;  // WritePly refuses these
  }
  const rotoscan::Result<rotoscan::cloud::PointCloud> again =
      rotoscan::cloud::DecodePly(rotoscan::cloud::EncodePly(*cloud), "again");
  if (!again.ok() || again->size() != cloud->size()) std::abort();
  return 0;
}

// libFuzzer target: bundle.json as read from a bundle (bundle::ParseBundleJson). What parses must be
// written back by BundleJson() to text that parses to the same frames (the reader never accepts what the
// writer would write differently). See host/fuzz/CMakeLists.txt and scripts/fuzz.sh.
#include <cstddef>
#include <cstdint>
#include <cstdlib>
#include <string>

#include "rotoscan/bundle/bundle.h"

extern "C" int LLVMFuzzerTestOneInput(const uint8_t* data, size_t size) {
  const std::string text(reinterpret_cast<const char*>(data), size);
  const rotoscan::Result<rotoscan::bundle::Bundle> parsed = rotoscan::bundle::ParseBundleJson(text, "fuzz");
  if (!parsed.ok()) return 0;
  const std::string again = rotoscan::bundle::BundleJson(parsed->header, parsed->frames);
  const rotoscan::Result<rotoscan::bundle::Bundle> reparsed = rotoscan::bundle::ParseBundleJson(again, "again");
  if (!reparsed.ok() || reparsed->frames.size() != parsed->frames.size()) std::abort();
  return 0;
}

#include "testing/testing.h"

#include <unistd.h>

#include <atomic>
#include <random>
#include <system_error>

namespace rotoscan::testing {

std::filesystem::path DataPath(const std::string& relative) {
  return std::filesystem::path(ROTOSCAN_SOURCE_DIR) / "data" / relative;
}

ScratchDir::ScratchDir() {
  static std::atomic<unsigned> counter{0};
  std::random_device device;
  path_ = std::filesystem::temp_directory_path() /
          ("rotoscan-test-" + std::to_string(::getpid()) + "-" + std::to_string(counter.fetch_add(1)) + "-" +
           std::to_string(device()));
  std::filesystem::create_directories(path_);
}

ScratchDir::~ScratchDir() {
  std::error_code ec;
  std::filesystem::remove_all(path_, ec);
}

}  // namespace rotoscan::testing

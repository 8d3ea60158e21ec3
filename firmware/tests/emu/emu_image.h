// Where the emulator tests find the image: the .elf of the cross build (firmware.cross_build, a CTest
// fixture they require), or $ROTOSCAN_FW_ELF. A test skips with the reason when there is none.
#pragma once

#include <cstdlib>
#include <fstream>
#include <string>

namespace rotoscan::fw_emu {

inline std::string ImagePath() {
  if (const char* p = std::getenv("ROTOSCAN_FW_ELF"); p != nullptr && *p != '\0') return p;
  return ROTOSCAN_FW_CROSS_DIR "/rotoscan-fw.elf";
}

inline bool ImageExists(const std::string& path) {
  return std::ifstream(path).good();
}

}  // namespace rotoscan::fw_emu

// A small reader of the ARM ELF32 executables the firmware's cross build links (rotoscan-fw.elf): the
// loadable segments at their load addresses (what a flasher writes), the sections' extents, and the symbol
// table. Our own, from the ELF specification (System V gABI, "ELF-32 Object File Format"); every offset and
// count read from the file is checked against its size before use.
#pragma once

#include <cstdint>
#include <map>
#include <string>
#include <vector>

namespace rotoscan::fw_emu {

struct ElfSegment {
  uint32_t load_address = 0;  // p_paddr: where the bytes lie in flash
  uint32_t address = 0;       // p_vaddr: where the program uses them
  uint32_t mem_size = 0;
  std::vector<uint8_t> bytes;  // p_filesz bytes (none for .bss-like segments)
};

struct ElfSection {
  uint32_t address = 0;
  uint32_t size = 0;
};

struct ElfImage {
  uint32_t entry = 0;
  std::vector<ElfSegment> segments;
  std::map<std::string, ElfSection> sections;
  std::map<std::string, uint32_t> symbols;  // value (Thumb functions with bit 0 set)

  // The symbol's value, or `fallback` when the image has no such symbol.
  uint32_t Symbol(const std::string& name, uint32_t fallback = 0) const;
};

// Reads `path`. Returns false and says why in *error for a file that is not a little-endian ARM ELF32
// executable or is truncated.
bool ReadElf(const std::string& path, ElfImage* image, std::string* error);

}  // namespace rotoscan::fw_emu

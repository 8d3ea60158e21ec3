// See elf_image.h. Field offsets are those of Elf32_Ehdr, Elf32_Phdr, Elf32_Shdr and Elf32_Sym.
#include "elf_image.h"

#include <fstream>
#include <iterator>

namespace rotoscan::fw_emu {

namespace {

constexpr uint32_t kPtLoad = 1;
constexpr uint32_t kShtSymtab = 2;
constexpr uint16_t kEmArm = 40;
constexpr uint16_t kEtExec = 2;

struct Reader {
  const std::vector<uint8_t>& b;
  bool ok = true;
  uint32_t U32(size_t at) {
    if (at + 4 > b.size()) {
      ok = false;
      return 0;
    }
    return uint32_t(b[at]) | uint32_t(b[at + 1]) << 8 | uint32_t(b[at + 2]) << 16 | uint32_t(b[at + 3]) << 24;
  }
  uint16_t U16(size_t at) {
    if (at + 2 > b.size()) {
      ok = false;
      return 0;
    }
    return uint16_t(b[at] | b[at + 1] << 8);
  }
  std::string Str(size_t table, size_t table_size, uint32_t index) {
    if (index >= table_size || table + table_size > b.size()) {
      ok = false;
      return {};
    }
    std::string s;
    for (size_t i = table + index; i < table + table_size && b[i] != 0; ++i) s.push_back(char(b[i]));
    return s;
  }
};

}  // namespace

uint32_t ElfImage::Symbol(const std::string& name, uint32_t fallback) const {
  auto it = symbols.find(name);
  return it == symbols.end() ? fallback : it->second;
}

bool ReadElf(const std::string& path, ElfImage* image, std::string* error) {
  std::ifstream in(path, std::ios::binary);
  if (!in) {
    *error = "cannot open " + path;
    return false;
  }
  const std::vector<uint8_t> b((std::istreambuf_iterator<char>(in)), std::istreambuf_iterator<char>());
  if (b.size() < 52 || b[0] != 0x7F || b[1] != 'E' || b[2] != 'L' || b[3] != 'F') {
    *error = path + ": not an ELF file";
    return false;
  }
  if (b[4] != 1 || b[5] != 1) {
    *error = path + ": not a little-endian ELF32 file";
    return false;
  }
  Reader r{b};
  if (r.U16(16) != kEtExec || r.U16(18) != kEmArm) {
    *error = path + ": not an ARM executable";
    return false;
  }
  *image = ElfImage{};
  image->entry = r.U32(24);
  const uint32_t phoff = r.U32(28), shoff = r.U32(32);
  const uint16_t phentsize = r.U16(42), phnum = r.U16(44), shentsize = r.U16(46), shnum = r.U16(48),
                 shstrndx = r.U16(50);
  if (phentsize < 32 || (shnum > 0 && shentsize < 40)) {
    *error = path + ": bad header entry sizes";
    return false;
  }
  for (uint32_t i = 0; i < phnum && r.ok; ++i) {
    const size_t p = size_t(phoff) + size_t(i) * phentsize;
    if (r.U32(p) != kPtLoad) continue;
    ElfSegment s;
    const uint32_t offset = r.U32(p + 4), filesz = r.U32(p + 16);
    s.address = r.U32(p + 8);
    s.load_address = r.U32(p + 12);
    s.mem_size = r.U32(p + 20);
    if (size_t(offset) + filesz > b.size() || filesz > s.mem_size) {
      *error = path + ": a segment lies beyond the end of the file";
      return false;
    }
    s.bytes.assign(b.begin() + offset, b.begin() + offset + filesz);
    image->segments.push_back(std::move(s));
  }
  // Sections: names, then the symbol table through its linked string table.
  const size_t shstr_hdr = size_t(shoff) + size_t(shstrndx) * shentsize;
  const uint32_t shstr_off = r.U32(shstr_hdr + 16), shstr_size = r.U32(shstr_hdr + 20);
  for (uint32_t i = 0; i < shnum && r.ok; ++i) {
    const size_t h = size_t(shoff) + size_t(i) * shentsize;
    const std::string name = r.Str(shstr_off, shstr_size, r.U32(h));
    if (!name.empty()) image->sections[name] = ElfSection{r.U32(h + 12), r.U32(h + 20)};
    if (r.U32(h + 4) != kShtSymtab) continue;
    const uint32_t off = r.U32(h + 16), size = r.U32(h + 20), link = r.U32(h + 24), entsize = r.U32(h + 36);
    if (entsize < 16 || link >= shnum || size_t(off) + size > b.size()) {
      *error = path + ": bad symbol table";
      return false;
    }
    const size_t strhdr = size_t(shoff) + size_t(link) * shentsize;
    const uint32_t str_off = r.U32(strhdr + 16), str_size = r.U32(strhdr + 20);
    for (uint32_t s = 0; s + entsize <= size && r.ok; s += entsize) {
      const std::string sym = r.Str(str_off, str_size, r.U32(off + s));
      if (!sym.empty() && sym.find('$') != 0) image->symbols[sym] = r.U32(off + s + 4);
    }
  }
  if (!r.ok) {
    *error = path + ": truncated";
    return false;
  }
  if (image->segments.empty()) {
    *error = path + ": no loadable segment";
    return false;
  }
  return true;
}

}  // namespace rotoscan::fw_emu

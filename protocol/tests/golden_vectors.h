// The golden frames of protocol/vectors/ for the tests that replay them (protocol, firmware, host device
// client): one reader, so that every side reads the same bytes the same way.
//
// A .hex vector is whitespace-separated two-digit hex bytes; '#' starts a comment to the end of the line.
// vectors.json is the manifest (file, direction, what the frame must decode to).
#pragma once

#include <cstdint>
#include <fstream>
#include <sstream>
#include <stdexcept>
#include <string>
#include <vector>

#include <nlohmann/json.hpp>

namespace rotoscan::protocol_testing {

// protocol/vectors/ in the source tree (ROTOSCAN_SOURCE_DIR is defined for every test target).
inline std::string VectorsDir() { return std::string(ROTOSCAN_SOURCE_DIR) + "/protocol/vectors/"; }

// The bytes of `file` (a name in VectorsDir(), or a path). Throws std::runtime_error naming the file and
// the word when the file is missing or a word is not a two-digit hex byte: a broken vector fails loudly.
inline std::vector<uint8_t> ReadHexVector(const std::string& file) {
  const std::string path = file.find('/') == std::string::npos ? VectorsDir() + file : file;
  std::ifstream in(path);
  if (!in.good()) throw std::runtime_error("cannot read golden vector " + path);
  std::vector<uint8_t> bytes;
  std::string line;
  while (std::getline(in, line)) {
    std::istringstream words(line.substr(0, line.find('#')));
    std::string word;
    while (words >> word) {
      std::size_t used = 0;
      unsigned long value = 0;
      try {
        value = std::stoul(word, &used, 16);
      } catch (const std::exception&) {
        used = 0;
      }
      if (word.size() != 2 || used != 2 || value > 0xFF) {
        throw std::runtime_error(path + ": '" + word + "' is not a two-digit hex byte");
      }
      bytes.push_back(static_cast<uint8_t>(value));
    }
  }
  return bytes;
}

// vectors.json, parsed. Throws std::runtime_error when it is missing or not JSON.
inline nlohmann::json ReadVectorManifest() {
  std::ifstream in(VectorsDir() + "vectors.json");
  if (!in.good()) throw std::runtime_error("cannot read " + VectorsDir() + "vectors.json");
  return nlohmann::json::parse(in);
}

}  // namespace rotoscan::protocol_testing

#include "backend_options.h"

#include <algorithm>
#include <cstdlib>
#include <sstream>

namespace rotoscan::capture::internal {

Result<BackendOptions> BackendOptions::Parse(const std::vector<std::string>& entries, const std::string& backend,
                                             const std::vector<std::string>& known) {
  BackendOptions options;
  options.backend_ = backend;
  for (const std::string& entry : entries) {
    const auto eq = entry.find('=');
    if (eq == std::string::npos || eq == 0) {
      return InvalidArgumentError(backend + ": option '" + entry + "' is not key=value");
    }
    const std::string key = entry.substr(0, eq);
    if (std::find(known.begin(), known.end(), key) == known.end()) continue;  // another backend's
    options.values_[key] = entry.substr(eq + 1);
  }
  return options;
}

Result<double> BackendOptions::Number(const std::string& key, double fallback) const {
  const auto it = values_.find(key);
  if (it == values_.end()) return fallback;
  char* end = nullptr;
  const double v = std::strtod(it->second.c_str(), &end);
  if (it->second.empty() || end == nullptr || *end != '\0') {
    return InvalidArgumentError(backend_ + ": option " + key + "=" + it->second + " is not a number");
  }
  return v;
}

std::string BackendOptions::Text(const std::string& key, const std::string& fallback) const {
  const auto it = values_.find(key);
  return it == values_.end() ? fallback : it->second;
}

Result<std::vector<long long>> BackendOptions::List(const std::string& key) const {
  std::vector<long long> out;
  const auto it = values_.find(key);
  if (it == values_.end()) return out;
  std::stringstream stream(it->second);
  std::string item;
  while (std::getline(stream, item, ',')) {
    char* end = nullptr;
    const long long v = std::strtoll(item.c_str(), &end, 10);
    if (item.empty() || *end != '\0') {
      return InvalidArgumentError(backend_ + ": option " + key + "=" + it->second + " is not a list of integers");
    }
    out.push_back(v);
  }
  return out;
}

}  // namespace rotoscan::capture::internal

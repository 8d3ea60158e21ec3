// "key=value" backend options (OpenContext::options), parsed with clear errors.
#pragma once

#include <map>
#include <string>
#include <vector>

#include "rotoscan/core/status.h"

namespace rotoscan::capture::internal {

class BackendOptions {
 public:
  // kInvalidArgument for an entry without '='; keys not in `known` belong to another backend (skipped).
  static Result<BackendOptions> Parse(const std::vector<std::string>& entries, const std::string& backend,
                                      const std::vector<std::string>& known);
  bool Has(const std::string& key) const { return values_.count(key) != 0; }
  Result<double> Number(const std::string& key, double fallback) const;
  std::string Text(const std::string& key, const std::string& fallback) const;
  // "5,17,40" -> numbers.
  Result<std::vector<long long>> List(const std::string& key) const;

 private:
  std::string backend_;
  std::map<std::string, std::string> values_;
};

}  // namespace rotoscan::capture::internal

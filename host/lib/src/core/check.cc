#include "rotoscan/core/check.h"

namespace rotoscan::internal {

CheckFailure::CheckFailure(const char* file, int line, const char* condition) {
  stream_ << file << ":" << line << ": check failed: " << condition << ". ";
}

// NOLINTNEXTLINE(bugprone-exception-escape): a failed check throws from here, by design.
CheckFailure::~CheckFailure() noexcept(false) {
  throw PreconditionError(stream_.str());
}

}  // namespace rotoscan::internal

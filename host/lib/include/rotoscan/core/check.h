// Precondition checks (see core/status.h for the error policy). A failed check is a caller bug: it throws
// rotoscan::PreconditionError whose message holds the file, the line, the condition and a description.
//
//   ROTOSCAN_CHECK(width > 0) << "image width " << width;
#pragma once

#include <sstream>
#include <string>

#include "rotoscan/core/status.h"

namespace rotoscan::internal {

// Collects the message of a failed check and throws when it goes out of scope at the end of the statement.
class CheckFailure {
 public:
  CheckFailure(const char* file, int line, const char* condition);
  CheckFailure(const CheckFailure&) = delete;
  CheckFailure& operator=(const CheckFailure&) = delete;
  [[noreturn]] ~CheckFailure() noexcept(false);  // NOLINT(bugprone-exception-escape): throws by design

  template <typename T>
  CheckFailure& operator<<(const T& value) {
    stream_ << value;
    return *this;
  }

 private:
  std::ostringstream stream_;
};

// Lets `cond ? (void)0 : Voidify() & CheckFailure(...) << ...` type-check.
struct Voidify {
  void operator&(const CheckFailure&) {}
};

}  // namespace rotoscan::internal

#define ROTOSCAN_CHECK(condition) \
  (condition)                     \
      ? (void)0                   \
      : ::rotoscan::internal::Voidify() & ::rotoscan::internal::CheckFailure(__FILE__, __LINE__, #condition)

#define ROTOSCAN_CHECK_EQ(a, b) ROTOSCAN_CHECK((a) == (b)) << #a " = " << (a) << ", " #b " = " << (b) << ". "
#define ROTOSCAN_CHECK_GT(a, b) ROTOSCAN_CHECK((a) > (b)) << #a " = " << (a) << ", " #b " = " << (b) << ". "
#define ROTOSCAN_CHECK_GE(a, b) ROTOSCAN_CHECK((a) >= (b)) << #a " = " << (a) << ", " #b " = " << (b) << ". "
#define ROTOSCAN_CHECK_LT(a, b) ROTOSCAN_CHECK((a) < (b)) << #a " = " << (a) << ", " #b " = " << (b) << ". "
#define ROTOSCAN_CHECK_LE(a, b) ROTOSCAN_CHECK((a) <= (b)) << #a " = " << (a) << ", " #b " = " << (b) << ". "

// The error policy of librotoscan, written down once (STYLE.md §6):
//
//  * A broken precondition -- a caller bug such as a negative image size or a null pointer -- throws
//    rotoscan::PreconditionError (a std::logic_error) carrying the file and line, through ROTOSCAN_CHECK
//    (core/check.h). Nothing catches it inside the library.
//  * An expected failure -- an unreadable file, a corrupt image, no device, a solve that did not converge,
//    a bundle missing frames -- is returned as a Status, or as a Result<T> that holds either a value or a
//    Status. Both are [[nodiscard]]: the caller must look.
//  * Library code never aborts the process, never prints to stdout, and never returns an empty object as
//    if it had succeeded. The CLI turns a failed Status into a message on stderr and a non-zero exit code.
#pragma once

#include <optional>
#include <stdexcept>
#include <string>
#include <utility>
#include <variant>

namespace rotoscan {

enum class StatusCode {
  kOk = 0,
  kInvalidArgument,     // the input is wrong (bad option, malformed file content, wrong image size)
  kNotFound,            // a file, device, frame or target that should be there is not
  kIoError,             // the operating system refused a read or write
  kCorruptData,         // the data is there but does not decode (bad image, truncated PLY, CRC error)
  kFailedPrecondition,  // the state does not allow it (e.g. no calibration loaded, device not open)
  kNotConverged,        // an estimator or solver did not reach an acceptable answer
  kDeviceError,         // the scanner board answered with an error or stopped answering
  kTimeout,             // a deadline passed
  kUnimplemented,       // the feature is not built yet
  kCancelled,           // the user stopped it
  kInternal,            // an invariant broke: a bug to report
};

// Short lower-case name of a code, e.g. "invalid argument".
const char* StatusCodeName(StatusCode code);

class [[nodiscard]] Status {
 public:
  Status() = default;  // OK
  Status(StatusCode code, std::string message) : code_(code), message_(std::move(message)) {}

  static Status Ok() { return Status(); }

  bool ok() const { return code_ == StatusCode::kOk; }
  StatusCode code() const { return code_; }
  const std::string& message() const { return message_; }

  // "invalid argument: scene.json: field 'camera.fx' must be > 0", or "ok".
  std::string ToString() const;

  // Returns a copy whose message is prefixed with `context`: ("reading calib.yaml") -> "reading calib.yaml:
  // <message>". Used to say where an error happened as it travels up.
  Status WithContext(const std::string& context) const;

 private:
  StatusCode code_ = StatusCode::kOk;
  std::string message_;
};

inline Status InvalidArgumentError(std::string m) {
  return {StatusCode::kInvalidArgument, std::move(m)};
}
inline Status NotFoundError(std::string m) {
  return {StatusCode::kNotFound, std::move(m)};
}
inline Status IoError(std::string m) {
  return {StatusCode::kIoError, std::move(m)};
}
inline Status CorruptDataError(std::string m) {
  return {StatusCode::kCorruptData, std::move(m)};
}
inline Status FailedPreconditionError(std::string m) {
  return {StatusCode::kFailedPrecondition, std::move(m)};
}
inline Status NotConvergedError(std::string m) {
  return {StatusCode::kNotConverged, std::move(m)};
}
inline Status DeviceError(std::string m) {
  return {StatusCode::kDeviceError, std::move(m)};
}
inline Status TimeoutError(std::string m) {
  return {StatusCode::kTimeout, std::move(m)};
}
inline Status UnimplementedError(std::string m) {
  return {StatusCode::kUnimplemented, std::move(m)};
}
inline Status CancelledError(std::string m) {
  return {StatusCode::kCancelled, std::move(m)};
}
inline Status InternalError(std::string m) {
  return {StatusCode::kInternal, std::move(m)};
}

// Thrown by Result<T>::value() on an error result, and by ROTOSCAN_CHECK: both mean a caller bug.
class PreconditionError : public std::logic_error {
 public:
  using std::logic_error::logic_error;
};

// Either a T or a non-OK Status.
template <typename T>
class [[nodiscard]] Result {
 public:
  Result(T value) : state_(std::move(value)) {}  // NOLINT(google-explicit-constructor): implicit by design
  Result(Status status) : state_(std::move(status)) {  // NOLINT(google-explicit-constructor)
    if (std::get<Status>(state_).ok()) {
      state_ = Status(StatusCode::kInternal, "Result constructed from an OK status without a value");
    }
  }

  bool ok() const { return std::holds_alternative<T>(state_); }
  // The error, or OK when a value is held.
  Status status() const { return ok() ? Status::Ok() : std::get<Status>(state_); }

  // Accessing the value of an error result is a caller bug: it throws PreconditionError with the status.
  const T& value() const& {
    ThrowIfError();
    return std::get<T>(state_);
  }
  T& value() & {
    ThrowIfError();
    return std::get<T>(state_);
  }
  T&& value() && {
    ThrowIfError();
    return std::get<T>(std::move(state_));
  }
  const T& operator*() const& { return value(); }
  T& operator*() & { return value(); }
  const T* operator->() const { return &value(); }
  T* operator->() { return &value(); }

 private:
  void ThrowIfError() const {
    if (!ok()) throw PreconditionError("value() of a failed Result: " + std::get<Status>(state_).ToString());
  }
  std::variant<T, Status> state_;
};

}  // namespace rotoscan

#define ROTOSCAN_STATUS_CONCAT_INNER(a, b) a##b
#define ROTOSCAN_STATUS_CONCAT(a, b) ROTOSCAN_STATUS_CONCAT_INNER(a, b)

// Returns the status from the enclosing function if `expr` (a Status) is not OK.
#define ROTOSCAN_RETURN_IF_ERROR(expr)                   \
  do {                                                   \
    ::rotoscan::Status rotoscan_status_ = (expr);        \
    if (!rotoscan_status_.ok()) return rotoscan_status_; \
  } while (false)

// ROTOSCAN_ASSIGN_OR_RETURN(auto x, F()); -- declares x from a Result, or returns its error.
#define ROTOSCAN_ASSIGN_OR_RETURN(lhs, expr) \
  ROTOSCAN_ASSIGN_OR_RETURN_IMPL(ROTOSCAN_STATUS_CONCAT(rotoscan_result_, __LINE__), lhs, expr)
#define ROTOSCAN_ASSIGN_OR_RETURN_IMPL(tmp, lhs, expr) \
  auto tmp = (expr);                                   \
  if (!tmp.ok()) return tmp.status();                  \
  lhs = std::move(tmp).value()

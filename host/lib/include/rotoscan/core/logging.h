// Logging with levels. Messages go to a sink (stderr by default) as "[level] message"; library code logs,
// it never prints to stdout (stdout belongs to the CLI's results). Thread-safe.
//
//   ROTOSCAN_LOG(kInfo) << "rendered " << n << " frames";
//
// The level comes from SetLogLevel(), or at start-up from the ROTOSCAN_LOG_LEVEL environment variable
// (trace, debug, info, warning, error, off). Default: info.
#pragma once

#include <functional>
#include <optional>
#include <sstream>
#include <string>
#include <string_view>

namespace rotoscan {

enum class LogLevel { kTrace = 0, kDebug, kInfo, kWarning, kError, kOff };

void SetLogLevel(LogLevel level);
LogLevel GetLogLevel();
bool IsLogEnabled(LogLevel level);

// "info" -> kInfo; nullopt for an unknown name.
std::optional<LogLevel> ParseLogLevel(std::string_view name);
const char* LogLevelName(LogLevel level);

// Replaces where messages go (for tests, or a GUI); an empty function restores stderr.
using LogSink = std::function<void(LogLevel, const std::string&)>;
void SetLogSink(LogSink sink);

namespace internal {
class LogMessage {
 public:
  explicit LogMessage(LogLevel level) : level_(level) {}
  LogMessage(const LogMessage&) = delete;
  LogMessage& operator=(const LogMessage&) = delete;
  ~LogMessage();
  template <typename T>
  LogMessage& operator<<(const T& value) {
    stream_ << value;
    return *this;
  }

 private:
  LogLevel level_;
  std::ostringstream stream_;
};
}  // namespace internal

}  // namespace rotoscan

#define ROTOSCAN_LOG(level)                                     \
  if (!::rotoscan::IsLogEnabled(::rotoscan::LogLevel::level)) { \
  } else                                                        \
    ::rotoscan::internal::LogMessage(::rotoscan::LogLevel::level)

#include "rotoscan/core/logging.h"

#include <atomic>
#include <cstdio>
#include <cstdlib>
#include <mutex>

namespace rotoscan {
namespace {

LogLevel InitialLevel() {
  const char* env = std::getenv("ROTOSCAN_LOG_LEVEL");
  if (env != nullptr) {
    if (auto level = ParseLogLevel(env)) return *level;
  }
  return LogLevel::kInfo;
}

std::atomic<int>& LevelStorage() {
  static std::atomic<int> level{static_cast<int>(InitialLevel())};
  return level;
}

std::mutex& SinkMutex() {
  static std::mutex mutex;
  return mutex;
}

LogSink& Sink() {
  static LogSink sink;
  return sink;
}

}  // namespace

void SetLogLevel(LogLevel level) {
  LevelStorage().store(static_cast<int>(level));
}
LogLevel GetLogLevel() {
  return static_cast<LogLevel>(LevelStorage().load());
}
bool IsLogEnabled(LogLevel level) {
  return level != LogLevel::kOff && static_cast<int>(level) >= LevelStorage().load();
}

std::optional<LogLevel> ParseLogLevel(std::string_view name) {
  if (name == "trace") return LogLevel::kTrace;
  if (name == "debug") return LogLevel::kDebug;
  if (name == "info") return LogLevel::kInfo;
  if (name == "warning" || name == "warn") return LogLevel::kWarning;
  if (name == "error") return LogLevel::kError;
  if (name == "off") return LogLevel::kOff;
  return std::nullopt;
}

const char* LogLevelName(LogLevel level) {
  switch (level) {
    case LogLevel::kTrace: return "trace";
    case LogLevel::kDebug: return "debug";
    case LogLevel::kInfo: return "info";
    case LogLevel::kWarning: return "warning";
    case LogLevel::kError: return "error";
    case LogLevel::kOff: return "off";
  }
  return "?";
}

void SetLogSink(LogSink sink) {
  std::lock_guard<std::mutex> lock(SinkMutex());
  Sink() = std::move(sink);
}

namespace internal {

LogMessage::~LogMessage() {
  const std::string text = stream_.str();
  std::lock_guard<std::mutex> lock(SinkMutex());
  if (Sink()) {
    Sink()(level_, text);
  } else {
    std::fprintf(stderr, "[%s] %s\n", LogLevelName(level_), text.c_str());
    std::fflush(stderr);
  }
}

}  // namespace internal
}  // namespace rotoscan

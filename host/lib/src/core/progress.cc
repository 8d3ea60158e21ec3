#include "rotoscan/core/progress.h"

#include <unistd.h>

#include <cmath>
#include <csignal>
#include <cstdlib>
#include <cstring>

namespace rotoscan {

bool ShouldDrawProgress(std::FILE* stream) {
  if (stream == nullptr || isatty(fileno(stream)) == 0) return false;
  const char* term = std::getenv("TERM");
  if (term != nullptr && std::strcmp(term, "dumb") == 0) return false;
  const char* ci = std::getenv("CI");
  return ci == nullptr || ci[0] == '\0' || std::strcmp(ci, "false") == 0 || std::strcmp(ci, "0") == 0;
}

ProgressBar::ProgressBar(Mode mode, std::FILE* stream)
    : stream_(stream),
      enabled_(mode == Mode::kAlways || (mode == Mode::kAuto && ShouldDrawProgress(stream))) {}

ProgressBar::~ProgressBar() {
  if (active_) End();
}

void ProgressBar::Begin(const std::string& label, uint64_t total) {
  std::lock_guard<std::mutex> lock(mutex_);
  label_ = label;
  total_ = total;
  done_ = 0;
  unit_.clear();
  secondary_unit_.clear();
  secondary_done_ = 0;
  active_ = true;
  start_ = std::chrono::steady_clock::now();
  last_draw_ = start_ - std::chrono::seconds(1);
  Draw(false);
}

void ProgressBar::Advance(uint64_t n) {
  done_.fetch_add(n);
  if (!enabled_) return;
  const auto now = std::chrono::steady_clock::now();
  std::unique_lock<std::mutex> lock(mutex_, std::try_to_lock);
  if (!lock.owns_lock() || now - last_draw_ < std::chrono::milliseconds(100)) return;
  Draw(false);
}

void ProgressBar::SetUnits(const std::string& unit, const std::string& secondary_unit) {
  std::lock_guard<std::mutex> lock(mutex_);
  unit_ = unit;
  secondary_unit_ = secondary_unit;
}

void ProgressBar::AdvanceSecondary(uint64_t n) { secondary_done_.fetch_add(n); }

void ProgressBar::End() {
  std::lock_guard<std::mutex> lock(mutex_);
  if (!active_) return;
  Draw(true);
  active_ = false;
}

std::string ProgressBar::FormatLine(double elapsed_s) const {
  constexpr int kWidth = 30;
  const uint64_t done = done_.load();
  const uint64_t secondary = secondary_done_.load();
  std::string line = label_;
  char buffer[160];
  const double rate = elapsed_s > 0 ? static_cast<double>(done) / elapsed_s : 0.0;
  const double secondary_rate = elapsed_s > 0 ? static_cast<double>(secondary) / elapsed_s : 0.0;
  const std::string unit = unit_.empty() ? "" : " " + unit_;
  // "  7.5 steps/s  30.0 frames/s" (or "  7.5/s" without units): the rates while the work runs.
  auto rates = [&] {
    std::snprintf(buffer, sizeof(buffer), "  %.1f%s/s", rate, unit.c_str());
    std::string text = buffer;
    if (!secondary_unit_.empty()) {
      std::snprintf(buffer, sizeof(buffer), "  %.1f %s/s", secondary_rate, secondary_unit_.c_str());
      text += buffer;
    }
    return text;
  };
  if (total_ > 0) {
    const double fraction = std::min(1.0, static_cast<double>(done) / static_cast<double>(total_));
    const int filled = static_cast<int>(std::lround(fraction * kWidth));
    line += "  [" + std::string(filled, '#') + std::string(kWidth - filled, '.') + "]";
    std::snprintf(buffer, sizeof(buffer), " %3d%% %llu/%llu%s", static_cast<int>(fraction * 100.0),
                  static_cast<unsigned long long>(done), static_cast<unsigned long long>(total_), unit.c_str());
    line += buffer;
    if (rate > 0 && done < total_) {
      line += rates();
      std::snprintf(buffer, sizeof(buffer), "  eta %.0fs", static_cast<double>(total_ - done) / rate);
      line += buffer;
    } else {
      if (!secondary_unit_.empty()) {
        std::snprintf(buffer, sizeof(buffer), "  %llu %s", static_cast<unsigned long long>(secondary),
                      secondary_unit_.c_str());
        line += buffer;
      }
      std::snprintf(buffer, sizeof(buffer), "  %.1fs", elapsed_s);
      line += buffer;
    }
  } else {
    std::snprintf(buffer, sizeof(buffer), "  %llu%s", static_cast<unsigned long long>(done), unit.c_str());
    line += buffer;
    line += rates();
  }
  return line;
}

void ProgressBar::Draw(bool final_line) {
  if (!enabled_) return;
  const auto now = std::chrono::steady_clock::now();
  last_draw_ = now;
  const double elapsed = std::chrono::duration<double>(now - start_).count();
  // \r and clear-to-end-of-line redraw in place; the final line ends with a newline.
  std::fprintf(stream_, "\r%s\x1b[K%s", FormatLine(elapsed).c_str(), final_line ? "\n" : "");
  std::fflush(stream_);
}

namespace {
volatile std::sig_atomic_t interrupt_requested = 0;

extern "C" void OnInterrupt(int signal_number) {
  interrupt_requested = 1;
  static const char kMessage[] = "\nrotoscan: interrupted, stopping cleanly (again to quit at once)\n";
  const ssize_t ignored = ::write(STDERR_FILENO, kMessage, sizeof(kMessage) - 1);
  (void)ignored;
  std::signal(signal_number, SIG_DFL);  // a second signal terminates
}
}  // namespace

void InstallInterruptHandler() {
  std::signal(SIGINT, OnInterrupt);
  std::signal(SIGTERM, OnInterrupt);
}
bool InterruptRequested() { return interrupt_requested != 0; }
void RequestInterrupt() { interrupt_requested = 1; }
void ClearInterrupt() { interrupt_requested = 0; }

bool ProgressBar::Cancelled() const { return InterruptRequested(); }

}  // namespace rotoscan

// Progress of long work (rendering, processing, calibration). Library functions take a `Progress*` that
// may be null; the CLI passes a ProgressBar.
//
// ProgressBar draws a one-line bar with rate and time left when its stream is a terminal, and stays quiet
// otherwise (pipes, files, CI=true in the environment): a log of 1,200 redraws helps no one. It redraws at
// most ten times a second, so calling Advance() per frame is cheap. Thread-safe.
#pragma once

#include <atomic>
#include <chrono>
#include <cstdint>
#include <cstdio>
#include <mutex>
#include <string>

namespace rotoscan {

class Progress {
 public:
  virtual ~Progress() = default;
  // Starts a phase of `total` units (0 if unknown) named `label`.
  virtual void Begin(const std::string& label, uint64_t total) = 0;
  // `n` more units are done.
  virtual void Advance(uint64_t n = 1) = 0;
  // The phase ended (successfully or not).
  virtual void End() = 0;
  // True when the user asked to stop; long work checks it and returns kCancelled.
  virtual bool Cancelled() const { return false; }
  // Optional, after Begin(): names the phase's units (e.g. "steps") and a second count kept beside them
  // (e.g. "frames", of which a step takes several), advanced by AdvanceSecondary(); a bar then shows both
  // rates. The time left still follows the units. Both reset at the next Begin().
  virtual void SetUnits(const std::string& unit, const std::string& secondary_unit) {
    (void)unit;
    (void)secondary_unit;
  }
  virtual void AdvanceSecondary(uint64_t n = 1) { (void)n; }
};

// Begin() on construction and End() on scope exit; tolerates a null Progress.
class ProgressScope {
 public:
  ProgressScope(Progress* progress, const std::string& label, uint64_t total) : progress_(progress) {
    if (progress_ != nullptr) progress_->Begin(label, total);
  }
  ~ProgressScope() {
    if (progress_ != nullptr) progress_->End();
  }
  ProgressScope(const ProgressScope&) = delete;
  ProgressScope& operator=(const ProgressScope&) = delete;
  void Advance(uint64_t n = 1) {
    if (progress_ != nullptr) progress_->Advance(n);
  }
  void SetUnits(const std::string& unit, const std::string& secondary_unit) {
    if (progress_ != nullptr) progress_->SetUnits(unit, secondary_unit);
  }
  void AdvanceSecondary(uint64_t n = 1) {
    if (progress_ != nullptr) progress_->AdvanceSecondary(n);
  }
  bool Cancelled() const { return progress_ != nullptr && progress_->Cancelled(); }

 private:
  Progress* progress_;
};

class ProgressBar : public Progress {
 public:
  enum class Mode { kAuto, kAlways, kNever };
  // Draws on `stream` (stderr by default). kAuto draws only on a terminal outside CI.
  explicit ProgressBar(Mode mode = Mode::kAuto, std::FILE* stream = stderr);
  ~ProgressBar() override;

  void Begin(const std::string& label, uint64_t total) override;
  void Advance(uint64_t n = 1) override;
  void End() override;
  void SetUnits(const std::string& unit, const std::string& secondary_unit) override;
  void AdvanceSecondary(uint64_t n = 1) override;
  // True once the user interrupted the program (InterruptRequested()).
  bool Cancelled() const override;

  // Whether this bar draws anything (decided at construction).
  bool enabled() const { return enabled_; }
  uint64_t done() const { return done_.load(); }
  uint64_t secondary_done() const { return secondary_done_.load(); }

  // The line that would be drawn, e.g. "render  [#########.........]  45% 540/1200  38.2/s  eta 17s", or
  // with units (SetUnits("steps", "frames")):
  // "scan  [#########.........]  45% 540/1200 steps  7.5 steps/s  30.0 frames/s  eta 88s".
  std::string FormatLine(double elapsed_s) const;

 private:
  void Draw(bool final_line);

  std::FILE* stream_;
  bool enabled_;
  std::mutex mutex_;
  std::string label_;
  uint64_t total_ = 0;
  std::atomic<uint64_t> done_{0};
  std::string unit_;            // empty: no unit shown
  std::string secondary_unit_;  // empty: no second count
  std::atomic<uint64_t> secondary_done_{0};
  bool active_ = false;
  std::chrono::steady_clock::time_point start_;
  std::chrono::steady_clock::time_point last_draw_;
};

// Interrupts (Ctrl-C, SIGTERM). InstallInterruptHandler() (called by the rotoscan program, not by the
// library) makes the first SIGINT/SIGTERM set a flag that long work sees through Progress::Cancelled(), so
// it stops cleanly (an unfinished bundle stays resumable, no output file is left half-written); a second
// one terminates at once. RequestInterrupt() sets the flag by hand (tests), ClearInterrupt() resets it.
void InstallInterruptHandler();
bool InterruptRequested();
void RequestInterrupt();
void ClearInterrupt();

// Whether a progress bar should be drawn on `stream`: a terminal, TERM not "dumb", CI not set.
bool ShouldDrawProgress(std::FILE* stream);

}  // namespace rotoscan

// Helpers for the GoogleTest suites: Eigen matchers, test data paths, scratch directories.
#pragma once

#include <filesystem>
#include <functional>
#include <string>
#include <vector>

#include <gmock/gmock.h>
#include <Eigen/Core>

namespace rotoscan::testing {

// Path of a file under the repository's data/ directory (test data shipped with the project).
std::filesystem::path DataPath(const std::string& relative);

// A fresh directory under the system temp dir, removed with its content on destruction.
class ScratchDir {
 public:
  ScratchDir();
  ~ScratchDir();
  ScratchDir(const ScratchDir&) = delete;
  ScratchDir& operator=(const ScratchDir&) = delete;
  const std::filesystem::path& path() const { return path_; }
  std::filesystem::path operator/(const std::string& name) const { return path_ / name; }

 private:
  std::filesystem::path path_;
};

// Runs `body` in a forked child whose files may not grow beyond `max_file_bytes` (RLIMIT_FSIZE, with
// SIGXFSZ ignored, so that a write past the limit fails with EFBIG as on a full disk) and returns the
// child's exit code (body's return value), or 128 + signal when it died of one. No root needed.
// With `kill_at_limit` SIGXFSZ is left to kill the child: a process killed in the middle of a write.
int RunWithFullDisk(std::size_t max_file_bytes, const std::function<int()>& body, bool kill_at_limit = false);

// Runs the program `argv[0]` in a child process (fork + exec: safe in a threaded test) with its files
// limited to `max_file_bytes` as above (0: no limit), stdout dropped, stderr in `*err` (if not null);
// returns its exit code, or 128 + signal.
int RunProgram(const std::vector<std::string>& argv, std::size_t max_file_bytes, bool kill_at_limit,
               std::string* err);

// Every entry of `dir` (recursively), sorted, as paths relative to it: what a failed run left behind.
std::vector<std::string> ListTree(const std::filesystem::path& dir);

// EXPECT_THAT(v, EigenNear(expected, 1e-9)): element-wise |v - expected| <= tolerance, same shape.
MATCHER_P2(EigenNear, expected, tolerance,
           std::string(negation ? "is not" : "is") + " within " + ::testing::PrintToString(tolerance) +
               " of\n" + ::testing::PrintToString(expected)) {
  if (arg.rows() != expected.rows() || arg.cols() != expected.cols()) {
    *result_listener << "shape " << arg.rows() << "x" << arg.cols();
    return false;
  }
  const double err = (arg - expected).cwiseAbs().maxCoeff();
  *result_listener << "largest difference " << err;
  return err <= tolerance;
}

}  // namespace rotoscan::testing

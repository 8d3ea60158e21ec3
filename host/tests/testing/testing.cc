#include "testing/testing.h"

#include <fcntl.h>
#include <sys/resource.h>
#include <sys/wait.h>
#include <unistd.h>

#include <algorithm>
#include <atomic>
#include <cerrno>
#include <csignal>
#include <fstream>
#include <iterator>
#include <random>
#include <system_error>

namespace rotoscan::testing {

std::filesystem::path DataPath(const std::string& relative) {
  return std::filesystem::path(ROTOSCAN_SOURCE_DIR) / "data" / relative;
}

ScratchDir::ScratchDir() {
  static std::atomic<unsigned> counter{0};
  std::random_device device;
  path_ = std::filesystem::temp_directory_path() /
          ("rotoscan-test-" + std::to_string(::getpid()) + "-" + std::to_string(counter.fetch_add(1)) + "-" +
           std::to_string(device()));
  std::filesystem::create_directories(path_);
}

ScratchDir::~ScratchDir() {
  std::error_code ec;
  std::filesystem::remove_all(path_, ec);
}

int RunWithFullDisk(std::size_t max_file_bytes, const std::function<int()>& body, bool kill_at_limit) {
  const pid_t child = ::fork();
  if (child < 0) return -1;
  if (child == 0) {
    if (!kill_at_limit) std::signal(SIGXFSZ, SIG_IGN);
    const rlimit no_core{0, 0};
    ::setrlimit(RLIMIT_CORE, &no_core);
    const rlimit limit{static_cast<rlim_t>(max_file_bytes), static_cast<rlim_t>(max_file_bytes)};
    if (::setrlimit(RLIMIT_FSIZE, &limit) != 0) ::_exit(125);
    int code = 124;
    try {
      code = body();
    } catch (...) {
      code = 123;
    }
    ::_exit(code);  // no destructors, no atexit: the parent owns the scratch directories
  }
  int status = 0;
  while (::waitpid(child, &status, 0) < 0) {
    if (errno != EINTR) return -1;
  }
  if (WIFSIGNALED(status)) return 128 + WTERMSIG(status);
  return WEXITSTATUS(status);
}

int RunProgram(const std::vector<std::string>& argv, std::size_t max_file_bytes, bool kill_at_limit,
               std::string* err) {
  if (argv.empty()) return -1;
  char err_path[] = "/tmp/rotoscan-test-stderr-XXXXXX";
  const int err_fd = ::mkstemp(err_path);
  if (err_fd < 0) return -1;
  std::vector<char*> args;
  for (const std::string& a : argv) args.push_back(const_cast<char*>(a.c_str()));
  args.push_back(nullptr);
  const pid_t child = ::fork();
  if (child < 0) {
    ::close(err_fd);
    ::unlink(err_path);
    return -1;
  }
  if (child == 0) {
    const int null_fd = ::open("/dev/null", O_WRONLY);
    ::dup2(null_fd, STDOUT_FILENO);
    ::dup2(err_fd, STDERR_FILENO);
    // The ignored SIGXFSZ and the limits survive exec.
    std::signal(SIGXFSZ, kill_at_limit ? SIG_DFL : SIG_IGN);
    const rlimit no_core{0, 0};
    ::setrlimit(RLIMIT_CORE, &no_core);
    if (max_file_bytes > 0) {
      const rlimit limit{static_cast<rlim_t>(max_file_bytes), static_cast<rlim_t>(max_file_bytes)};
      if (::setrlimit(RLIMIT_FSIZE, &limit) != 0) ::_exit(125);
    }
    ::execv(args[0], args.data());
    ::_exit(127);
  }
  int status = 0;
  while (::waitpid(child, &status, 0) < 0) {
    if (errno != EINTR) {
      status = -1;
      break;
    }
  }
  ::close(err_fd);
  if (err != nullptr) {
    std::ifstream in(err_path);
    err->assign(std::istreambuf_iterator<char>(in), std::istreambuf_iterator<char>());
  }
  ::unlink(err_path);
  if (status == -1) return -1;
  if (WIFSIGNALED(status)) return 128 + WTERMSIG(status);
  return WEXITSTATUS(status);
}

std::vector<std::string> ListTree(const std::filesystem::path& dir) {
  std::vector<std::string> out;
  std::error_code ec;
  for (auto it = std::filesystem::recursive_directory_iterator(dir, ec);
       !ec && it != std::filesystem::recursive_directory_iterator(); it.increment(ec)) {
    out.push_back(it->path().lexically_relative(dir).string());
  }
  std::sort(out.begin(), out.end());
  return out;
}

}  // namespace rotoscan::testing

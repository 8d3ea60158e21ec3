#include "rotoscan/core/file.h"

#include <unistd.h>

#include <atomic>
#include <cerrno>
#include <cstring>
#include <fstream>
#include <system_error>

namespace rotoscan {
namespace fs = std::filesystem;

namespace {

fs::path TemporarySibling(const fs::path& path) {
  static std::atomic<unsigned> counter{0};
  fs::path tmp = path;
  tmp += ".tmp-" + std::to_string(::getpid()) + "-" + std::to_string(counter.fetch_add(1));
  return tmp;
}

void RemoveQuietly(const fs::path& path) {
  std::error_code ec;
  fs::remove_all(path, ec);
}

}  // namespace

Status WriteAtomically(const fs::path& path, const std::function<Status(const fs::path&)>& write) {
  if (path.empty()) return InvalidArgumentError("empty output path");
  const fs::path parent = path.has_parent_path() ? path.parent_path() : fs::path(".");
  std::error_code ec;
  if (!fs::is_directory(parent, ec)) {
    return NotFoundError("output directory " + parent.string() + " does not exist");
  }
  const fs::path tmp = TemporarySibling(path);
  Status status;
  try {
    status = write(tmp);
  } catch (...) {
    RemoveQuietly(tmp);
    throw;
  }
  if (!status.ok()) {
    RemoveQuietly(tmp);
    return status;
  }
  if (!fs::exists(tmp, ec)) return InternalError("writer for " + path.string() + " produced no output");
  // A directory cannot be renamed over a non-empty directory: remove the old one first.
  if (fs::is_directory(tmp, ec) && fs::exists(path, ec)) fs::remove_all(path, ec);
  fs::rename(tmp, path, ec);
  if (ec) {
    RemoveQuietly(tmp);
    return IoError("cannot rename " + tmp.string() + " to " + path.string() + ": " + ec.message());
  }
  return Status::Ok();
}

Status WriteFileAtomically(const fs::path& path, const std::string& content) {
  return WriteAtomically(path, [&](const fs::path& tmp) -> Status {
    std::ofstream out(tmp, std::ios::binary);
    if (!out) return IoError("cannot create " + tmp.string() + ": " + std::strerror(errno));
    out.write(content.data(), static_cast<std::streamsize>(content.size()));
    out.flush();
    if (!out) return IoError("cannot write " + tmp.string() + ": " + std::strerror(errno));
    return Status::Ok();
  });
}

Result<std::string> ReadFile(const fs::path& path, std::size_t max_bytes) {
  std::error_code ec;
  if (!fs::exists(path, ec)) return NotFoundError(path.string() + " does not exist");
  if (fs::is_directory(path, ec)) return InvalidArgumentError(path.string() + " is a directory, not a file");
  const auto size = fs::file_size(path, ec);
  if (ec) return IoError("cannot read the size of " + path.string() + ": " + ec.message());
  if (size > max_bytes) {
    return InvalidArgumentError(path.string() + " is " + std::to_string(size) +
                                " bytes, more than the limit of " + std::to_string(max_bytes));
  }
  std::ifstream in(path, std::ios::binary);
  if (!in) return IoError("cannot open " + path.string() + ": " + std::strerror(errno));
  std::string content(size, '\0');
  in.read(content.data(), static_cast<std::streamsize>(size));
  if (static_cast<std::size_t>(in.gcount()) != size) return IoError("short read from " + path.string());
  return content;
}

}  // namespace rotoscan

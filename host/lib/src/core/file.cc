#include "rotoscan/core/file.h"

#include <fcntl.h>
#include <sys/stat.h>
#include <unistd.h>

#include <atomic>
#include <cerrno>
#include <cstring>
#include <fstream>
#include <memory>
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

fs::path ParentOf(const fs::path& path) { return path.has_parent_path() ? path.parent_path() : fs::path("."); }

// What is at `path` without following a symlink: "" when absent or a regular file, else a description.
std::string NotARegularFile(const fs::path& path, bool directory_allowed) {
  struct stat st {};
  if (::lstat(path.c_str(), &st) != 0) return "";
  if (S_ISREG(st.st_mode)) return "";
  if (S_ISDIR(st.st_mode)) return directory_allowed ? "" : "a directory";
  if (S_ISLNK(st.st_mode)) return "a symbolic link";
  if (S_ISCHR(st.st_mode) || S_ISBLK(st.st_mode)) return "a device";
  if (S_ISFIFO(st.st_mode)) return "a FIFO";
  if (S_ISSOCK(st.st_mode)) return "a socket";
  return "not a regular file";
}

Status ErrnoError(const std::string& what, int error) {
  return IoError(what + ": " + std::strerror(error));
}

// fsync on a file or directory by path.
Status SyncPath(const fs::path& path, const fs::path& target) {
  const int fd = ::open(path.c_str(), O_RDONLY | O_CLOEXEC);
  if (fd < 0) return ErrnoError("cannot open " + path.string() + " to sync " + target.string(), errno);
  const int synced = ::fsync(fd);
  const int error = errno;
  ::close(fd);
  // Some file systems cannot sync a directory (EINVAL); that is not a write failure.
  if (synced != 0 && error != EINVAL) return ErrnoError("cannot sync " + target.string(), error);
  return Status::Ok();
}

}  // namespace

namespace {

// A file written to its temporary sibling and synced, not yet renamed into place.
struct Prepared {
  fs::path path, tmp;
  bool directory = false;
};

// Checks the target, calls `write(tmp)` and syncs what it wrote. On failure nothing is left.
Status Prepare(const fs::path& path, const std::function<Status(const fs::path&)>& write, Prepared* out) {
  if (path.empty()) return InvalidArgumentError("empty output path");
  const fs::path parent = ParentOf(path);
  std::error_code ec;
  if (!fs::exists(parent, ec)) return NotFoundError("output directory " + parent.string() + " does not exist");
  if (!fs::is_directory(parent, ec)) return InvalidArgumentError(parent.string() + " is not a directory");
  if (const std::string what = NotARegularFile(path, /*directory_allowed=*/true); !what.empty()) {
    return InvalidArgumentError("refusing to replace " + path.string() + ": it is " + what);
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
  const bool directory = fs::is_directory(tmp, ec);
  status = SyncPath(tmp, path);
  if (!status.ok()) {
    RemoveQuietly(tmp);
    return status;
  }
  *out = {path, tmp, directory};
  return Status::Ok();
}

// Renames a prepared file over its target. On failure the temporary file is removed.
Status Commit(const Prepared& file) {
  std::error_code ec;
  // Checked again just before the rename: the target may have been replaced while we worked.
  if (const std::string what = NotARegularFile(file.path, file.directory); !what.empty()) {
    RemoveQuietly(file.tmp);
    return InvalidArgumentError("refusing to replace " + file.path.string() + ": it is " + what);
  }
  // A directory cannot be renamed over a non-empty directory: remove the old one first.
  if (file.directory && fs::exists(file.path, ec)) fs::remove_all(file.path, ec);
  fs::rename(file.tmp, file.path, ec);
  if (ec) {
    RemoveQuietly(file.tmp);
    return IoError("cannot rename " + file.tmp.string() + " to " + file.path.string() + ": " + ec.message());
  }
  return Status::Ok();
}

}  // namespace

Status WriteAtomically(const fs::path& path, const std::function<Status(const fs::path&)>& write) {
  Prepared file;
  ROTOSCAN_RETURN_IF_ERROR(Prepare(path, write, &file));
  ROTOSCAN_RETURN_IF_ERROR(Commit(file));
  // The rename itself is durable once the directory is synced.
  return SyncPath(ParentOf(path), path);
}

Status WriteFilesTogether(const std::vector<PendingFile>& files) {
  for (std::size_t i = 0; i < files.size(); ++i) {
    for (std::size_t j = 0; j < i; ++j) {
      if (files[i].path.lexically_normal() == files[j].path.lexically_normal())
        return InvalidArgumentError("the same file twice in one commit: " + files[i].path.string());
    }
  }
  // 1. Every file to its temporary sibling; the first failure removes the others' temporaries.
  std::vector<Prepared> prepared;
  auto remove_temporaries = [&](std::size_t from) {
    for (std::size_t k = from; k < prepared.size(); ++k) RemoveQuietly(prepared[k].tmp);
  };
  for (const PendingFile& file : files) {
    Prepared p;
    Status status;
    try {
      status = Prepare(file.path, file.write, &p);
    } catch (...) {
      remove_temporaries(0);
      throw;
    }
    if (!status.ok()) {
      remove_temporaries(0);
      return status;
    }
    prepared.push_back(p);
  }
  // 2. The previous files kept under a second name (a hard link: the target itself never disappears).
  std::vector<fs::path> backups(prepared.size());
  std::error_code ec;
  auto drop_backups = [&] {
    for (const fs::path& b : backups) {
      if (!b.empty()) fs::remove(b, ec);
    }
  };
  // (One file alone needs none: its rename is the whole commit. Where hard links are not possible, a copy.)
  for (std::size_t k = 0; k < prepared.size() && prepared.size() > 1; ++k) {
    if (prepared[k].directory || !fs::is_regular_file(prepared[k].path, ec)) continue;
    const fs::path backup = TemporarySibling(prepared[k].path);
    if (::link(prepared[k].path.c_str(), backup.c_str()) != 0) {
      const int error = errno;
      std::error_code copied;
      fs::copy_file(prepared[k].path, backup, copied);
      if (copied) {
        fs::remove(backup, ec);
        drop_backups();
        remove_temporaries(0);
        return ErrnoError("cannot keep the previous " + prepared[k].path.string() + " while replacing it", error);
      }
    }
    backups[k] = backup;
  }
  // 3. The renames; if one fails, the files renamed before it get their previous content back (or go, if
  // there was none).
  for (std::size_t k = 0; k < prepared.size(); ++k) {
    const Status status = Commit(prepared[k]);
    if (status.ok()) continue;
    remove_temporaries(k + 1);
    for (std::size_t j = 0; j < k; ++j) {
      if (!backups[j].empty()) {
        fs::rename(backups[j], prepared[j].path, ec);
        if (!ec) backups[j].clear();
      } else {
        RemoveQuietly(prepared[j].path);
      }
    }
    drop_backups();
    return status;
  }
  drop_backups();
  for (const Prepared& p : prepared) ROTOSCAN_RETURN_IF_ERROR(SyncPath(ParentOf(p.path), p.path));
  return Status::Ok();
}

namespace {

// Writes all of `content` to `fd` and syncs it; closes `fd` on failure.
Status WriteAllAndSync(int fd, const std::string& content, const fs::path& target) {
  const char* data = content.data();
  std::size_t left = content.size();
  while (left > 0) {
    const ssize_t n = ::write(fd, data, left);
    if (n < 0 && errno == EINTR) continue;
    if (n <= 0) {
      const int error = n < 0 ? errno : EIO;
      ::close(fd);
      return ErrnoError("cannot write " + target.string(), error);
    }
    data += n;
    left -= static_cast<std::size_t>(n);
  }
  if (::fsync(fd) != 0) {
    const int error = errno;
    ::close(fd);
    return ErrnoError("cannot write " + target.string() + " to disk", error);
  }
  return Status::Ok();
}

// Writes `content` to `tmp` (the temporary sibling of `path`), every write checked and synced.
Status WriteContent(const fs::path& tmp, const fs::path& path, const std::string& content) {
  // An unnamed file (O_TMPFILE) while it is written: a process killed in the middle leaves nothing. It is
  // given the temporary name only once complete. Where that is not possible (a file system without
  // O_TMPFILE, no /proc), the named temporary file.
  const int unnamed = ::open(ParentOf(tmp).c_str(), O_TMPFILE | O_WRONLY | O_CLOEXEC, 0666);
  if (unnamed >= 0) {
    ROTOSCAN_RETURN_IF_ERROR(WriteAllAndSync(unnamed, content, path));
    const std::string self = "/proc/self/fd/" + std::to_string(unnamed);
    const bool named = ::linkat(AT_FDCWD, self.c_str(), AT_FDCWD, tmp.c_str(), AT_SYMLINK_FOLLOW) == 0;
    if (::close(unnamed) != 0 && named) return ErrnoError("cannot write " + path.string(), errno);
    if (named) return Status::Ok();
  }
  const int fd = ::open(tmp.c_str(), O_WRONLY | O_CREAT | O_EXCL | O_CLOEXEC, 0666);
  if (fd < 0) return ErrnoError("cannot create a temporary file beside " + path.string(), errno);
  ROTOSCAN_RETURN_IF_ERROR(WriteAllAndSync(fd, content, path));
  if (::close(fd) != 0) return ErrnoError("cannot write " + path.string(), errno);
  return Status::Ok();
}

}  // namespace

Status WriteFileAtomically(const fs::path& path, const std::string& content) {
  return WriteAtomically(path, [&](const fs::path& tmp) { return WriteContent(tmp, path, content); });
}

PendingFile FileWithContent(const fs::path& path, std::string content) {
  auto shared = std::make_shared<const std::string>(std::move(content));
  return {path, [path, shared](const fs::path& tmp) { return WriteContent(tmp, path, *shared); }};
}

Result<std::string> ReadFile(const fs::path& path, std::size_t max_bytes) {
  std::error_code ec;
  if (!fs::exists(path, ec)) return NotFoundError(path.string() + " does not exist");
  if (fs::is_directory(path, ec)) return InvalidArgumentError(path.string() + " is a directory, not a file");
  // A FIFO or a device would block or never end.
  if (!fs::is_regular_file(path, ec)) return InvalidArgumentError(path.string() + " is not a regular file");
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

namespace {

// The path with symlinks and ".." resolved as far as it exists (for comparing paths).
fs::path Resolved(const fs::path& path) {
  std::error_code ec;
  fs::path resolved = fs::weakly_canonical(fs::absolute(path, ec), ec);
  return ec ? path.lexically_normal() : resolved;
}

bool SameFile(const fs::path& a, const fs::path& b) {
  std::error_code ec;
  if (fs::exists(a, ec) && fs::exists(b, ec) && fs::equivalent(a, b, ec)) return true;
  return Resolved(a) == Resolved(b);
}

// True when `inner` lies inside the directory `outer`.
bool Inside(const fs::path& inner, const fs::path& outer) {
  const fs::path i = Resolved(inner), o = Resolved(outer);
  auto it = i.begin();
  for (const auto& part : o) {
    if (it == i.end() || *it != part) return false;
    ++it;
  }
  return it != i.end();
}

}  // namespace

Status CheckOutputPaths(const std::vector<OutputPath>& outputs, const std::vector<fs::path>& inputs) {
  for (std::size_t k = 0; k < outputs.size(); ++k) {
    const OutputPath& output = outputs[k];
    const std::string name = output.what.empty() ? "output" : output.what;
    if (output.path.empty()) return InvalidArgumentError(name + ": empty path");
    fs::path path = output.path;
    if (!path.has_filename() && path.has_parent_path()) path = path.parent_path();  // "out/" -> "out"
    const fs::path parent = ParentOf(path);
    std::error_code ec;
    if (!fs::exists(parent, ec)) {
      return NotFoundError(name + " " + path.string() + ": directory " + parent.string() + " does not exist");
    }
    if (!fs::is_directory(parent, ec)) {
      return InvalidArgumentError(name + " " + path.string() + ": " + parent.string() + " is not a directory");
    }
    const bool directory = output.kind == OutputKind::kDirectory;
    if (const std::string what = NotARegularFile(path, directory); !what.empty()) {
      return InvalidArgumentError(name + " " + path.string() + " is " + what + ": refusing to replace it");
    }
    if (::access(parent.c_str(), W_OK | X_OK) != 0) {
      return InvalidArgumentError(name + " " + path.string() + ": cannot write in directory " +
                                  parent.string() + ": " + std::strerror(errno));
    }
    if (directory && fs::exists(path, ec) && !fs::is_directory(path, ec)) {
      return InvalidArgumentError(name + " " + path.string() + " is a file, not a directory");
    }
    for (const fs::path& input : inputs) {
      if (input.empty()) continue;
      if (SameFile(path, input) || (directory && Inside(input, path))) {
        return InvalidArgumentError(name + " " + path.string() + " is also an input (" + input.string() +
                                    "): refusing to overwrite it");
      }
    }
    for (std::size_t j = 0; j < k; ++j) {
      if (SameFile(path, outputs[j].path)) {
        return InvalidArgumentError(name + " " + path.string() + " is also " + outputs[j].what +
                                    ": give two different paths");
      }
    }
  }
  return Status::Ok();
}

}  // namespace rotoscan

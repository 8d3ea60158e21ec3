// Files written so that nothing half-written is ever left under the final name: content goes to a
// temporary file beside the target ("<name>.tmp-<pid>-<n>"), every write is checked, the file is flushed
// and fsynced, and it is renamed over the target only when the writer succeeded. A failure or an exception
// removes the temporary file and leaves the previous target untouched. Every file the program writes goes
// through here; third-party writers (OpenCV FileStorage, Open3D, PNG encoders) write to memory first, or to
// the temporary path and are checked.
#pragma once

#include <filesystem>
#include <functional>
#include <string>
#include <vector>

#include "rotoscan/core/status.h"

namespace rotoscan {

// Calls `write(temporary_path)`; on OK syncs the temporary file (or directory) to disk and renames it to
// `path`, replacing an existing regular file (or, for a directory, an existing directory). Refuses a target
// that is a symlink, device, FIFO or socket (kInvalidArgument), before calling `write`.
Status WriteAtomically(const std::filesystem::path& path,
                       const std::function<Status(const std::filesystem::path& temporary_path)>& write);

// Writes `content` to `path` atomically (every write checked, fsynced before the rename).
Status WriteFileAtomically(const std::filesystem::path& path, const std::string& content);

// One file of a set written together: `write` fills the temporary path it is given (as for
// WriteAtomically).
struct PendingFile {
  std::filesystem::path path;
  std::function<Status(const std::filesystem::path& temporary_path)> write;
};
// A pending file with this content.
PendingFile FileWithContent(const std::filesystem::path& path, std::string content);

// Several files committed together (a mesh and its preview; an OBJ, its material and its texture): every
// file is written to its temporary sibling and synced first, and only when all succeeded are they renamed
// into place, one after the other. If a rename fails, the targets already renamed get their previous
// content back (kept meanwhile under a hard link) or are removed if they had none, so the previous set
// stays whole. Between two renames the set is mixed only if the process dies there.
Status WriteFilesTogether(const std::vector<PendingFile>& files);

// Reads a whole file; kNotFound if it does not exist, kIoError if it cannot be read, kInvalidArgument
// if it is larger than `max_bytes` or not a regular file.
Result<std::string> ReadFile(const std::filesystem::path& path, std::size_t max_bytes = std::size_t{1} << 30);

// What an output may be.
enum class OutputKind { kFile, kDirectory };

// One output of a command, checked before the work starts.
struct OutputPath {
  std::filesystem::path path;
  std::string what;  // "--out", "--report", ...: named in the message
  OutputKind kind = OutputKind::kFile;
};

// The check every command makes before it starts work: each output's directory exists and is writable;
// the output is absent or of its kind (a regular file, or a directory for a directory output; never a
// symlink, device, FIFO or socket); no output is one of the `inputs` or another output. kInvalidArgument
// or kNotFound naming the option and the path.
Status CheckOutputPaths(const std::vector<OutputPath>& outputs,
                        const std::vector<std::filesystem::path>& inputs = {});

}  // namespace rotoscan

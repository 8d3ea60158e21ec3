// Files written so that nothing half-written is ever left under the final name: content goes to a
// temporary file beside the target ("<name>.tmp-<pid>-<n>"), is flushed, and is renamed over the target
// only when the writer succeeded. A failure or an exception removes the temporary file.
#pragma once

#include <filesystem>
#include <functional>
#include <string>

#include "rotoscan/core/status.h"

namespace rotoscan {

// Calls `write(temporary_path)`; on OK renames the temporary file (or directory) to `path`, replacing an
// existing file. `write` may create a file or a directory at the temporary path.
Status WriteAtomically(const std::filesystem::path& path,
                       const std::function<Status(const std::filesystem::path& temporary_path)>& write);

// Writes `content` to `path` atomically.
Status WriteFileAtomically(const std::filesystem::path& path, const std::string& content);

// Reads a whole file; kNotFound if it does not exist, kIoError if it cannot be read, kInvalidArgument
// if it is larger than `max_bytes`.
Result<std::string> ReadFile(const std::filesystem::path& path, std::size_t max_bytes = std::size_t{1} << 30);

}  // namespace rotoscan

// The one reader of OpenCV FileStorage YAML in Rotoscan (calib.yaml and truth/rig.yaml: geometry/rig.h;
// camera.yaml: calib/camera_calibration.h). Every YAML reader goes through it, so that what it guards
// against is guarded everywhere:
//  * text that is not well-formed UTF-8 or holds control bytes (YAML must not): OpenCV 4.6's YAML parser
//    loops forever on some malformed bytes (the calib.yaml fuzzer's finding: "- \xEC" items), so such text
//    never reaches it;
//  * exceptions: cv::Exception, and the standard exceptions OpenCV's parser also lets out
//    (std::length_error on a mangled key, another fuzzer finding).
// Errors are kCorruptData (or what `read` returns, with `name` as context), never an exception or a hang.
#pragma once

#include <cstddef>
#include <filesystem>
#include <functional>
#include <string>

#include <opencv2/core/persistence.hpp>

#include "rotoscan/core/status.h"

namespace rotoscan::geometry {

// Parses `text` (named `name` in messages) and hands its root node to `read`, inside the guards above.
Status ReadYamlText(const std::string& text, const std::string& name,
                    const std::function<Status(const cv::FileNode& root)>& read);

// The same for a file (at most 64 MiB): kNotFound when missing, kInvalidArgument when not a regular file;
// `what` names the file's role in messages ("calibration file").
Status ReadYamlFile(const std::filesystem::path& path, const std::string& what,
                    const std::function<Status(const cv::FileNode& root)>& read);

// Where `text` is not well-formed UTF-8 or holds a control byte other than tab, CR and LF, or npos.
std::size_t InvalidYamlByteAt(const std::string& text);

}  // namespace rotoscan::geometry

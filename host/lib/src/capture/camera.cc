#include "rotoscan/capture/camera.h"

namespace rotoscan::capture {

Status CameraSettings::Check() const {
  if (width < 0 || height < 0 || (width == 0) != (height == 0)) {
    return InvalidArgumentError("camera size must be both 0 (default) or both positive");
  }
  if (!(frame_rate_hz > 0.0 && frame_rate_hz <= 10'000.0)) {
    return InvalidArgumentError("camera frame rate must be in (0, 10000] frames/s");
  }
  if (exposure_us <= 0) return InvalidArgumentError("camera exposure must be positive");
  for (int64_t e : exposure_cycle_us) {
    if (e <= 0) return InvalidArgumentError("camera exposure cycle: every exposure must be positive");
  }
  if (!exposure_cycle_us.empty() && !triggered) {
    return InvalidArgumentError("camera exposure cycle is for triggered capture only");
  }
  if (white_balance) {
    for (double g : *white_balance) {
      if (!(g > 0.0 && g < 100.0)) return InvalidArgumentError("white balance gains must be in (0, 100)");
    }
  }
  return Status();
}

}  // namespace rotoscan::capture

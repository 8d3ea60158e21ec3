// What the virtual camera renders for one exposure (virtual_camera.cc), for tests that feed another camera
// stack with the virtual scanner's frames (Aravis's fake camera): the table angle at the exposure's middle,
// and per row the fraction of that row's window each laser was lit (row r starts readout_us * r /
// (height - 1) after the first), by the rig's truth.
#pragma once

#include <cmath>
#include <cstdint>

#include <opencv2/core/mat.hpp>

#include "rotoscan/capture/camera.h"
#include "rotoscan/capture/virtual_rig.h"
#include "rotoscan/sim/renderer.h"
#include "rotoscan/sim/scene.h"

namespace rotoscan::capture::internal {

// `natural`: the scene's natural frame (lamp on) as the base instead of its laser-off frame.
cv::Mat RenderExposure(sim::Renderer& renderer, RigTruth& truth, int64_t exposure_start_us, int64_t exposure_us,
                       int64_t readout_us, uint64_t frame_id, bool natural, PixelFormat format);

// Exposures at or above this are rendered as natural frames: the geometric mean of the scene's laser and
// natural exposures.
inline double NaturalThresholdUs(const sim::Scene& scene) {
  return std::sqrt(scene.sensor.laser_exposure_us * scene.sensor.natural_exposure_us);
}

}  // namespace rotoscan::capture::internal

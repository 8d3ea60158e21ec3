// Helpers of the tests that judge the extractor on the webcam sets rendered by our renderer (issue 15): the
// scene with the camera's effects off (what the image holds without noise, speckle or a changing ambient),
// and the renderer's line truth by row.
#pragma once

#include <map>
#include <vector>

#include "rotoscan/bundle/truth.h"
#include "rotoscan/sim/scene.h"

namespace rotoscan::laser::testing {

// `scene` without sensor noise, speckle, ambient change or flicker; with keep_jpeg false, without its
// MJPEG compression too.
inline sim::Scene NoiseFreeScene(const sim::Scene& scene, bool keep_jpeg) {
  sim::Scene clean = scene;
  clean.sensor.noise = false;
  if (!keep_jpeg) clean.sensor.jpeg_quality = 0;
  clean.ambient_change = 0.0;
  clean.ambient_flicker = 0.0;
  for (sim::LaserModel& laser : clean.laser) {
    laser.f_number = 0.0;
    laser.speckle_contrast = 0.0;
  }
  return clean;
}

// One frame's true line by row: every true crossing's column, and whether any of them is on an object
// (not the table top).
struct TruthByRow {
  std::map<int, std::vector<double>> all;
  std::map<int, bool> object;
};
inline TruthByRow TruthRows(const std::vector<bundle::LinePoint>& truth) {
  TruthByRow rows;
  for (const bundle::LinePoint& t : truth) {
    rows.all[t.row].push_back(t.column);
    rows.object[t.row] = rows.object[t.row] || t.object != 0;
  }
  return rows;
}

}  // namespace rotoscan::laser::testing

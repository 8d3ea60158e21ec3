// The virtual scanner's renderer: ray casting with Embree 3 against the scene's triangle meshes (the
// table top is mesh 0, built in; the objects follow), in the table frame. Per table angle it casts one
// set of camera rays (S x S per pixel) and shades from the same hits the four frames of a step: left laser,
// right laser, lasers off (short exposure, ambient light) and natural (long exposure, ambient + lamp).
//
// Image formation per pixel: radiance = albedo * light (eq. of a Lambertian surface); a laser adds
// power * exp(-s^2 / 2 sigma^2) * cos(incidence) * 300 / range * red albedo * response[c], with s the
// distance of the hit point from the laser plane, times a multiplicative, spatially correlated speckle
// factor; a point hidden from the laser origin (Embree occlusion ray) gets nothing from it. Then optical
// blur, the sensor (scene.h), optional RGGB mosaic + OpenCV demosaicing and the color matrix.
//
// Ground truth per laser frame (LineTruth): the plane of the laser cuts every triangle of the scene (table
// included) in a segment; for every image row that the segment's distorted projection crosses, the
// crossing point is found by bisection on the segment (to 1e-12 of its length) and kept if the camera sees
// it (the first hit of the camera ray through it is that point) and the laser lights it (no occluder
// between it and the laser origin). These are the exact points of (laser plane ∩ surface) on the same
// triangles the image is rendered from.
#pragma once

#include <array>
#include <cstdint>
#include <memory>
#include <vector>

#include <Eigen/Core>
#include <Eigen/Geometry>
#include <opencv2/core/mat.hpp>

#include "rotoscan/bundle/truth.h"
#include "rotoscan/core/status.h"
#include "rotoscan/sim/scene.h"

namespace rotoscan::sim {

// Which frames to render at a step, by bundle::LaserState index (left, right, off, natural).
using FrameMask = std::array<bool, 4>;
inline constexpr FrameMask kAllFrames = {true, true, true, true};

struct RenderedStep {
  std::array<cv::Mat, 4> frames;  // by bundle::LaserState; CV_8UC3 (or CV_16UC3 for 12-bit), BGR
};

class Renderer {
 public:
  // Loads the scene's meshes and textures and builds the ray-casting structure. kNotFound/kCorruptData
  // for mesh files, kInvalidArgument for an invalid scene.
  static Result<std::unique_ptr<Renderer>> Create(const Scene& scene);
  ~Renderer();
  Renderer(const Renderer&) = delete;
  Renderer& operator=(const Renderer&) = delete;

  const Scene& scene() const { return scene_; }

  // Renders the frames of `mask` with the table at `table_angle` (radians). Noise and speckle draw from
  // `seed` only, so a frame does not depend on which thread rendered it. Thread-safe.
  RenderedStep RenderStep(double table_angle, uint64_t seed, const FrameMask& mask = kAllFrames) const;

  // The true line of laser `laser` at `table_angle` (see the file comment), sorted by row then column.
  std::vector<bundle::LinePoint> LineTruth(geometry::LaserId laser, double table_angle) const;

  // The objects (not the table) in the table frame, with vertex colors, for truth/object.ply.
  bundle::TruthMesh ObjectMesh() const;
  // table_from_object of object i (0-based, in scene.objects order): the target frame of boards and of
  // the calibration object.
  Eigen::Isometry3d TableFromObject(std::size_t i) const;
  std::size_t TriangleCount() const;

  // The sensor alone: electrons (CV_32FC3, BGR, mean per pixel, before saturation) -> DN image, with the
  // noise, saturation, mosaic, color matrix and quantisation of scene().sensor. Used for flat fields.
  cv::Mat ApplySensor(const cv::Mat& electrons, uint64_t seed) const;

 private:
  struct Impl;
  Renderer(const Scene& scene, std::unique_ptr<Impl> impl);
  Scene scene_;
  std::unique_ptr<Impl> impl_;
};

// A 64-bit seed from (scene seed, pose, step, frame) by SplitMix64 mixing.
uint64_t FrameSeed(uint64_t scene_seed, int pose, int step, int frame);

}  // namespace rotoscan::sim

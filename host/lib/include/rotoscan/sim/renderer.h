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
// Real-camera effects (scene options; the "webcam" preset turns them on):
//  * Glossy materials (ObjectSpec::specular, shininess): a Blinn-Phong lobe ks (n.h)^m, white, for each
//    laser (times its irradiance; the laser frame saturates in a glint) and for the lamp (natural frame).
//  * Dark-and-white texture (ObjectSpec::checker_mm): under a laser that saturates the on frame, a white
//    cell's bright laser-off value leaves a notch in the difference (DESIGN.md's `146 145 53 164 44`).
//  * Speckle (LaserModel::f_number > 0), from physics rather than from what the extractor expects: the
//    field in the image plane is a circular complex Gaussian random field whose spectrum is the pupil
//    (a disk of radius 1 / (2 wavelength N) cycles per unit length: the coherent cutoff; N the f-number), made by filling that
//    disk of a DFT with independent complex normal deviates on a grid finer than the pixels (spacing <=
//    wavelength N / 2, the intensity's Nyquist spacing) and transforming back. The intensity |field|^2 is
//    then exponentially distributed (fully developed speckle, contrast 1) with the autocovariance
//    [2 J1(v) / v]^2, v = pi r / (wavelength N), whose first zero, the grain radius, is 1.22 wavelength
//    N (Goodman, Speckle Phenomena in Optics, ch. 4 and 5). Each pixel integrates its cells (which lowers
//    the contrast as grains approach the pixel size); the laser image is multiplied by that.
//    SpeckleIntensity exposes the field for tests. Otherwise (f_number = 0) the older model: blurred
//    Gaussian noise of speckle_contrast and speckle_size_px.
//  * Ambient light changing between frames (Scene::ambient_change) and a flickering lamp read out by a
//    rolling shutter (Scene::ambient_flicker, flicker_hz, SensorModel::line_time_us): per-row gains on
//    each frame's ambient light, each frame at its own phase.
//  * MJPEG (SensorModel::jpeg_quality): each 8-bit frame through OpenCV's JPEG encoder and decoder
//    (4:2:0 chroma, as UVC webcams send) at that quality.
// Not modelled: light scattered between surfaces (a concavity's second, weaker line).
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

// Fully developed speckle (see the file comment): the intensity (mean 1) on a grid of `oversampling`
// cells per pixel in each direction, size (rows * oversampling) x (cols * oversampling), CV_32FC1, for a
// pupil of `f_number` at `wavelength_nm` and pixels of `pixel_size_um`. Deterministic for a seed.
cv::Mat SpeckleIntensity(int rows, int cols, double pixel_size_um, double wavelength_nm, double f_number,
                         int oversampling, uint64_t seed);
// The cells per pixel the renderer uses: the smallest integer giving a spacing <= wavelength N / 2.
int SpeckleOversampling(double pixel_size_um, double wavelength_nm, double f_number);

// A 64-bit seed from (scene seed, pose, step, frame) by SplitMix64 mixing.
uint64_t FrameSeed(uint64_t scene_seed, int pose, int step, int frame);

}  // namespace rotoscan::sim

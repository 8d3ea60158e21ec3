// Internal to the sim module: the triangle meshes the renderer casts rays against, built from the scene's
// objects (OBJ/PLY files and built-in shapes) and placed in the table frame.
#pragma once

#include <vector>

#include <Eigen/Core>
#include <Eigen/Geometry>
#include <opencv2/core/mat.hpp>

#include "rotoscan/core/status.h"
#include "rotoscan/sim/scene.h"

namespace rotoscan::sim::internal {

enum class Pattern { kNone, kChecker, kCalibrationObject, kCharuco };

struct Mesh {
  std::vector<Eigen::Vector3f> vertices;  // table frame, mm
  std::vector<Eigen::Vector3i> faces;
  std::vector<Eigen::Vector3f> colors;      // per-vertex albedo RGB 0..1 (optional)
  std::vector<Eigen::Vector2f> uv;          // 3 per face (optional, with texture)
  // 3 per face (table frame, unit, on the side of the face's own normal): the shading normal is their
  // barycentric blend (smooth shading of a mesh that stands for a smooth surface); empty: flat facets.
  std::vector<Eigen::Vector3f> corner_normals;
  cv::Mat texture;                          // CV_32FC3, BGR albedo 0..1
  Eigen::Vector3f color{0.8f, 0.8f, 0.8f};  // uniform albedo RGB
  Pattern pattern = Pattern::kNone;
  float specular = 0.0f, shininess = 60.0f;  // ObjectSpec's glossy lobe
  double checker_mm = 0.0;                   // ObjectSpec's 3D checker (0: none)
  float dark_albedo = 0.1f;
  int cols = 0, rows = 0;
  double square_mm = 0.0;
  // kCharuco: the summed-area table (CV_64FC1, (H + 1) x (W + 1), cv::integral) of the board image
  // (calib::CharucoBoard::Draw, 0..255; texel (u, v) covers [u, u + 1) x [v, v + 1) / texels_per_mm from
  // the board's outer corner at (-square, -square) of the target frame). A box filter over any rectangle
  // is then exact: the integral of a piecewise-constant image is bilinear inside each texel.
  cv::Mat pattern_sum;
  double pattern_texels_per_mm = 0.0;
  Eigen::Isometry3d table_from_object = Eigen::Isometry3d::Identity();
  Eigen::Isometry3d object_from_table = Eigen::Isometry3d::Identity();

  // Albedo RGB at a point of face `face` with barycentric (u, v) (Embree's convention: p = (1-u-v) v0 +
  // u v1 + v v2) and table-frame position `point_in_table`.
  // `footprint_x/y` (table frame, may be zero) are the point's offsets to the neighbouring samples: the
  // checker patterns are box-filtered over that footprint (anti-aliasing without a bias of the edges).
  Eigen::Vector3f Albedo(unsigned face, float u, float v, const Eigen::Vector3d& point_in_table,
                         const Eigen::Vector3d& footprint_x = Eigen::Vector3d::Zero(),
                         const Eigen::Vector3d& footprint_y = Eigen::Vector3d::Zero()) const;
  // The texture, vertex colors or `color` alone (no pattern, no checker).
  Eigen::Vector3f PlainAlbedo(unsigned face, float u, float v) const;
  // True when Albedo is `color` everywhere (no pattern, texture or vertex colors).
  bool UniformAlbedo() const {
    return pattern == Pattern::kNone && (texture.empty() || uv.empty()) && colors.empty() && checker_mm <= 0.0;
  }
};

// Fills m->corner_normals: at each corner of a face, the area-weighted mean of the normals of the faces
// around that vertex (vertices at the same position count as one) within `crease_deg` of the face's
// own, so that sharper edges stay sharp.
void SmoothCornerNormals(Mesh* m, double crease_deg);

// The table top: a disk of `radius` at z = 0 of the table frame, dark diffuse.
Mesh MakeTableTop(double radius_mm, const Eigen::Vector3d& albedo);

// Builds one scene object in the table frame. kNotFound/kCorruptData for mesh files.
Result<Mesh> MakeObject(const ObjectSpec& spec, const Scene& scene);

}  // namespace rotoscan::sim::internal

// Meshing of a colored point cloud and a preview picture of the result.
//
// The default surface is range-scan fusion (FuseSurface, fusion.cc): Curless & Levoy's volumetric method
// (VRIP, SIGGRAPH 1996) fed by what the scanner knows of every point: the camera it was seen from, its
// quality, and the spacing of the table steps. The alternative is screened Poisson (Kazhdan, Bolitho & Hoppe; the paper's Fig. 10c/11c used
// MeshLab's), through Open3D, which also interpolates the vertex colors. Poisson closes every surface, so the
// parts it invents far from any sample (the "balloon" under an open bottom) are trimmed by dropping the
// vertices of lowest sample density. Open3D stays inside this module's .cc files: the API uses Eigen only.
#pragma once

#include <cstdint>
#include <filesystem>
#include <string>
#include <vector>

#include <Eigen/Core>
#include <Eigen/Geometry>
#include <opencv2/core/mat.hpp>

#include "rotoscan/cloud/cloud.h"
#include "rotoscan/core/file.h"
#include "rotoscan/core/progress.h"
#include "rotoscan/core/status.h"

namespace rotoscan::mesh {

// Points in mm with unit normals (zero normals are estimated) and colors in [0, 1].
struct ColoredPoints {
  std::vector<Eigen::Vector3d> points;
  std::vector<Eigen::Vector3d> normals;  // empty, or one per point
  std::vector<Eigen::Vector3d> colors;   // empty, or one per point (RGB)
  std::vector<Eigen::Vector3d> views;    // empty, or one per point: unit, from the point toward its camera
  std::vector<float> quality;            // empty, or one per point in 0..1
  double step_rad = 0.0;                 // the turn between table steps (0: unknown); sets sample footprints
  // Empty, or the camera's positions during the scan (table frame, mm; one per table step that has points):
  // the watertight fusion carves the table top the cameras saw around the object.
  std::vector<Eigen::Vector3d> cameras;
};

// A scan's cloud as meshing input: positions, normals (zero ones are estimated), colors, quality and, when
// the cloud knows its camera path (cloud::ScanGeometry), each point's direction to its camera.
ColoredPoints ToColoredPoints(const cloud::PointCloud& cloud);

struct TriangleMesh {
  std::vector<Eigen::Vector3d> vertices;       // mm
  std::vector<Eigen::Vector3d> vertex_colors;  // RGB in [0, 1]; empty if none
  std::vector<Eigen::Vector3i> triangles;      // counter-clockwise seen from outside
};

// Range-scan fusion (VRIP). Every sample adds a signed distance (positive on its camera's side) along its
// normal to the voxels of a thin disc around it, weighted by its quality, by how squarely its camera saw the
// surface (the cosine between normal and sensor ray) and by a lateral fall-off; the volume is a sparse set
// of 8^3-voxel blocks. Marching cubes extracts the zero level set where every corner of a cube holds enough
// weight (trimming), small components are dropped, and each vertex takes the color of the cloud's points
// near it (ColorVerticesFromPoints; color_radius_voxels 0: the voxels' blended color).
// Two threads by default: the volume is cut into two slabs of blocks, each written by one thread.
struct FusionOptions {
  double voxel_mm = 0.5;             // voxel edge
  double truncation_voxels = 2.0;    // half-width of the signed-distance band, in voxels
  double footprint_voxels = 1.5;     // the least lateral radius of a sample, in voxels
  double min_weight_fraction = 0.1;  // trim cubes with a corner below this x the median surface weight
  double min_component_fraction = 0.01;  // drop components with fewer triangles than this x the total
  bool flat_bottom = true;           // close the bottom with the table plane (z = table_z) under the object
  double table_z = 0.0;              // mm, the table top in the table frame
  // A closed surface (fusion.cc, "Watertight"): the space each sensor ray crossed is carved empty, what no
  // ray reached counts as inside, the unobserved voxels are smoothed by diffusion, and marching cubes runs
  // over the whole box. Needs each point's camera (views) and the flat bottom.
  bool watertight = false;
  int diffusion_iterations = 12;     // Jacobi sweeps over the unobserved voxels (watertight only)
  // Vertex colors (ColorVerticesFromPoints): from the cloud's points within this many voxels of each vertex;
  // 0: the voxels' blended color (every sample's color smeared over its splat, behind the surface too).
  double color_radius_voxels = 1.0;
  int threads = 2;                   // 0: all cores
  Status Check() const;
};

struct FusionSummary {
  std::size_t input_points = 0;
  std::size_t blocks = 0;               // allocated 8^3 blocks
  std::size_t removed_components = 0;
  std::size_t removed_triangles = 0;
  // Watertight only: rays carved (from the points to their cameras; from the table top to the cameras) and
  // the share of the surface's vertices on observed voxels (the rest fill holes).
  std::size_t carved_point_rays = 0, carved_table_rays = 0, discarded_rays = 0;
  double observed_vertex_fraction = 1.0;
  std::size_t colored_from_points = 0, colored_from_neighbours = 0;  // ColorVerticesFromPoints
  double splat_seconds = 0.0;
  double extract_seconds = 0.0;  // marching cubes, components, colors
  double seconds = 0.0;
};

// Fused surface of `cloud`. kInvalidArgument for fewer than 100 points, inconsistent arrays, non-finite
// points, or a cloud too large for the voxel size (more than 2^26 blocks).
Result<TriangleMesh> FuseSurface(const ColoredPoints& cloud, const FusionOptions& options,
                                 FusionSummary* summary = nullptr, Progress* progress = nullptr);

struct VertexColorSummary {
  std::size_t from_points = 0;      // vertices colored from the cloud's points near them
  std::size_t from_neighbours = 0;  // vertices with no point near, colored from their neighbours
  int rings = 0;                    // rings of neighbours that took
};

// Each vertex's color from the cloud's colors: the Gaussian-weighted average (sigma = radius / 5) of the
// points within `radius_mm` whose normals agree with the vertex's (cos >= 0.3, so the far side of a thin
// part does not bleed through; all points when the cloud has no normals); a vertex with none near (a hole
// of the scan that meshing closed) takes the mean of its already colored neighbours, ring after ring. A
// vertex that no ring reaches keeps its color. kInvalidArgument for mismatched arrays or a bad radius.
Status ColorVerticesFromPoints(const ColoredPoints& cloud, double radius_mm, TriangleMesh* mesh,
                               VertexColorSummary* summary = nullptr);

struct PoissonOptions {
  int depth = 9;                        // octree depth (9: ~0.3 mm cells on a 150 mm object)
  double trim_density_quantile = 0.02;  // drop vertices below this quantile of sample density
  int normal_neighbours = 30;           // for normal estimation when the input has none
  int threads = 0;                      // 0: all cores
  Status Check() const;
};

struct PoissonSummary {
  std::size_t input_points = 0;
  std::size_t vertices_before_trim = 0;
  double seconds = 0.0;
};

// Poisson surface of `cloud`. kInvalidArgument for fewer than 100 points or inconsistent arrays.
// kInvalidArgument for a cloud no mesher can use: a non-finite point, no extent (identical points, or
// points apart only at denormal scale: Open3D's Poisson crashes on it), or all points in one plane.
// PoissonReconstruct and FuseSurface call it first.
Status CheckCloudExtent(const ColoredPoints& cloud);

Result<TriangleMesh> PoissonReconstruct(const ColoredPoints& cloud, const PoissonOptions& options,
                                        PoissonSummary* summary = nullptr, Progress* progress = nullptr);

// kInvalidArgument unless `path` ends in .ply, .obj, .stl or .glb (checked before any work).
Status CheckMeshPath(const std::filesystem::path& path);
// The files a mesh at `path` is written as: `path` itself, and for an .obj with colors its material
// <stem>.mtl and texture <stem>_texture.png beside it (for CheckOutputPaths before the work).
std::vector<std::filesystem::path> MeshFilePaths(const std::filesystem::path& path, const TriangleMesh* mesh = nullptr);
// The files of `mesh` at `path`, to be committed together (WriteFilesTogether), by the extension: .ply
// (binary, vertex colors), .obj (text: vertex colors as the common "v x y z r g b" extension, and a
// texture atlas made from them with per-corner UVs, material and PNG beside: ObjWithAtlas), .stl (binary)
// or .glb (glTF 2.0 binary, our own writer: metres, +Y up, vertex normals and colors). Each is checked
// (Open3D's writers are read back) before it may replace anything.
Result<std::vector<PendingFile>> MeshFiles(const std::filesystem::path& path, const TriangleMesh& mesh);
// MeshFiles, committed together.
Status WriteMesh(const std::filesystem::path& path, const TriangleMesh& mesh);

// An OBJ with a texture atlas baked from the vertex colors (obj.cc). Every triangle gets its own 2 x 2
// texels; its corners' UVs sit on the centres of three of them, which hold the corners' colors, and the
// fourth holds c1 + c2 - c0, so that bilinear filtering inside the triangle reproduces the linear
// interpolation of the vertex colors exactly (clamped to 0..255). The atlas is as square as the triangle
// count allows (at most 8192 x 8192 texels: 16.7 M triangles). Blender, MeshLab and Open3D read the
// `vt`/`map_Kd` texture; MeshLab and Open3D also the vertex colors.
struct ObjWithAtlas {
  std::string obj;  // refers to `mtl_name`
  std::string mtl;  // refers to `texture_name`
  cv::Mat texture;  // BGR, 8-bit
};
Result<ObjWithAtlas> EncodeObjWithAtlas(const TriangleMesh& mesh, const std::string& mtl_name,
                                        const std::string& texture_name);
// Reads any of those (through Open3D); a .glb comes back in the table frame's millimetres, +Z up.
Result<TriangleMesh> ReadMesh(const std::filesystem::path& path);

// True when `path` holds a mesh rather than a bare cloud: .obj, .stl, .glb, or a .ply with faces.
bool IsMeshFile(const std::filesystem::path& path);
// A mesh's vertices as a cloud (color kept, normals from the faces, laser 0, step 0, quality 1), for
// comparing a mesh with what compares clouds (pipeline/evaluate.h).
cloud::PointCloud VerticesAsCloud(const TriangleMesh& mesh);

// The bytes of a .glb file (gltf.cc). kInvalidArgument for an empty mesh or a bad index.
Result<std::string> EncodeGlb(const TriangleMesh& mesh);
// Unit vertex normals, area-weighted from the faces (+Z where a vertex has none).
std::vector<Eigen::Vector3d> VertexNormals(const TriangleMesh& mesh);

struct PreviewOptions {
  int width = 960;
  int height = 720;
  double azimuth_deg = 30.0;    // view direction about the z (up) axis
  double elevation_deg = 20.0;  // above the horizontal
  double fov_deg = 30.0;
  Eigen::Vector3d up = Eigen::Vector3d::UnitZ();  // the model's up axis (table frame: z)
  Status Check() const;
};

// A shaded, colored picture of `mesh` (BGR, 8-bit) framed to fit, on a dark background: the quick look a
// person wants after a scan. A headlight Lambert term times the vertex color.
Result<cv::Mat> RenderPreview(const TriangleMesh& mesh, const PreviewOptions& options);

// The same for a point cloud (splats of one pixel, nearest wins).
Result<cv::Mat> RenderPointPreview(const ColoredPoints& cloud, const PreviewOptions& options);

// Four views in a 2 x 2 sheet, each options.width x options.height, labelled: front (azimuth
// `options.azimuth_deg`), side (+90°), back (+180°) and top. A mesh, or a cloud.
Result<cv::Mat> RenderPreviewSheet(const TriangleMesh& mesh, const PreviewOptions& options);
Result<cv::Mat> RenderPointPreviewSheet(const ColoredPoints& cloud, const PreviewOptions& options);

// Encodes `image` as PNG and writes it atomically.
Status WritePng(const std::filesystem::path& path, const cv::Mat& image);
// The same as a file to commit with others (encoded now: an encoding error comes before any write).
Result<PendingFile> PngFile(const std::filesystem::path& path, const cv::Mat& image);
Result<std::string> EncodePng(const cv::Mat& image, const std::string& name);

}  // namespace rotoscan::mesh

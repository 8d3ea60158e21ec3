// laser_digest: a digest of every field of every point (and every count of LineStats) that the extractor
// gives on a fixed set of frames, so that a change meant to be bit-identical (a faster kernel, a fused
// pass) can be checked against another build of the library, e.g. main's:
//
//   (main's build)   build/host/bench/laser/laser_digest > /tmp/digest-main.txt
//   (this build)     build/host/bench/laser/laser_digest --check /tmp/digest-main.txt
//
// --check exits 1 and names each set whose digest differs. Sets: "synthetic" (laser_bench's frames: a
// saturated 12 px line, curved, in every row; and a weak wide Gaussian one), "random" (kernels_test's kind:
// saturated lines with notches, a second line of random height and width, random pixels, rows narrower than
// a vector), "rendered" (one table step of glossy-webcam.json and textured-webcam.json, both lasers, and of
// spot.json, the machine-vision preset; ~10 s to render). Each set runs every estimator, smoothing on and
// off, and with every vector extension against SSE2 alone (the SSE2-only digest must equal the other, so
// the tool also checks the paths against each other). --sets synthetic,random skips the renders.
// The digest is FNV-1a over the bytes of each field, in a fixed order (not of the struct: no padding).
// --dump FILE also writes every point (set, estimator, smoothing, frame, row, column, peak, width,
// quality, uncertainty, flags) as text, to see where two builds differ and by how much
// (scripts/compare_digest_dumps.py).
#include <cmath>
#include <cstdint>
#include <cstdio>
#include <cstring>
#include <fstream>
#include <functional>
#include <map>
#include <random>
#include <sstream>
#include <string>
#include <vector>

#include <opencv2/core.hpp>

#include "rotoscan/core/file.h"
#include "rotoscan/laser/extract.h"
#include "rotoscan/sim/renderer.h"
#include "rotoscan/sim/scene.h"
#include "synthetic_line.h"

namespace {

using rotoscan::laser::Estimator;
using rotoscan::laser::ExtractOptions;
using rotoscan::laser::Line;
using rotoscan::laser::LineExtractor;

struct Digest {
  uint64_t h = 1469598103934665603ull;
  void Bytes(const void* p, size_t n) {
    const auto* b = static_cast<const uint8_t*>(p);
    for (size_t i = 0; i < n; ++i) {
      h ^= b[i];
      h *= 1099511628211ull;
    }
  }
  template <typename T>
  void Add(T v) {
    Bytes(&v, sizeof v);
  }
};

void AddLine(const Line& line, Digest* d) {
  d->Add(static_cast<uint64_t>(line.points.size()));
  for (const rotoscan::laser::LinePoint& p : line.points) {
    d->Add(p.row);
    d->Add(p.column);
    d->Add(p.peak);
    d->Add(p.width);
    d->Add(p.quality);
    d->Add(p.uncertainty_px);
    d->Add(p.flags);
  }
  const rotoscan::laser::LineStats& s = line.stats;
  for (int v : {s.rows, s.found, s.low_contrast, s.bad_width, s.off_saturated, s.multiple_peaks, s.glints,
                s.stronger_rejected})
    d->Add(v);
  d->Add(s.noise_dn);
  d->Add(static_cast<uint8_t>(s.noise_on_lit));
  d->Add(s.threshold_dn);
}

using Pairs = std::vector<std::pair<cv::Mat, cv::Mat>>;

Pairs Synthetic() {
  Pairs pairs;
  rotoscan::laser::testing::LineSpec saturated;  // laser_bench's line
  saturated.amplitude = 400;
  saturated.sigma = 2.0;
  saturated.flat_half_width = 3.5;
  rotoscan::laser::testing::LineSpec weak;  // a weak wide Gaussian, partly off the frame
  weak.amplitude = 60;
  weak.sigma = 3.5;
  for (int i = 0; i < 3; ++i) {
    cv::Mat on, off;
    rotoscan::laser::testing::MakePair(
        1288, 964, saturated, [i](int r) { return 644.0 + 150.0 * std::sin(r * 0.01 + i); }, 100 + i, &on, &off);
    pairs.emplace_back(on, off);
  }
  cv::Mat on, off;
  rotoscan::laser::testing::MakePair(
      640, 480, weak, [](int r) { return r % 97 < 5 ? -1.0 : 20.0 + 0.8 * r; }, 7, &on, &off);
  pairs.emplace_back(on, off);
  return pairs;
}

Pairs Random() {
  Pairs pairs;
  std::mt19937 rng(31);
  std::uniform_int_distribution<int> byte(0, 255), coin(0, 5);
  for (int i = 0; i < 12; ++i) {
    const int cols = i % 4 == 3 ? 13 : std::uniform_int_distribution<int>(40, 700)(rng), rows = 128;
    cv::Mat on(rows, cols, CV_8UC1), off(rows, cols, CV_8UC1);
    for (int r = 0; r < rows; ++r) {
      const int c1 = cols / 2 + static_cast<int>(cols / 3 * std::sin(0.05 * r + i));
      const int c2 = std::uniform_int_distribution<int>(0, cols - 1)(rng);
      const int amp2 = std::uniform_int_distribution<int>(10, 300)(rng);
      const int wide = std::uniform_int_distribution<int>(1, 40)(rng);
      for (int x = 0; x < cols; ++x) {
        const int b = i % 4 == 1 ? 250 : (coin(rng) == 0 ? byte(rng) : 40 + (x * 7) % 50);
        int a = b + std::max(0, 300 - 30 * std::abs(x - c1)) + std::max(0, amp2 - amp2 * std::abs(x - c2) / wide) +
                coin(rng);
        if (coin(rng) == 0) a = byte(rng);
        off.at<uint8_t>(r, x) = static_cast<uint8_t>(b);
        on.at<uint8_t>(r, x) = static_cast<uint8_t>(std::min(a, 255));
      }
    }
    pairs.emplace_back(on, off);
  }
  return pairs;
}

bool Rendered(Pairs* pairs) {
  for (const char* file : {"glossy-webcam.json", "textured-webcam.json", "spot.json"}) {
    auto scene = rotoscan::sim::LoadScene(std::string(ROTOSCAN_SOURCE_DIR) + "/data/scenes/" + file);
    if (!scene.ok()) {
      std::fprintf(stderr, "laser_digest: %s\n", scene.status().ToString().c_str());
      return false;
    }
    auto renderer = rotoscan::sim::Renderer::Create(*scene);
    if (!renderer.ok()) {
      std::fprintf(stderr, "laser_digest: %s\n", renderer.status().ToString().c_str());
      return false;
    }
    const double angle = 0.7;
    const rotoscan::sim::RenderedStep step =
        (*renderer)->RenderStep(angle, rotoscan::sim::FrameSeed(scene->seed, 0, 1, 0), {true, true, true, false});
    pairs->emplace_back(step.frames[0], step.frames[2]);
    pairs->emplace_back(step.frames[1], step.frames[2]);
  }
  return true;
}

// One digest per set: every estimator, smoothing on and off; `wide` false: SSE2 alone.
// --dump: the points as text, written whole at the end (core/file.h: nothing half-written on failure).
std::string g_dump_path;
std::string g_dump;

uint64_t DigestOf(const std::string& set, const Pairs& pairs, bool wide, size_t* points, long* gap_filled) {
  rotoscan::laser::internal::AllowVectorExtensions(wide, wide);
  Digest d;
  for (Estimator estimator :
       {Estimator::kCenterOfMass, Estimator::kParabolic, Estimator::kGaussian, Estimator::kZeroCrossing}) {
    for (int smooth : {12, 0}) {
      ExtractOptions options;
      options.estimator = estimator;
      options.smooth_half_rows = smooth;
      LineExtractor extractor(options);
      Line line;
      int frame = 0;
      for (const auto& [on, off] : pairs) {
        const rotoscan::Status status = extractor.Extract(on, off, &line);
        if (!status.ok()) {
          std::fprintf(stderr, "laser_digest: %s\n", status.ToString().c_str());
          std::exit(2);
        }
        AddLine(line, &d);
        *points += line.points.size();
        *gap_filled += line.stats.gap_filled;
        if (!g_dump_path.empty() && wide) {
          for (const rotoscan::laser::LinePoint& p : line.points) {
            char text[256];
            std::snprintf(text, sizeof text, "%s %s %d %d %d %.9g %.9g %.9g %.9g %.9g %d\n", set.c_str(),
                          rotoscan::laser::EstimatorName(estimator), smooth, frame, p.row, p.column, p.peak, p.width,
                          p.quality, p.uncertainty_px, p.flags);
            g_dump += text;
          }
        }
        ++frame;
      }
    }
  }
  rotoscan::laser::internal::AllowVectorExtensions(true, true);
  return d.h;
}

}  // namespace

int main(int argc, char** argv) {
  std::string check, sets = "synthetic,random,rendered";
  for (int i = 1; i < argc; ++i) {
    const std::string arg = argv[i];
    if (arg == "--check" && i + 1 < argc) {
      check = argv[++i];
    } else if (arg == "--dump" && i + 1 < argc) {
      g_dump_path = argv[++i];
    } else if (arg == "--sets" && i + 1 < argc) {
      sets = argv[++i];
    } else {
      std::fprintf(stderr, "usage: laser_digest [--sets synthetic,random,rendered] [--check FILE] [--dump FILE]\n");
      return 2;
    }
  }
  std::map<std::string, std::string> expected;
  if (!check.empty()) {
    std::ifstream in(check);
    if (!in) {
      std::fprintf(stderr, "laser_digest: cannot read %s\n", check.c_str());
      return 2;
    }
    std::string name, hash;
    while (in >> name >> hash) {
      expected[name] = hash;
      in.ignore(1 << 20, '\n');
    }
  }
  const std::map<std::string, std::function<bool(Pairs*)>> makers = {
      {"synthetic", [](Pairs* p) { *p = Synthetic(); return true; }},
      {"random", [](Pairs* p) { *p = Random(); return true; }},
      {"rendered", Rendered}};
  int failures = 0;
  std::stringstream list(sets);
  for (std::string name; std::getline(list, name, ',');) {
    const auto maker = makers.find(name);
    if (maker == makers.end()) {
      std::fprintf(stderr, "laser_digest: unknown set '%s'\n", name.c_str());
      return 2;
    }
    Pairs pairs;
    if (!maker->second(&pairs)) return 2;
    size_t points = 0, points_sse2 = 0;
    long gap_filled = 0, gap_filled_sse2 = 0;
    char hash[17], hash_sse2[17];
    std::snprintf(hash, sizeof hash, "%016llx",
                  static_cast<unsigned long long>(DigestOf(name, pairs, true, &points, &gap_filled)));
    std::snprintf(hash_sse2, sizeof hash_sse2, "%016llx",
                  static_cast<unsigned long long>(DigestOf(name, pairs, false, &points_sse2, &gap_filled_sse2)));
    // The points the gap step added (LineStats::gap_filled; not in the digest, whose found counts hold them).
    std::printf("%s %s %zu frames, %zu points (%ld filled by the gap step)\n", name.c_str(), hash, pairs.size(),
                points, gap_filled);
    if (std::strcmp(hash, hash_sse2) != 0) {
      std::printf("  FAIL: SSE2 alone gives %s\n", hash_sse2);
      ++failures;
    }
    if (!check.empty()) {
      const auto it = expected.find(name);
      if (it == expected.end()) {
        std::printf("  FAIL: no digest of '%s' in %s\n", name.c_str(), check.c_str());
        ++failures;
      } else if (it->second != hash) {
        std::printf("  FAIL: %s has %s\n", check.c_str(), it->second.c_str());
        ++failures;
      } else {
        std::printf("  same as %s\n", check.c_str());
      }
    }
  }
  if (!g_dump_path.empty()) {
    const rotoscan::Status written = rotoscan::WriteFileAtomically(g_dump_path, g_dump);
    if (!written.ok()) {
      std::fprintf(stderr, "laser_digest: %s\n", written.ToString().c_str());
      return 2;
    }
  }
  return failures == 0 ? 0 : 1;
}

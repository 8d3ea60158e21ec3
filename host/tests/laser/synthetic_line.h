// Synthetic laser-on / laser-off frames for the extraction tests and benchmarks: a line whose centre is
// known per row, with a chosen profile, noise and saturation.
#pragma once

#include <cmath>
#include <functional>
#include <random>
#include <vector>

#include <opencv2/core.hpp>

namespace rotoscan::laser::testing {

struct LineSpec {
  double amplitude = 160;      // DN added by the laser at the centre, before clipping
  double sigma = 1.2;          // Gaussian sigma (px) of the edges
  double flat_half_width = 0;  // half width of the flat top (px); 0: a plain Gaussian
  double background = 80;      // laser-off level, DN
  double noise = 1.4;          // Gaussian noise per frame, DN
};

// Profile value at distance x from the centre: a flat top of half width w with Gaussian flanks.
inline double Profile(const LineSpec& s, double x) {
  const double e = std::max(0.0, std::abs(x) - s.flat_half_width);
  return s.amplitude * std::exp(-0.5 * e * e / (s.sigma * s.sigma));
}

// Fills on/off (CV_8UC1) with a line at centre(row) (< 0: no line in that row). The profile is
// integrated over each pixel's width (5 sub-samples) as a real sensor does.
inline void MakePair(int width, int height, const LineSpec& s, const std::function<double(int)>& centre,
                     uint32_t seed, cv::Mat* on, cv::Mat* off) {
  std::mt19937 rng(seed);
  std::normal_distribution<double> noise(0.0, s.noise);
  on->create(height, width, CV_8UC1);
  off->create(height, width, CV_8UC1);
  for (int r = 0; r < height; ++r) {
    const double c = centre(r);
    for (int x = 0; x < width; ++x) {
      double laser = 0;
      if (c >= 0 && std::abs(x - c) < s.flat_half_width + 8 * s.sigma + 2) {
        for (int k = 0; k < 5; ++k) laser += Profile(s, x - 0.4 + 0.2 * k - c) / 5;
      }
      const double b = s.background + noise(rng);
      const double a = s.background + laser + noise(rng);
      off->at<uint8_t>(r, x) = cv::saturate_cast<uint8_t>(b);
      on->at<uint8_t>(r, x) = cv::saturate_cast<uint8_t>(a);
    }
  }
}

}  // namespace rotoscan::laser::testing

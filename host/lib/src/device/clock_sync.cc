// Clock fit from PING round trips; see clock_sync.h for the method.
#include "rotoscan/device/clock_sync.h"

#include <algorithm>
#include <cmath>
#include <string>

namespace rotoscan::device {

Status ClockFitOptions::Check() const {
  if (!(keep_fraction > 0.0 && keep_fraction <= 1.0)) {
    return InvalidArgumentError("clock fit: keep_fraction must be in (0, 1], got " +
                                std::to_string(keep_fraction));
  }
  if (min_samples < 1) return InvalidArgumentError("clock fit: min_samples must be >= 1");
  if (fit_drift && min_samples < 2) return InvalidArgumentError("clock fit: a drift needs min_samples >= 2");
  if (min_drift_span_us < 0) return InvalidArgumentError("clock fit: min_drift_span_us must be >= 0");
  return Status::Ok();
}

Result<ClockFit> FitClock(const std::vector<PingSample>& samples, const ClockFitOptions& options) {
  ROTOSCAN_RETURN_IF_ERROR(options.Check());
  for (size_t i = 0; i < samples.size(); ++i) {
    if (samples[i].host_receive_us < samples[i].host_send_us) {
      return InvalidArgumentError("clock fit: ping sample " + std::to_string(i) +
                                  " was received before it was sent");
    }
  }
  std::vector<PingSample> sorted = samples;
  std::sort(sorted.begin(), sorted.end(), [](const PingSample& a, const PingSample& b) {
    return a.host_receive_us - a.host_send_us < b.host_receive_us - b.host_send_us;
  });
  const size_t keep = std::max<size_t>(static_cast<size_t>(options.min_samples),
                                       static_cast<size_t>(std::ceil(options.keep_fraction * sorted.size())));
  if (sorted.size() < static_cast<size_t>(options.min_samples)) {
    return NotConvergedError("clock fit: " + std::to_string(sorted.size()) + " ping samples, need at least " +
                             std::to_string(options.min_samples));
  }
  sorted.resize(std::min(keep, sorted.size()));

  // Centre the host times to keep the normal equations well conditioned (times are ~1e12 us).
  const double h_ref = 0.5 * static_cast<double>(sorted[0].host_send_us + sorted[0].host_receive_us);
  const double d_ref = static_cast<double>(sorted[0].device_us);
  double sum_h = 0, sum_d = 0;
  std::vector<double> hs, ds;
  for (const PingSample& s : sorted) {
    const double h = 0.5 * static_cast<double>(s.host_send_us + s.host_receive_us) - h_ref;
    const double d = static_cast<double>(s.device_us) - d_ref;
    hs.push_back(h);
    ds.push_back(d);
    sum_h += h;
    sum_d += d;
  }
  const double n = static_cast<double>(hs.size());
  const double mean_h = sum_h / n, mean_d = sum_d / n;
  const auto [first, last] = std::minmax_element(hs.begin(), hs.end());
  const int64_t span_us = std::llround(*last - *first);
  double slope = 1.0;
  if (options.fit_drift && span_us >= options.min_drift_span_us) {
    double shh = 0, shd = 0;
    for (size_t i = 0; i < hs.size(); ++i) {
      shh += (hs[i] - mean_h) * (hs[i] - mean_h);
      shd += (hs[i] - mean_h) * (ds[i] - mean_d);
    }
    if (shh <= 0.0) {
      return NotConvergedError(
          "clock fit: the kept ping samples all have the same host time; drift unobservable");
    }
    slope = shd / shh;
  }
  // d - d_ref = a + slope * (h - h_ref)  =>  d = (d_ref + a - slope * h_ref) + slope * h.
  const double a = mean_d - slope * mean_h;
  double sq = 0;
  for (size_t i = 0; i < hs.size(); ++i) {
    const double r = ds[i] - (a + slope * hs[i]);
    sq += r * r;
  }
  ClockFit fit;
  fit.drift = slope - 1.0;
  fit.offset_us = d_ref + a - slope * h_ref;
  fit.samples_used = static_cast<int>(hs.size());
  fit.min_round_trip_us = sorted[0].host_receive_us - sorted[0].host_send_us;
  fit.residual_rms_us = std::sqrt(sq / n);
  fit.span_us = span_us;
  return fit;
}

}  // namespace rotoscan::device

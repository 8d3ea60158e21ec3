// Clock offset and drift between the board's timebase and the host clock, from PING round trips.
//
// Each PING gives a sample (host send time h0, board time d, host receive time h1). The board read its clock
// somewhere inside [h0, h1], so d - (h0 + h1) / 2 is the offset at the midpoint with an error of at most
// half the round trip. Round trips delayed by the OS or the bus only widen that interval, so only the samples
// with the smallest round trips are kept (those within `keep_fraction` of the fastest, and at least
// `min_samples`), and a straight line
//     d = offset + (1 + drift) * h_mid
// is fitted to them by least squares. The fit's residual RMS is reported; a fit from too few samples or
// with no spread in time (drift unobservable) is refused.
#pragma once

#include <cstdint>
#include <vector>

#include "rotoscan/core/status.h"

namespace rotoscan::device {

struct PingSample {
  int64_t host_send_us = 0;     // host clock when the PING was written
  uint64_t device_us = 0;       // board clock in the PONG
  int64_t host_receive_us = 0;  // host clock when the PONG was read
};

struct ClockFitOptions {
  double keep_fraction = 0.25;  // fraction of samples kept, fastest round trips first
  int min_samples = 3;          // refuse a fit from fewer kept samples
  bool fit_drift = true;        // false: offset only (drift fixed to 0)
  // The drift is fitted only when the kept samples span at least this much host time, else the offset
  // alone: the fastest pings may all come from one burst a few milliseconds long, whose drift is its
  // jitter (issue 13: 0.5 %, every later trigger missed). 0: any span.
  int64_t min_drift_span_us = 0;
  Status Check() const;
};

struct ClockFit {
  // device_us = offset_us + (1 + drift) * host_us
  double offset_us = 0.0;
  double drift = 0.0;  // dimensionless; 1e-6 = 1 ppm (board clock runs fast)
  int samples_used = 0;
  int64_t min_round_trip_us = 0;
  double residual_rms_us = 0.0;
  // Host time from the first to the last sample used (ClockFitOptions::min_drift_span_us).
  int64_t span_us = 0;

  double DeviceFromHost(double host_us) const { return offset_us + (1.0 + drift) * host_us; }
  double HostFromDevice(double device_us) const { return (device_us - offset_us) / (1.0 + drift); }
};

// InvalidArgument when a sample's receive time precedes its send time; NotConverged when too few samples
// or (with fit_drift) all kept samples are at the same host time.
Result<ClockFit> FitClock(const std::vector<PingSample>& samples, const ClockFitOptions& options = {});

}  // namespace rotoscan::device

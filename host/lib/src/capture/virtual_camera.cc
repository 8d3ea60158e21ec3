// Backend `virtual`: the virtual scanner (sim/renderer.h) as a camera. At each exposure it renders what
// the simulated rig (RigTruth: the sim board's pin edges) did during that exposure: the table angle at the
// frame's middle, and for every row the fraction of that row's exposure window each laser was lit, so a
// frame exposed across a laser switch shows it -- for a rolling shutter, row by row (rows start
// readout_us / (height - 1) apart). A laser's contribution is additive (renderer.h), so a row lit for a
// fraction f of its exposure is off + f * (laser - off).
//
// Free-running: frame k exposes from start + k / fps; triggered: each rising edge of the board's trigger
// line starts an exposure `trigger_delay_us` later (the sim board's camera model). Time is the scan's
// clock: a VirtualClock moves to the end of each frame (accelerated time), a real clock waits for it.
// The renderer's short frames (left, right, off) are taken for exposures below the geometric mean of the
// scene's laser and natural exposures, the natural frame (lamp on) above it.
//
// Backend options: rolling=0|1, readout_ms (rolling readout, default 0.8 of the frame period),
// drop=ID,ID (frame ids the camera loses: the id is used, no frame is delivered), extra=ID,ID (a frame
// delivered twice under a new id, as a camera with a spurious trigger would), trigger_delay_us,
// latency_ms (a frame is delivered this long after its last row's exposure ended: USB transfer).
#include <algorithm>
#include <cmath>
#include <deque>
#include <set>

#include <opencv2/imgproc.hpp>

#include "backend_options.h"
#include "rotoscan/capture/factory.h"
#include "rotoscan/capture/virtual_rig.h"
#include "rotoscan/sim/renderer.h"
#include "rotoscan/sim/scene.h"
#include "virtual_render.h"

namespace rotoscan::capture {
namespace {

class VirtualCamera : public Camera {
 public:
  VirtualCamera(std::unique_ptr<sim::Renderer> renderer, std::shared_ptr<Clock> clock, RigTruth* truth,
                bool rolling, double readout_fraction, int64_t readout_us, std::set<long long> drop,
                std::set<long long> extra, int64_t trigger_delay_us, int64_t latency_us)
      : renderer_(std::move(renderer)),
        clock_(std::move(clock)),
        truth_(truth),
        readout_fraction_(readout_fraction),
        fixed_readout_us_(readout_us),
        drop_(std::move(drop)),
        extra_(std::move(extra)),
        trigger_delay_us_(trigger_delay_us),
        latency_us_(latency_us) {
    const auto& scene = renderer_->scene();
    capabilities_.trigger_input = true;
    capabilities_.exposure_active_output = true;
    capabilities_.rolling_shutter = rolling;
    capabilities_.timestamp = TimestampSource::kExposureStart;
    capabilities_.device_timestamps = true;
    capabilities_.manual_exposure = capabilities_.manual_gain = capabilities_.manual_white_balance = true;
    capabilities_.exposure_while_streaming = true;
    settings_.width = scene.rig.camera.width;
    settings_.height = scene.rig.camera.height;
    settings_.exposure_us = static_cast<int64_t>(scene.sensor.laser_exposure_us);
    natural_threshold_us_ = internal::NaturalThresholdUs(scene);
    UpdateReadout();
  }

  const CameraCapabilities& capabilities() const override { return capabilities_; }
  std::string Description() const override {
    return "virtual " + std::to_string(settings_.width) + "x" + std::to_string(settings_.height) +
           (capabilities_.rolling_shutter ? " rolling" : " global") + " shutter";
  }

  Result<CameraSettings> Configure(const CameraSettings& settings) override {
    ROTOSCAN_RETURN_IF_ERROR(settings.Check());
    if (started_) return FailedPreconditionError("virtual camera: Configure() while started");
    const auto& camera = renderer_->scene().rig.camera;
    if (settings.width != 0 && (settings.width != camera.width || settings.height != camera.height)) {
      return InvalidArgumentError("the virtual camera renders the scene's size " + std::to_string(camera.width) +
                                  "x" + std::to_string(camera.height) + " (set camera.width/height in the scene)");
    }
    if (renderer_->scene().sensor.bit_depth != 8) {
      return InvalidArgumentError("the virtual camera delivers 8-bit frames (the scene has a 12-bit sensor)");
    }
    const double period = 1e6 / settings.frame_rate_hz;
    int64_t longest = settings.exposure_us;
    for (int64_t e : settings.exposure_cycle_us) longest = std::max(longest, e);
    if (!settings.triggered && static_cast<double>(longest) > period) {
      return InvalidArgumentError("virtual camera: exposure " + std::to_string(longest) +
                                  " us is longer than the frame period at " +
                                  std::to_string(settings.frame_rate_hz) + " frames/s");
    }
    settings_ = settings;
    settings_.width = camera.width;
    settings_.height = camera.height;
    UpdateReadout();
    return settings_;
  }
  const CameraSettings& settings() const override { return settings_; }

  Status Start() override {
    started_ = true;
    exposure_ = settings_.exposure_us;
    exposure_change_us_ = 0;
    previous_exposure_ = exposure_;
    const int64_t now = clock_->NowUs();
    first_start_us_ = now + 100;
    next_index_ = 0;
    cycle_index_ = 0;
    last_edge_us_ = now;
    pending_edges_.clear();
    return Status::Ok();
  }
  Status Stop() override {
    started_ = false;
    pending_edges_.clear();
    return Status::Ok();
  }
  Status SetExposure(int64_t exposure_us) override {
    if (exposure_us <= 0) return InvalidArgumentError("virtual camera: exposure must be positive");
    if (!settings_.triggered && static_cast<double>(exposure_us) > 1e6 / settings_.frame_rate_hz) {
      return InvalidArgumentError("virtual camera: exposure longer than the frame period");
    }
    previous_exposure_ = exposure_;
    exposure_ = exposure_us;
    exposure_change_us_ = clock_->NowUs();
    return Status::Ok();
  }

  Result<std::optional<Frame>> NextFrame(int64_t timeout_us) override {
    if (!started_) return FailedPreconditionError("virtual camera: NextFrame() before Start()");
    const int64_t deadline = clock_->NowUs() + std::max<int64_t>(timeout_us, 0);
    if (!repeat_.empty()) {
      Frame f = std::move(repeat_.front());
      repeat_.pop_front();
      return std::optional<Frame>(std::move(f));
    }
    while (true) {
      Frame frame;
      frame.readout_us = readout_us_;
      if (settings_.triggered) {
        if (pending_edges_.empty()) {
          const int64_t now = clock_->NowUs();
          for (int64_t e : truth_->TriggerEdges(last_edge_us_, now)) pending_edges_.push_back(e);
          if (!pending_edges_.empty()) last_edge_us_ = pending_edges_.back();
        }
        if (pending_edges_.empty()) {
          const int64_t now = clock_->NowUs();
          if (now >= deadline) return std::optional<Frame>();
          clock_->WaitUntilUs(std::min(deadline, now + kPollUs));
          continue;
        }
        frame.exposure_start_us = pending_edges_.front() + trigger_delay_us_;
        pending_edges_.pop_front();
        frame.exposure_us = settings_.exposure_cycle_us.empty()
                                ? settings_.exposure_us
                                : settings_.exposure_cycle_us[cycle_index_ % settings_.exposure_cycle_us.size()];
        ++cycle_index_;
      } else {
        const double period = 1e6 / settings_.frame_rate_hz;
        frame.exposure_start_us = first_start_us_ + std::llround(static_cast<double>(next_index_) * period);
        frame.exposure_us = frame.exposure_start_us >= exposure_change_us_ ? exposure_ : previous_exposure_;
        if (frame.ExposureEndUs() + latency_us_ > deadline) {
          clock_->WaitUntilUs(deadline);
          return std::optional<Frame>();
        }
        ++next_index_;
      }
      frame.frame_id = frame_id_++;
      frame.device_time_us = static_cast<uint64_t>(frame.exposure_start_us);
      clock_->WaitUntilUs(frame.ExposureEndUs() + latency_us_);  // delivered after readout and transfer
      if (drop_.count(static_cast<long long>(frame.frame_id)) != 0) continue;  // lost by the camera
      frame.image = Render(frame);
      if (extra_.count(static_cast<long long>(frame.frame_id)) != 0) {
        Frame copy = frame;
        copy.frame_id = frame_id_++;
        copy.exposure_start_us += 1;  // a spurious second exposure right after
        copy.image = frame.image.clone();
        repeat_.push_back(std::move(copy));
      }
      return std::optional<Frame>(std::move(frame));
    }
  }

 private:
  static constexpr int64_t kPollUs = 500;

  void UpdateReadout() {
    if (!capabilities_.rolling_shutter) {
      readout_us_ = 0;
    } else if (fixed_readout_us_ > 0) {
      readout_us_ = fixed_readout_us_;
    } else {
      readout_us_ = std::llround(readout_fraction_ * 1e6 / settings_.frame_rate_hz);
    }
    capabilities_.readout_us = readout_us_;
  }

  cv::Mat Render(const Frame& frame) {
    const bool natural = static_cast<double>(frame.exposure_us) >= natural_threshold_us_;
    return internal::RenderExposure(*renderer_, *truth_, frame.exposure_start_us, frame.exposure_us, frame.readout_us,
                                    frame.frame_id, natural, settings_.format);
  }

  std::unique_ptr<sim::Renderer> renderer_;
  std::shared_ptr<Clock> clock_;
  RigTruth* truth_;
  CameraCapabilities capabilities_;
  CameraSettings settings_;
  double readout_fraction_;
  int64_t fixed_readout_us_;
  int64_t readout_us_ = 0;
  std::set<long long> drop_, extra_;
  int64_t trigger_delay_us_;
  int64_t latency_us_;
  double natural_threshold_us_ = 0;
  bool started_ = false;
  int64_t exposure_ = 0, previous_exposure_ = 0, exposure_change_us_ = 0;
  int64_t first_start_us_ = 0;
  int64_t next_index_ = 0;
  size_t cycle_index_ = 0;
  uint64_t frame_id_ = 0;
  int64_t last_edge_us_ = 0;
  std::deque<int64_t> pending_edges_;
  std::deque<Frame> repeat_;
};

}  // namespace

namespace internal {

cv::Mat RenderExposure(sim::Renderer& renderer, RigTruth& truth, int64_t exposure_start_us, int64_t exposure_us,
                       int64_t readout_us, uint64_t frame_id, bool natural, PixelFormat format) {
  const int h = renderer.scene().rig.camera.height;
  const int64_t mid = exposure_start_us + (readout_us + exposure_us) / 2;
  const double angle = truth.TableAngleAt(mid);
  // Per row, the fraction of its exposure each laser was lit.
  std::vector<double> fl(static_cast<size_t>(h)), fr(static_cast<size_t>(h));
  bool any_left = false, any_right = false;
  for (int r = 0; r < h; ++r) {
    const int64_t s = exposure_start_us + (h > 1 ? readout_us * r / (h - 1) : 0);
    if (r == 0 || readout_us > 0) truth.LaserFractions(s, s + exposure_us, &fl[r], &fr[r]);
    else { fl[r] = fl[0]; fr[r] = fr[0]; }
    any_left |= fl[r] > 0;
    any_right |= fr[r] > 0;
  }
  sim::FrameMask mask{any_left, any_right, true, natural};
  const auto step = renderer.RenderStep(angle, sim::FrameSeed(renderer.scene().seed, -1, static_cast<int>(frame_id), 0), mask);
  const cv::Mat& off = step.frames[2];
  cv::Mat base = natural ? step.frames[3] : off;
  cv::Mat out;
  if (!any_left && !any_right) {
    out = base.clone();
  } else {
    cv::Mat acc;
    base.convertTo(acc, CV_32FC3);
    cv::Mat off_f;
    off.convertTo(off_f, CV_32FC3);
    for (int laser = 0; laser < 2; ++laser) {
      const auto& f = laser == 0 ? fl : fr;
      if (!(laser == 0 ? any_left : any_right)) continue;
      cv::Mat lit;
      step.frames[static_cast<size_t>(laser)].convertTo(lit, CV_32FC3);
      lit -= off_f;
      for (int r = 0; r < h; ++r) {
        if (f[static_cast<size_t>(r)] > 0) acc.row(r) += lit.row(r) * f[static_cast<size_t>(r)];
      }
    }
    acc.convertTo(out, CV_8UC3);  // saturates
  }
  if (format == PixelFormat::kGray8) {
    cv::Mat gray;
    cv::cvtColor(out, gray, cv::COLOR_BGR2GRAY);
    return gray;
  }
  return out;
}

}  // namespace internal

namespace {

Result<std::unique_ptr<Camera>> OpenVirtualCamera(const std::string& argument, const OpenContext& context) {
  if (!argument.empty()) return InvalidArgumentError("camera 'virtual' takes no argument (got '" + argument + "')");
  RigTruth* truth = context.truth != nullptr ? context.truth
                                             : (context.board != nullptr ? context.board->truth() : nullptr);
  if (truth == nullptr || !context.clock) {
    return FailedPreconditionError(
        "the virtual camera films the simulated rig: open it with the sim board (--device sim)");
  }
  ROTOSCAN_ASSIGN_OR_RETURN(const auto options,
                            internal::BackendOptions::Parse(context.options, "virtual",
                                                            {"rolling", "readout_ms", "drop", "extra",
                                                             "trigger_delay_us", "latency_ms"}));
  ROTOSCAN_ASSIGN_OR_RETURN(const double rolling, options.Number("rolling", 0));
  ROTOSCAN_ASSIGN_OR_RETURN(const double readout_ms, options.Number("readout_ms", 0));
  ROTOSCAN_ASSIGN_OR_RETURN(const double delay, options.Number("trigger_delay_us", 10));
  ROTOSCAN_ASSIGN_OR_RETURN(const double latency_ms, options.Number("latency_ms", 0));
  ROTOSCAN_ASSIGN_OR_RETURN(const auto drop, options.List("drop"));
  ROTOSCAN_ASSIGN_OR_RETURN(const auto extra, options.List("extra"));
  if (readout_ms < 0 || delay < 0 || latency_ms < 0) return InvalidArgumentError("virtual: readout_ms and trigger_delay_us must be >= 0");
  sim::Scene scene;
  if (context.scene_path.empty()) {
    ROTOSCAN_ASSIGN_OR_RETURN(scene, sim::SceneDefaults("machine_vision"));
    sim::ObjectSpec sphere;  // a sphere on the table, as `rotoscan simulate` has by default
    sphere.type = sim::ObjectType::kSphere;
    sphere.radius_mm = 30.0;
    sphere.position_mm = Eigen::Vector3d(0, 0, 0);  // resting on the table
    scene.objects.push_back(sphere);
  } else {
    ROTOSCAN_ASSIGN_OR_RETURN(scene, sim::LoadScene(context.scene_path));
  }
  ROTOSCAN_ASSIGN_OR_RETURN(scene, sim::PlaceScene(scene, context.placement, nullptr));
  ROTOSCAN_ASSIGN_OR_RETURN(auto renderer, sim::Renderer::Create(scene));
  return std::unique_ptr<Camera>(std::make_unique<VirtualCamera>(
      std::move(renderer), context.clock, truth, rolling != 0, 0.8, std::llround(readout_ms * 1000),
      std::set<long long>(drop.begin(), drop.end()), std::set<long long>(extra.begin(), extra.end()),
      std::llround(delay), std::llround(latency_ms * 1000)));
}

}  // namespace

void RegisterCaptureBackend_virtual(BackendRegistry* registry) {
  registry->AddCamera({"virtual", "the virtual scanner rendering the simulated rig (with --device sim)",
                       OpenVirtualCamera, []() -> Result<std::vector<DeviceListing>> {
                         return std::vector<DeviceListing>{{"virtual", "the virtual scanner's camera"}};
                       }});
}

}  // namespace rotoscan::capture

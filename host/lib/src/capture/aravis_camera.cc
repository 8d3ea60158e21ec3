// See aravis_camera.h.
#include "capture/aravis_camera.h"

#include <arv.h>

#include <algorithm>
#include <cmath>
#include <cstdlib>
#include <cstring>
#include <ctime>
#include <mutex>
#include <optional>

#include <opencv2/imgproc.hpp>

#include "rotoscan/core/logging.h"

namespace rotoscan::capture {

uint64_t FrameIdExtender::Extend(uint64_t raw) {
  if (first_) {
    first_ = false;
    last_raw_ = raw;
    value_ = raw;
    return value_;
  }
  uint64_t delta;
  if (raw > last_raw_) {
    delta = raw - last_raw_;
  } else if (last_raw_ <= 0xffff && raw <= 0xffff && last_raw_ - raw > 0x8000) {
    delta = raw + 0xffff - last_raw_;  // a 16-bit GigE Vision 1.x block id wrapped (0 is never used)
  } else {
    delta = 1;  // a restart or a repeat: keep the sequence increasing
  }
  last_raw_ = raw;
  value_ += delta;
  return value_;
}

namespace {

std::optional<std::string> OptionValue(const std::vector<std::string>& options, const std::string& key) {
  for (const auto& o : options) {
    const auto eq = o.find('=');
    if (eq != std::string::npos && o.substr(0, eq) == key) return o.substr(eq + 1);
  }
  return std::nullopt;
}

Result<int64_t> IntOption(const std::vector<std::string>& options, const std::string& key, int64_t fallback,
                          int64_t lo, int64_t hi) {
  const auto v = OptionValue(options, key);
  if (!v) return fallback;
  char* end = nullptr;
  const long long x = std::strtoll(v->c_str(), &end, 10);
  if (v->empty() || *end != '\0' || x < lo || x > hi) {
    return InvalidArgumentError("aravis option " + key + "=" + *v + ": expected an integer in [" +
                                std::to_string(lo) + ", " + std::to_string(hi) + "]");
  }
  return static_cast<int64_t>(x);
}

// Takes a GError: its message, and frees it.
std::string Take(GError** error) {
  std::string m = (*error != nullptr) ? (*error)->message : "unknown error";
  g_clear_error(error);
  return m;
}

int64_t RealtimeMinusMonotonicUs() {
  timespec r{}, m{};
  clock_gettime(CLOCK_REALTIME, &r);
  clock_gettime(CLOCK_MONOTONIC, &m);
  return (int64_t{r.tv_sec} - m.tv_sec) * 1'000'000 + (r.tv_nsec - m.tv_nsec) / 1000;
}

std::once_flag fake_enabled;

}  // namespace

struct AravisCamera::Impl {
  ArvCamera* camera = nullptr;
  ArvStream* stream = nullptr;
  std::string id;
  std::string model;
  std::vector<std::string> options;
  CameraCapabilities caps;
  CameraSettings settings;
  bool configured = false;
  bool streaming = false;
  int buffer_count = 8;
  size_t payload = 0;  // bytes allocated per stream buffer
  std::string pixel_format;  // "Mono8", "BGR8", "RGB8", "BayerRG8", ...
  std::string trigger_source;
  std::string exposure_line;
  FrameIdExtender ids;
  std::optional<uint64_t> last_id;
  AravisCounters counters;
  int64_t frame_period_us = 33'333;
  int64_t exposure_change_us = INT64_MIN / 2;
  int64_t previous_exposure_us = 0;
  gulong control_lost_handler = 0;
  bool control_lost = false;  // set from Aravis's thread
  std::mutex mutex;

  std::string Name() const { return "aravis " + id + (model.empty() ? "" : " (" + model + ")"); }

  Status FeatureError(const std::string& feature, const std::string& what) const {
    return DeviceError(Name() + ": feature " + feature + ": " + what);
  }

  bool Has(const char* feature) {
    GError* error = nullptr;
    const bool has = arv_camera_is_feature_available(camera, feature, &error);
    g_clear_error(&error);
    return has;
  }

  std::vector<std::string> Enumeration(const char* feature) {
    std::vector<std::string> values;
    GError* error = nullptr;
    guint n = 0;
    const char** v = arv_camera_dup_available_enumerations_as_strings(camera, feature, &n, &error);
    g_clear_error(&error);
    for (guint i = 0; v != nullptr && i < n; ++i) values.emplace_back(v[i]);
    g_free(v);
    return values;
  }

  // Sets an enumeration feature and reads it back.
  Status SetString(const char* feature, const std::string& value) {
    if (!Has(feature)) return FeatureError(feature, "the camera does not have it");
    const auto allowed = Enumeration(feature);
    if (!allowed.empty() && std::find(allowed.begin(), allowed.end(), value) == allowed.end()) {
      std::string list;
      for (const auto& a : allowed) list += (list.empty() ? "" : ", ") + a;
      return FeatureError(feature, "'" + value + "' is not one of its values (" + list + ")");
    }
    GError* error = nullptr;
    arv_camera_set_string(camera, feature, value.c_str(), &error);
    if (error != nullptr) return FeatureError(feature, "setting '" + value + "': " + Take(&error));
    const char* back = arv_camera_get_string(camera, feature, &error);
    if (error != nullptr) return FeatureError(feature, "reading it back: " + Take(&error));
    if (back == nullptr || value != back) {
      return FeatureError(feature, "set to '" + value + "', reads back '" + (back ? back : "") +
                                       "': the camera does not hold it");
    }
    return Status();
  }

  // Sets a value through an Aravis setter and checks the getter within a relative tolerance.
  Status SetFloat(const char* feature, double value, void (*set)(ArvCamera*, double, GError**),
                  double (*get)(ArvCamera*, GError**), void (*bounds)(ArvCamera*, double*, double*, GError**)) {
    GError* error = nullptr;
    double lo = 0.0, hi = 0.0;
    bounds(camera, &lo, &hi, &error);
    if (error != nullptr) return FeatureError(feature, "reading its bounds: " + Take(&error));
    if (value < lo || value > hi) {
      return {StatusCode::kInvalidArgument, Name() + ": feature " + feature + ": " + std::to_string(value) +
                                                " is outside the camera's range [" + std::to_string(lo) + ", " +
                                                std::to_string(hi) + "]"};
    }
    set(camera, value, &error);
    if (error != nullptr) return FeatureError(feature, "setting " + std::to_string(value) + ": " + Take(&error));
    const double back = get(camera, &error);
    if (error != nullptr) return FeatureError(feature, "reading it back: " + Take(&error));
    if (std::abs(back - value) > 0.01 * std::abs(value) + 1.0) {
      return FeatureError(feature, "set to " + std::to_string(value) + ", reads back " + std::to_string(back) +
                                       ": the camera does not hold it");
    }
    return Status();
  }

  void DestroyStream() {
    if (stream != nullptr) {
      g_object_unref(stream);
      stream = nullptr;
    }
  }

  static void OnControlLost(ArvDevice*, gpointer self) {
    auto* impl = static_cast<Impl*>(self);
    std::lock_guard<std::mutex> lock(impl->mutex);
    impl->control_lost = true;
  }

  bool Lost() {
    std::lock_guard<std::mutex> lock(mutex);
    return control_lost;
  }

  // Copies (and converts) a buffer's image; nullopt for a format this backend does not decode.
  std::optional<cv::Mat> Image(ArvBuffer* buffer) {
    size_t size = 0;
    const auto* data = static_cast<const uint8_t*>(arv_buffer_get_image_data(buffer, &size));
    const int w = arv_buffer_get_image_width(buffer), h = arv_buffer_get_image_height(buffer);
    const ArvPixelFormat pf = arv_buffer_get_image_pixel_format(buffer);
    const bool mono = pf == ARV_PIXEL_FORMAT_MONO_8;
    const bool rgb = pf == ARV_PIXEL_FORMAT_RGB_8_PACKED || pf == ARV_PIXEL_FORMAT_BGR_8_PACKED;
    const size_t needed = static_cast<size_t>(w) * static_cast<size_t>(h) * (rgb ? 3 : 1);
    // Aravis's fake camera with a fill pattern of the caller's own leaves the received size at 0 (only its
    // built-in pattern sets it); the image is still in the buffer, whose allocation is `payload` bytes.
    if (size == 0 && data != nullptr && arv_buffer_get_status(buffer) == ARV_BUFFER_STATUS_SUCCESS) {
      size = std::min<size_t>(needed, payload);
    }
    if (data == nullptr || w <= 0 || h <= 0 || size < needed) return std::nullopt;
    const cv::Mat raw(h, w, rgb ? CV_8UC3 : CV_8UC1, const_cast<uint8_t*>(data));
    const bool gray = settings.format == PixelFormat::kGray8;
    cv::Mat out;
    if (mono) {
      if (gray) {
        out = raw.clone();
      } else {
        cv::cvtColor(raw, out, cv::COLOR_GRAY2BGR);
      }
    } else if (pf == ARV_PIXEL_FORMAT_BGR_8_PACKED) {
      if (gray) {
        cv::cvtColor(raw, out, cv::COLOR_BGR2GRAY);
      } else {
        out = raw.clone();
      }
    } else if (pf == ARV_PIXEL_FORMAT_RGB_8_PACKED) {
      cv::cvtColor(raw, out, gray ? cv::COLOR_RGB2GRAY : cv::COLOR_RGB2BGR);
    } else {
      // GenICam BayerXY8 names the first two pixels of the first row; OpenCV names the second and third
      // pixels of the second row, so GenICam RG is OpenCV's BG, and so on.
      int code = -1;
      if (pf == ARV_PIXEL_FORMAT_BAYER_RG_8) code = gray ? cv::COLOR_BayerBG2GRAY : cv::COLOR_BayerBG2BGR;
      if (pf == ARV_PIXEL_FORMAT_BAYER_BG_8) code = gray ? cv::COLOR_BayerRG2GRAY : cv::COLOR_BayerRG2BGR;
      if (pf == ARV_PIXEL_FORMAT_BAYER_GR_8) code = gray ? cv::COLOR_BayerGB2GRAY : cv::COLOR_BayerGB2BGR;
      if (pf == ARV_PIXEL_FORMAT_BAYER_GB_8) code = gray ? cv::COLOR_BayerGR2GRAY : cv::COLOR_BayerGR2BGR;
      if (code < 0) return std::nullopt;
      cv::cvtColor(raw, out, code);
    }
    return out;
  }
};

AravisCamera::AravisCamera(std::unique_ptr<Impl> impl) : impl_(std::move(impl)) {}

AravisCamera::~AravisCamera() {
  if (impl_->streaming) (void)Stop();
  impl_->DestroyStream();
  if (impl_->camera != nullptr) {
    if (impl_->control_lost_handler != 0) {
      g_signal_handler_disconnect(arv_camera_get_device(impl_->camera), impl_->control_lost_handler);
    }
    g_object_unref(impl_->camera);
  }
}

Result<std::unique_ptr<AravisCamera>> AravisCamera::Open(const std::string& id, const OpenContext& context) {
  if (id.rfind("Fake", 0) == 0) std::call_once(fake_enabled, [] { arv_enable_interface("Fake"); });
  auto impl = std::make_unique<Impl>();
  impl->options = context.options;
  ROTOSCAN_ASSIGN_OR_RETURN(const int64_t buffers, IntOption(impl->options, "buffers", 8, 2, 64));
  impl->buffer_count = static_cast<int>(buffers);
  ROTOSCAN_ASSIGN_OR_RETURN(const int64_t readout, IntOption(impl->options, "readout_us", 0, 0, 1'000'000));
  GError* error = nullptr;
  impl->camera = arv_camera_new(id.empty() ? nullptr : id.c_str(), &error);
  if (impl->camera == nullptr) {
    const std::string message = Take(&error);
    std::string found;
    arv_update_device_list();
    for (unsigned i = 0; i < arv_get_n_devices(); ++i) {
      found += (found.empty() ? "" : ", ") + std::string(arv_get_device_id(i));
    }
    return NotFoundError("aravis: no camera " + (id.empty() ? std::string("found") : "'" + id + "'") + " (" +
                         message + "); cameras found: " + (found.empty() ? "none" : found));
  }
  const char* device_id = arv_camera_get_device_id(impl->camera, &error);
  g_clear_error(&error);
  // The id the user gave names the camera in messages; Aravis's own is used when none was given.
  impl->id = !id.empty() ? id : (device_id != nullptr ? device_id : "?");
  const char* vendor = arv_camera_get_vendor_name(impl->camera, &error);
  g_clear_error(&error);
  const char* model = arv_camera_get_model_name(impl->camera, &error);
  g_clear_error(&error);
  impl->model = std::string(vendor ? vendor : "") + (vendor && model ? " " : "") + (model ? model : "");
  impl->control_lost_handler = g_signal_connect(arv_camera_get_device(impl->camera), "control-lost",
                                                G_CALLBACK(&Impl::OnControlLost), impl.get());

  CameraCapabilities& c = impl->caps;
  c.trigger_input = impl->Has("TriggerMode") && impl->Has("TriggerSource");
  c.exposure_active_output = impl->Has("LineSelector") && impl->Has("LineSource");
  c.rolling_shutter = readout > 0;
  c.readout_us = readout;
  c.timestamp = TimestampSource::kFrameEnd;
  c.device_timestamps = true;
  c.manual_exposure = true;
  c.manual_gain = impl->Has("Gain") || impl->Has("GainRaw");
  c.manual_white_balance = impl->Has("BalanceRatio");
  c.exposure_while_streaming = true;
  return std::unique_ptr<AravisCamera>(new AravisCamera(std::move(impl)));
}

const CameraCapabilities& AravisCamera::capabilities() const { return impl_->caps; }
const CameraSettings& AravisCamera::settings() const { return impl_->settings; }
AravisCounters AravisCamera::counters() const { return impl_->counters; }
ArvCamera* AravisCamera::arv_camera() { return impl_->camera; }
std::string AravisCamera::trigger_source() const { return impl_->trigger_source; }
std::string AravisCamera::exposure_output_line() const { return impl_->exposure_line; }

std::string AravisCamera::Description() const {
  const Impl& m = *impl_;
  std::string d = m.Name();
  if (m.configured) {
    d += " " + m.pixel_format + " " + std::to_string(m.settings.width) + "x" + std::to_string(m.settings.height) +
         (m.settings.triggered ? ", triggered on " + m.trigger_source : ", free-running") +
         (m.exposure_line.empty() ? "" : ", exposure active on " + m.exposure_line) +
         (m.caps.rolling_shutter ? ", rolling shutter" : ", global shutter");
  }
  return d;
}

Result<CameraSettings> AravisCamera::Configure(const CameraSettings& requested) {
  Impl& m = *impl_;
  ROTOSCAN_RETURN_IF_ERROR(requested.Check());
  if (m.streaming) return FailedPreconditionError(m.Name() + ": Configure while streaming");
  if (requested.triggered && !m.caps.trigger_input) {
    return InvalidArgumentError(m.Name() + " has no TriggerMode/TriggerSource: it cannot be triggered");
  }
  // A cycle of different exposures per trigger needs the camera's sequencer (SequencerMode, GenICam SFNC),
  // which this backend does not drive yet: one exposure for every frame only.
  for (const int64_t e : requested.exposure_cycle_us) {
    if (e != requested.exposure_cycle_us.front()) {
      return InvalidArgumentError(m.Name() + ": a cycle of exposures per trigger needs the camera's sequencer, "
                                             "which the aravis backend does not drive yet");
    }
  }
  m.configured = false;
  GError* error = nullptr;
  CameraSettings got = requested;
  if (!requested.exposure_cycle_us.empty()) got.exposure_us = requested.exposure_cycle_us.front();

  // Trigger off while configuring (some cameras refuse size changes or frame rates while triggered).
  if (m.Has("TriggerSelector")) {
    const auto selectors = m.Enumeration("TriggerSelector");
    if (std::find(selectors.begin(), selectors.end(), "FrameStart") != selectors.end()) {
      ROTOSCAN_RETURN_IF_ERROR(m.SetString("TriggerSelector", "FrameStart"));
    }
  }
  if (m.caps.trigger_input) ROTOSCAN_RETURN_IF_ERROR(m.SetString("TriggerMode", "Off"));

  // Pixel format: Mono8 for gray; for color BGR8, RGB8, or a Bayer pattern demosaiced here.
  const auto formats = m.Enumeration("PixelFormat");
  auto offered = [&](const char* f) { return std::find(formats.begin(), formats.end(), f) != formats.end(); };
  std::vector<const char*> wanted;
  if (requested.format == PixelFormat::kGray8) {
    wanted = {"Mono8"};
  } else {
    wanted = {"BGR8", "BGR8Packed", "RGB8", "RGB8Packed", "BayerRG8", "BayerBG8", "BayerGR8", "BayerGB8"};
  }
  m.pixel_format.clear();
  for (const char* f : wanted) {
    if (offered(f)) {
      m.pixel_format = f;
      break;
    }
  }
  if (m.pixel_format.empty()) {
    return InvalidArgumentError(m.Name() + " offers no 8-bit " +
                                (requested.format == PixelFormat::kGray8 ? "Mono8" : "color or Bayer") + " format");
  }
  ROTOSCAN_RETURN_IF_ERROR(m.SetString("PixelFormat", m.pixel_format));

  // Size: the requested one centred on the sensor, or the whole sensor.
  gint sensor_w = 0, sensor_h = 0;
  arv_camera_get_sensor_size(m.camera, &sensor_w, &sensor_h, &error);
  if (error != nullptr) return DeviceError(m.Name() + ": reading the sensor size: " + Take(&error));
  const int w = requested.width > 0 ? requested.width : sensor_w;
  const int h = requested.height > 0 ? requested.height : sensor_h;
  if (w > sensor_w || h > sensor_h) {
    return InvalidArgumentError(m.Name() + ": " + std::to_string(w) + "x" + std::to_string(h) +
                                " is larger than the sensor (" + std::to_string(sensor_w) + "x" +
                                std::to_string(sensor_h) + ")");
  }
  arv_camera_set_region(m.camera, 0, 0, w, h, &error);
  if (error != nullptr) return DeviceError(m.Name() + ": setting the region: " + Take(&error));
  gint x = 0, y = 0, got_w = 0, got_h = 0;
  arv_camera_get_region(m.camera, &x, &y, &got_w, &got_h, &error);
  if (error != nullptr) return DeviceError(m.Name() + ": reading the region back: " + Take(&error));
  if (got_w != w || got_h != h) {
    return DeviceError(m.Name() + ": features Width/Height: set to " + std::to_string(w) + "x" + std::to_string(h) +
                       ", read back " + std::to_string(got_w) + "x" + std::to_string(got_h));
  }
  got.width = w;
  got.height = h;

  // Frame rate (free-running; the upper bound of trigger rates when triggered).
  if (m.Has("AcquisitionFrameRate") || m.Has("AcquisitionFrameRateAbs")) {
    arv_camera_set_frame_rate(m.camera, requested.frame_rate_hz, &error);
    if (error != nullptr) return DeviceError(m.Name() + ": feature AcquisitionFrameRate: " + Take(&error));
    const double rate = arv_camera_get_frame_rate(m.camera, &error);
    if (error != nullptr) return DeviceError(m.Name() + ": feature AcquisitionFrameRate: " + Take(&error));
    got.frame_rate_hz = rate;
  }
  m.frame_period_us = std::lround(1e6 / got.frame_rate_hz);

  // Exposure and gain: manual, then set and read back.
  if (m.Has("ExposureAuto")) ROTOSCAN_RETURN_IF_ERROR(m.SetString("ExposureAuto", "Off"));
  const char* exposure_name = m.Has("ExposureTime") ? "ExposureTime" : "ExposureTimeAbs";
  ROTOSCAN_RETURN_IF_ERROR(m.SetFloat(exposure_name, static_cast<double>(got.exposure_us),
                                      &arv_camera_set_exposure_time, &arv_camera_get_exposure_time,
                                      &arv_camera_get_exposure_time_bounds));
  got.exposure_us = std::llround(arv_camera_get_exposure_time(m.camera, &error));
  g_clear_error(&error);
  if (m.Has("GainAuto")) ROTOSCAN_RETURN_IF_ERROR(m.SetString("GainAuto", "Off"));
  if (m.caps.manual_gain) {
    ROTOSCAN_RETURN_IF_ERROR(m.SetFloat(m.Has("Gain") ? "Gain" : "GainRaw", requested.gain_db, &arv_camera_set_gain,
                                        &arv_camera_get_gain, &arv_camera_get_gain_bounds));
  } else if (requested.gain_db != 0.0) {
    return DeviceError(m.Name() + ": feature Gain: the camera does not have it");
  }

  // White balance.
  if (m.Has("BalanceWhiteAuto")) ROTOSCAN_RETURN_IF_ERROR(m.SetString("BalanceWhiteAuto", "Off"));
  if (requested.white_balance) {
    if (!m.Has("BalanceRatioSelector") || !m.Has("BalanceRatio")) {
      return DeviceError(m.Name() + ": feature BalanceRatio: the camera does not have it");
    }
    const char* channels[3] = {"Red", "Green", "Blue"};
    for (int i = 0; i < 3; ++i) {
      ROTOSCAN_RETURN_IF_ERROR(m.SetString("BalanceRatioSelector", channels[i]));
      arv_camera_set_float(m.camera, "BalanceRatio", (*requested.white_balance)[static_cast<size_t>(i)], &error);
      if (error != nullptr) return DeviceError(m.Name() + ": feature BalanceRatio: " + Take(&error));
      const double back = arv_camera_get_float(m.camera, "BalanceRatio", &error);
      if (error != nullptr) return DeviceError(m.Name() + ": feature BalanceRatio: " + Take(&error));
      if (std::abs(back - (*requested.white_balance)[static_cast<size_t>(i)]) > 0.02) {
        return DeviceError(m.Name() + ": feature BalanceRatio (" + channels[i] + "): reads back " +
                           std::to_string(back) + ": the camera does not hold it");
      }
    }
  }

  // Exposure-active output, wired back to the board.
  m.exposure_line.clear();
  const auto line_option = OptionValue(m.options, "exposure_line");
  if (m.caps.exposure_active_output) {
    const std::string line = line_option.value_or("Line1");
    ROTOSCAN_RETURN_IF_ERROR(m.SetString("LineSelector", line));
    if (m.Has("LineMode")) ROTOSCAN_RETURN_IF_ERROR(m.SetString("LineMode", "Output"));
    ROTOSCAN_RETURN_IF_ERROR(m.SetString("LineSource", "ExposureActive"));
    m.exposure_line = line;
  } else if (line_option) {
    return DeviceError(m.Name() + ": features LineSelector/LineSource: the camera has none, so its exposure-active "
                                  "output cannot be put on " + *line_option);
  } else {
    ROTOSCAN_LOG(kInfo) << m.Name() << ": no LineSelector/LineSource: exposure-active output not configured";
  }

  // Trigger last (setting the frame rate turns it off on some cameras).
  m.trigger_source.clear();
  if (requested.triggered) {
    const std::string source = OptionValue(m.options, "trigger_line").value_or("Line0");
    ROTOSCAN_RETURN_IF_ERROR(m.SetString("TriggerSource", source));
    if (m.Has("TriggerActivation")) {
      const auto activations = m.Enumeration("TriggerActivation");
      if (std::find(activations.begin(), activations.end(), "RisingEdge") != activations.end()) {
        ROTOSCAN_RETURN_IF_ERROR(m.SetString("TriggerActivation", "RisingEdge"));
      }
    }
    ROTOSCAN_RETURN_IF_ERROR(m.SetString("TriggerMode", "On"));
    m.trigger_source = source;
  }

  m.caps.timestamp_uncertainty_us = m.frame_period_us;
  m.settings = got;
  m.previous_exposure_us = got.exposure_us;
  m.exposure_change_us = INT64_MIN / 2;
  m.configured = true;
  return got;
}

Status AravisCamera::Start() {
  Impl& m = *impl_;
  if (!m.configured) return FailedPreconditionError(m.Name() + ": Start before Configure");
  if (m.streaming) return Status();
  GError* error = nullptr;
  m.stream = arv_camera_create_stream(m.camera, nullptr, nullptr, &error);
  if (m.stream == nullptr) return DeviceError(m.Name() + ": creating the stream: " + Take(&error));
  const guint payload = arv_camera_get_payload(m.camera, &error);
  if (error != nullptr) {
    m.DestroyStream();
    return DeviceError(m.Name() + ": reading the payload size: " + Take(&error));
  }
  m.payload = payload;
  for (int i = 0; i < m.buffer_count; ++i) arv_stream_push_buffer(m.stream, arv_buffer_new(payload, nullptr));
  arv_camera_start_acquisition(m.camera, &error);
  if (error != nullptr) {
    m.DestroyStream();
    return DeviceError(m.Name() + ": starting the acquisition: " + Take(&error));
  }
  m.streaming = true;
  m.ids = FrameIdExtender();
  m.last_id.reset();
  return Status();
}

Status AravisCamera::Stop() {
  Impl& m = *impl_;
  if (!m.streaming) return Status();
  m.streaming = false;
  GError* error = nullptr;
  arv_camera_stop_acquisition(m.camera, &error);
  m.DestroyStream();
  if (error != nullptr) return DeviceError(m.Name() + ": stopping the acquisition: " + Take(&error));
  return Status();
}

Status AravisCamera::SetExposure(int64_t exposure_us) {
  Impl& m = *impl_;
  if (!m.configured) return FailedPreconditionError(m.Name() + ": SetExposure before Configure");
  if (exposure_us <= 0) return InvalidArgumentError("exposure must be positive");
  ROTOSCAN_RETURN_IF_ERROR(m.SetFloat(m.Has("ExposureTime") ? "ExposureTime" : "ExposureTimeAbs",
                                      static_cast<double>(exposure_us), &arv_camera_set_exposure_time,
                                      &arv_camera_get_exposure_time, &arv_camera_get_exposure_time_bounds));
  m.previous_exposure_us = m.settings.exposure_us;
  m.settings.exposure_us = exposure_us;
  m.exposure_change_us = MonotonicNowUs();
  return Status();
}

Result<std::optional<Frame>> AravisCamera::NextFrame(int64_t timeout_us) {
  Impl& m = *impl_;
  if (!m.streaming) return FailedPreconditionError(m.Name() + ": NextFrame while not streaming");
  const int64_t deadline = MonotonicNowUs() + std::max<int64_t>(0, timeout_us);
  for (;;) {
    if (m.Lost()) return DeviceError(m.Name() + ": control of the camera was lost (unplugged?)");
    const int64_t left = deadline - MonotonicNowUs();
    if (left <= 0) return std::optional<Frame>();
    ArvBuffer* buffer = arv_stream_timeout_pop_buffer(m.stream, static_cast<guint64>(left));
    if (buffer == nullptr) {
      if (m.Lost()) return DeviceError(m.Name() + ": control of the camera was lost (unplugged?)");
      return std::optional<Frame>();
    }
    if (arv_buffer_get_status(buffer) != ARV_BUFFER_STATUS_SUCCESS) {
      ++m.counters.failed;
      ++m.counters.dropped;
      ROTOSCAN_LOG(kWarning) << m.Name() << ": frame " << arv_buffer_get_frame_id(buffer)
                             << " dropped (Aravis buffer status " << static_cast<int>(arv_buffer_get_status(buffer))
                             << ")";
      arv_stream_push_buffer(m.stream, buffer);
      continue;
    }
    std::optional<cv::Mat> image = m.Image(buffer);
    if (!image) {
      arv_stream_push_buffer(m.stream, buffer);
      return DeviceError(m.Name() + ": a frame in an unexpected pixel format or size");
    }
    Frame f;
    f.image = std::move(*image);
    f.frame_id = m.ids.Extend(arv_buffer_get_frame_id(buffer));
    if (m.last_id && f.frame_id > *m.last_id + 1) m.counters.dropped += f.frame_id - *m.last_id - 1;
    m.last_id = f.frame_id;
    f.device_time_us = arv_buffer_get_timestamp(buffer) / 1000;
    const int64_t received_us =
        static_cast<int64_t>(arv_buffer_get_system_timestamp(buffer) / 1000) - RealtimeMinusMonotonicUs();
    arv_stream_push_buffer(m.stream, buffer);
    f.readout_us = m.caps.readout_us;
    f.exposure_us = m.settings.exposure_us;
    f.exposure_start_us = received_us - f.readout_us - f.exposure_us;
    if (f.exposure_start_us < m.exposure_change_us + m.frame_period_us) {
      f.exposure_us = m.previous_exposure_us;
      f.exposure_start_us = received_us - f.readout_us - f.exposure_us;
    }
    ++m.counters.frames;
    return std::optional<Frame>(std::move(f));
  }
}

Result<std::vector<DeviceListing>> ListAravisCameras() {
  arv_update_device_list();
  std::vector<DeviceListing> out;
  for (unsigned i = 0; i < arv_get_n_devices(); ++i) {
    const char* id = arv_get_device_id(i);
    if (id == nullptr) continue;
    const char* vendor = arv_get_device_vendor(i);
    const char* model = arv_get_device_model(i);
    const char* protocol = arv_get_device_protocol(i);
    out.push_back({std::string("aravis:") + id, std::string(vendor ? vendor : "") + " " + (model ? model : "") +
                                                    " (" + (protocol ? protocol : "GenICam") + ")"});
  }
  return out;
}

void RegisterCaptureBackend_aravis(BackendRegistry* registry) {
  CameraBackend b;
  b.name = "aravis";
  b.description = "GenICam cameras through Aravis (USB3 Vision, GigE Vision): trigger input, exposure-active output";
  b.open = [](const std::string& argument, const OpenContext& context) -> Result<std::unique_ptr<Camera>> {
    ROTOSCAN_ASSIGN_OR_RETURN(auto camera, AravisCamera::Open(argument, context));
    return std::unique_ptr<Camera>(std::move(camera));
  };
  b.list = &ListAravisCameras;
  registry->AddCamera(std::move(b));
}

}  // namespace rotoscan::capture

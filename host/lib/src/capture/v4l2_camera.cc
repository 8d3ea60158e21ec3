// See v4l2_camera.h. The structures, ioctls and control ids are the kernel's (linux/videodev2.h).
#include "capture/v4l2_camera.h"

#include <dirent.h>
#include <fcntl.h>
#include <poll.h>
#include <sys/ioctl.h>
#include <sys/mman.h>
#include <unistd.h>

#include <linux/videodev2.h>

#include <algorithm>
#include <cerrno>
#include <cmath>
#include <csetjmp>
#include <cstdio>
#include <cstdlib>
#include <cstring>
#include <optional>

#include <jpeglib.h>
#include <opencv2/imgproc.hpp>

#include "rotoscan/core/logging.h"

namespace rotoscan::capture {

// ---------------------------------------------------------------------------------------------------
// Pure helpers

namespace {

// libjpeg reports errors through a callback that must not return: jump back to the decoder.
struct JpegError {
  jpeg_error_mgr mgr;
  jmp_buf jump;
  int warnings = 0;
  char message[JMSG_LENGTH_MAX] = {};
};

void JpegErrorExit(j_common_ptr cinfo) {
  auto* err = reinterpret_cast<JpegError*>(cinfo->err);
  (*cinfo->err->format_message)(cinfo, err->message);
  std::longjmp(err->jump, 1);
}

// Level -1 is a warning ("premature end of data segment", "corrupt JPEG data"): libjpeg would go on and
// fill the rest with grey. For a scanner that frame is corrupt: remember the first one.
void JpegEmitMessage(j_common_ptr cinfo, int level) {
  auto* err = reinterpret_cast<JpegError*>(cinfo->err);
  if (level < 0) {
    if (err->warnings++ == 0) (*cinfo->err->format_message)(cinfo, err->message);
  }
}

// Decodes into `out` (already allocated, rows contiguous). No object with a destructor lives in this
// function, so the longjmp out of libjpeg skips nothing.
bool DecodeJpegInto(const uint8_t* data, size_t size, bool gray, cv::Mat* out, std::string* error) {
  jpeg_decompress_struct cinfo;
  JpegError err;
  cinfo.err = jpeg_std_error(&err.mgr);
  err.mgr.error_exit = &JpegErrorExit;
  err.mgr.emit_message = &JpegEmitMessage;
  if (setjmp(err.jump) != 0) {
    jpeg_destroy_decompress(&cinfo);
    *error = err.message;
    return false;
  }
  jpeg_create_decompress(&cinfo);
  jpeg_mem_src(&cinfo, data, static_cast<unsigned long>(size));
  jpeg_read_header(&cinfo, TRUE);
  cinfo.out_color_space = gray ? JCS_GRAYSCALE : JCS_EXT_BGR;
  jpeg_start_decompress(&cinfo);
  if (static_cast<int>(cinfo.output_width) != out->cols || static_cast<int>(cinfo.output_height) != out->rows) {
    std::snprintf(err.message, sizeof(err.message), "JPEG is %ux%u, the stream is %dx%d", cinfo.output_width,
                  cinfo.output_height, out->cols, out->rows);
    jpeg_destroy_decompress(&cinfo);
    *error = err.message;
    return false;
  }
  while (cinfo.output_scanline < cinfo.output_height) {
    JSAMPROW row = out->ptr<uint8_t>(static_cast<int>(cinfo.output_scanline));
    jpeg_read_scanlines(&cinfo, &row, 1);
  }
  jpeg_finish_decompress(&cinfo);
  jpeg_destroy_decompress(&cinfo);
  if (err.warnings > 0) {
    *error = err.message;
    return false;
  }
  return true;
}

std::string FourccName(uint32_t f) {
  std::string s;
  for (int i = 0; i < 4; ++i) {
    const char c = static_cast<char>((f >> (8 * i)) & 0xff);
    s += (c >= 32 && c < 127) ? c : '?';
  }
  while (!s.empty() && s.back() == ' ') s.pop_back();
  return s;
}

int Xioctl(int fd, unsigned long request, void* arg) {
  int r;
  do {
    r = ioctl(fd, request, arg);
  } while (r == -1 && errno == EINTR);
  return r;
}

std::string Errno() { return std::strerror(errno); }

}  // namespace

Result<cv::Mat> DecodeMjpeg(const uint8_t* data, size_t size, int width, int height, PixelFormat format) {
  // A JPEG starts with SOI (FF D8); anything shorter than a header is not one.
  if (data == nullptr || size < 4 || data[0] != 0xff || data[1] != 0xd8) {
    return CorruptDataError("MJPEG frame does not start with a JPEG SOI marker (" + std::to_string(size) +
                            " bytes)");
  }
  cv::Mat out(height, width, format == PixelFormat::kGray8 ? CV_8UC1 : CV_8UC3);
  std::string error;
  if (!DecodeJpegInto(data, size, format == PixelFormat::kGray8, &out, &error)) {
    return CorruptDataError("MJPEG frame does not decode (" + std::to_string(size) + " bytes): " + error);
  }
  return out;
}

Result<cv::Mat> ConvertYuyv(const uint8_t* data, size_t size, int width, int height, int bytes_per_line,
                            PixelFormat format) {
  if (bytes_per_line < 2 * width) bytes_per_line = 2 * width;
  const size_t needed = static_cast<size_t>(bytes_per_line) * static_cast<size_t>(height - 1) +
                        2 * static_cast<size_t>(width);
  if (data == nullptr || size < needed) {
    return CorruptDataError("YUYV frame is " + std::to_string(size) + " bytes, " + std::to_string(width) + "x" +
                            std::to_string(height) + " needs " + std::to_string(needed));
  }
  const cv::Mat yuyv(height, width, CV_8UC2, const_cast<uint8_t*>(data), static_cast<size_t>(bytes_per_line));
  cv::Mat out;
  cv::cvtColor(yuyv, out, format == PixelFormat::kGray8 ? cv::COLOR_YUV2GRAY_YUYV : cv::COLOR_YUV2BGR_YUYV);
  return out;
}

V4l2Timestamp DecodeTimestampFlags(uint32_t flags) {
  V4l2Timestamp t;
  t.monotonic = (flags & V4L2_BUF_FLAG_TIMESTAMP_MASK) == V4L2_BUF_FLAG_TIMESTAMP_MONOTONIC;
  t.start_of_exposure = (flags & V4L2_BUF_FLAG_TSTAMP_SRC_MASK) == V4L2_BUF_FLAG_TSTAMP_SRC_SOE;
  return t;
}

int64_t ExposureStartFromStamp(int64_t t_us, const V4l2Timestamp& kind, int64_t exposure_us, int64_t readout_us) {
  return kind.start_of_exposure ? t_us : t_us - readout_us - exposure_us;
}

uint64_t SequenceExtender::Extend(uint32_t sequence) {
  if (first_) {
    first_ = false;
    last_ = sequence;
    return last_;
  }
  const uint32_t delta = sequence - static_cast<uint32_t>(last_);  // modulo 2^32
  // A step "back" of less than half the range is a restart (STREAMOFF/ON resets the driver's count).
  if (delta >= 0x80000000u) {
    last_ = (last_ & ~uint64_t{0xffffffff}) | sequence;
    return last_;
  }
  last_ += delta;
  return last_;
}

// ---------------------------------------------------------------------------------------------------
// The camera

namespace {

struct Buffer {
  void* start = nullptr;
  size_t length = 0;
  bool mmapped = false;
};

struct ControlSpec {
  uint32_t id;
  const char* macro;  // for the message
};

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
  errno = 0;
  const long long x = std::strtoll(v->c_str(), &end, 10);
  if (v->empty() || *end != '\0' || errno != 0 || x < lo || x > hi) {
    return InvalidArgumentError("v4l2 option " + key + "=" + *v + ": expected an integer in [" +
                                std::to_string(lo) + ", " + std::to_string(hi) + "]");
  }
  return static_cast<int64_t>(x);
}

}  // namespace

struct V4l2Camera::Impl {
  std::string path;
  int fd = -1;
  v4l2_capability cap{};
  std::vector<std::string> options;
  CameraCapabilities caps;
  CameraSettings settings;
  bool configured = false;
  bool streaming = false;
  bool userptr = false;
  int buffer_count = 4;
  uint32_t fourcc = 0;
  int bytes_per_line = 0;
  size_t image_size = 0;
  std::optional<int64_t> readout_option;
  std::vector<Buffer> buffers;
  SequenceExtender sequence;
  std::optional<uint64_t> last_id;
  V4l2Counters counters;
  int64_t frame_period_us = 33'333;
  // Exposure change while streaming: frames starting before `exposure_change_us` + one frame period may
  // still have the old exposure (UVC applies a control at a frame boundary of its own choosing).
  int64_t exposure_change_us = INT64_MIN;
  int64_t previous_exposure_us = 0;

  std::string Name() const {
    return "v4l2 " + path + " (" + reinterpret_cast<const char*>(cap.card) + ")";
  }

  Status ControlError(const ControlSpec& c, const std::string& what) const {
    return DeviceError(Name() + ": control " + c.macro + ": " + what);
  }

  // Sets a control and reads it back: the camera must hold the value (within one step of it).
  Status SetAndCheck(const ControlSpec& c, int32_t value) {
    v4l2_queryctrl q{};
    q.id = c.id;
    if (Xioctl(fd, VIDIOC_QUERYCTRL, &q) == -1) {
      return ControlError(c, "the camera does not have it (" + Errno() + "); a scanner needs it manual");
    }
    if (q.flags & V4L2_CTRL_FLAG_DISABLED) return ControlError(c, "the camera has it disabled");
    if (q.type != V4L2_CTRL_TYPE_MENU && q.type != V4L2_CTRL_TYPE_BOOLEAN && (value < q.minimum || value > q.maximum)) {
      return ControlError(c, std::to_string(value) + " is outside the camera's range [" + std::to_string(q.minimum) +
                                 ", " + std::to_string(q.maximum) + "]");
    }
    v4l2_control ctrl{};
    ctrl.id = c.id;
    ctrl.value = value;
    if (Xioctl(fd, VIDIOC_S_CTRL, &ctrl) == -1) {
      return ControlError(c, "setting it to " + std::to_string(value) + " failed: " + Errno());
    }
    v4l2_control back{};
    back.id = c.id;
    if (Xioctl(fd, VIDIOC_G_CTRL, &back) == -1) {
      return ControlError(c, "reading it back failed: " + Errno());
    }
    const int32_t tolerance = q.step > 1 ? q.step - 1 : 0;
    if (std::abs(back.value - value) > tolerance) {
      return ControlError(c, "set to " + std::to_string(value) + ", reads back " + std::to_string(back.value) +
                                 ": the camera does not hold it");
    }
    return Status();
  }

  // The control's default value, or an error naming it when the camera does not have it.
  Result<int32_t> DefaultOf(const ControlSpec& c) {
    v4l2_queryctrl q{};
    q.id = c.id;
    if (Xioctl(fd, VIDIOC_QUERYCTRL, &q) == -1) {
      return ControlError(c, "the camera does not have it (" + Errno() + "); a scanner needs it manual");
    }
    return q.default_value;
  }

  bool HasControl(uint32_t id) {
    v4l2_queryctrl q{};
    q.id = id;
    return Xioctl(fd, VIDIOC_QUERYCTRL, &q) == 0 && !(q.flags & V4L2_CTRL_FLAG_DISABLED);
  }

  std::vector<std::pair<int, int>> Sizes(uint32_t format) {
    std::vector<std::pair<int, int>> sizes;
    for (uint32_t i = 0; i < 256; ++i) {
      v4l2_frmsizeenum s{};
      s.index = i;
      s.pixel_format = format;
      if (Xioctl(fd, VIDIOC_ENUM_FRAMESIZES, &s) == -1) break;
      if (s.type == V4L2_FRMSIZE_TYPE_DISCRETE) {
        sizes.emplace_back(static_cast<int>(s.discrete.width), static_cast<int>(s.discrete.height));
      } else {
        sizes.emplace_back(static_cast<int>(s.stepwise.max_width), static_cast<int>(s.stepwise.max_height));
        break;
      }
    }
    return sizes;
  }

  std::vector<uint32_t> Formats() {
    std::vector<uint32_t> formats;
    for (uint32_t i = 0; i < 64; ++i) {
      v4l2_fmtdesc f{};
      f.index = i;
      f.type = V4L2_BUF_TYPE_VIDEO_CAPTURE;
      if (Xioctl(fd, VIDIOC_ENUM_FMT, &f) == -1) break;
      formats.push_back(f.pixelformat);
    }
    return formats;
  }

  void FreeBuffers() {
    for (Buffer& b : buffers) {
      if (b.mmapped) {
        munmap(b.start, b.length);
      } else {
        std::free(b.start);
      }
    }
    buffers.clear();
    if (fd >= 0) {
      v4l2_requestbuffers req{};
      req.count = 0;
      req.type = V4L2_BUF_TYPE_VIDEO_CAPTURE;
      req.memory = userptr ? V4L2_MEMORY_USERPTR : V4L2_MEMORY_MMAP;
      (void)Xioctl(fd, VIDIOC_REQBUFS, &req);
    }
  }

  Status Queue(uint32_t index) {
    v4l2_buffer b{};
    b.type = V4L2_BUF_TYPE_VIDEO_CAPTURE;
    b.index = index;
    if (userptr) {
      b.memory = V4L2_MEMORY_USERPTR;
      b.m.userptr = reinterpret_cast<unsigned long>(buffers[index].start);
      b.length = static_cast<uint32_t>(buffers[index].length);
    } else {
      b.memory = V4L2_MEMORY_MMAP;
    }
    if (Xioctl(fd, VIDIOC_QBUF, &b) == -1) return DeviceError(Name() + ": VIDIOC_QBUF: " + Errno());
    return Status();
  }

  Status AllocateBuffers() {
    v4l2_requestbuffers req{};
    req.count = static_cast<uint32_t>(buffer_count);
    req.type = V4L2_BUF_TYPE_VIDEO_CAPTURE;
    req.memory = userptr ? V4L2_MEMORY_USERPTR : V4L2_MEMORY_MMAP;
    if (Xioctl(fd, VIDIOC_REQBUFS, &req) == -1) {
      return DeviceError(Name() + ": VIDIOC_REQBUFS (" + (userptr ? "userptr" : "mmap") +
                         " streaming I/O): " + Errno());
    }
    if (req.count < 2) return DeviceError(Name() + ": the driver gave " + std::to_string(req.count) + " buffers");
    buffers.assign(req.count, Buffer{});
    const size_t page = static_cast<size_t>(sysconf(_SC_PAGESIZE));
    for (uint32_t i = 0; i < req.count; ++i) {
      if (userptr) {
        const size_t length = (image_size + page - 1) / page * page;
        void* p = nullptr;
        if (posix_memalign(&p, page, length) != 0) return InternalError(Name() + ": out of memory for buffers");
        std::memset(p, 0, length);
        buffers[i].start = p;
        buffers[i].length = length;
      } else {
        v4l2_buffer b{};
        b.type = V4L2_BUF_TYPE_VIDEO_CAPTURE;
        b.memory = V4L2_MEMORY_MMAP;
        b.index = i;
        if (Xioctl(fd, VIDIOC_QUERYBUF, &b) == -1) return DeviceError(Name() + ": VIDIOC_QUERYBUF: " + Errno());
        void* p = mmap(nullptr, b.length, PROT_READ | PROT_WRITE, MAP_SHARED, fd, b.m.offset);
        if (p == MAP_FAILED) return DeviceError(Name() + ": mmap of buffer " + std::to_string(i) + ": " + Errno());
        buffers[i].start = p;
        buffers[i].length = b.length;
        buffers[i].mmapped = true;
      }
    }
    return Status();
  }

  // One decoded frame from a dequeued buffer; nullopt when the buffer is dropped (counted).
  std::optional<Frame> Decode(const v4l2_buffer& b) {
    if ((b.flags & V4L2_BUF_FLAG_ERROR) || b.bytesused == 0) {
      ++counters.error_buffers;  // counted in `dropped` by the gap it leaves
      ROTOSCAN_LOG(kWarning) << Name() << ": frame " << b.sequence << " dropped (driver flagged an error)";
      return std::nullopt;
    }
    const auto* data = static_cast<const uint8_t*>(buffers[b.index].start);
    const size_t size = std::min<size_t>(b.bytesused, buffers[b.index].length);
    Result<cv::Mat> image = fourcc == V4L2_PIX_FMT_MJPEG
                                ? DecodeMjpeg(data, size, settings.width, settings.height, settings.format)
                                : ConvertYuyv(data, size, settings.width, settings.height, bytes_per_line,
                                              settings.format);
    if (!image.ok()) {
      if (fourcc == V4L2_PIX_FMT_MJPEG) ++counters.corrupt_jpeg;
      ++counters.error_buffers;  // counted in `dropped` by the gap it leaves
      ROTOSCAN_LOG(kWarning) << Name() << ": frame " << b.sequence << " dropped: " << image.status().message();
      return std::nullopt;
    }
    Frame f;
    f.image = std::move(image).value();
    f.frame_id = sequence.Extend(b.sequence);
    if (last_id && f.frame_id > *last_id + 1) counters.dropped += f.frame_id - *last_id - 1;
    last_id = f.frame_id;
    V4l2Timestamp kind = DecodeTimestampFlags(b.flags);
    int64_t stamp_us = static_cast<int64_t>(b.timestamp.tv_sec) * 1'000'000 + b.timestamp.tv_usec;
    if (!kind.monotonic) {  // COPY/UNKNOWN clock: only the dequeue time is known, after the frame's end
      stamp_us = MonotonicNowUs();
      kind.start_of_exposure = false;
    }
    f.readout_us = caps.readout_us;
    f.exposure_us = settings.exposure_us;
    f.exposure_start_us = ExposureStartFromStamp(stamp_us, kind, f.exposure_us, f.readout_us);
    if (f.exposure_start_us < exposure_change_us + frame_period_us) {
      f.exposure_us = previous_exposure_us;  // taken before the change reached the sensor (see Impl)
      f.exposure_start_us = ExposureStartFromStamp(stamp_us, kind, f.exposure_us, f.readout_us);
    }
    caps.timestamp = kind.start_of_exposure && kind.monotonic ? TimestampSource::kExposureStart
                                                               : TimestampSource::kFrameEnd;
    ++counters.frames;
    return f;
  }
};

V4l2Camera::V4l2Camera(std::unique_ptr<Impl> impl) : impl_(std::move(impl)) {}

V4l2Camera::~V4l2Camera() {
  if (impl_->streaming) (void)Stop();
  impl_->FreeBuffers();
  if (impl_->fd >= 0) close(impl_->fd);
}

Result<std::unique_ptr<V4l2Camera>> V4l2Camera::Open(const std::string& path_in, const OpenContext& context) {
  std::string path = path_in;
  if (path.empty()) {
    ROTOSCAN_ASSIGN_OR_RETURN(const auto found, ListV4l2Cameras());
    if (found.empty()) return NotFoundError("v4l2: no video capture device in /dev");
    path = found.front().spec.substr(std::string("v4l2:").size());
  }
  auto impl = std::make_unique<Impl>();
  impl->path = path;
  impl->options = context.options;
  const int fd = open(path.c_str(), O_RDWR | O_NONBLOCK | O_CLOEXEC);
  if (fd < 0) {
    const int e = errno;
    return (e == ENOENT ? NotFoundError("v4l2: " + path + ": no such device")
                        : IoError("v4l2: cannot open " + path + ": " + std::strerror(e)));
  }
  impl->fd = fd;
  if (Xioctl(fd, VIDIOC_QUERYCAP, &impl->cap) == -1) {
    const std::string e = Errno();
    close(fd);
    impl->fd = -1;
    return InvalidArgumentError("v4l2: " + path + " is not a V4L2 device (VIDIOC_QUERYCAP: " + e + ")");
  }
  const uint32_t dev_caps =
      (impl->cap.capabilities & V4L2_CAP_DEVICE_CAPS) ? impl->cap.device_caps : impl->cap.capabilities;
  std::unique_ptr<V4l2Camera> camera(new V4l2Camera(std::move(impl)));
  Impl& m = *camera->impl_;
  if (!(dev_caps & V4L2_CAP_VIDEO_CAPTURE)) {
    return InvalidArgumentError(m.Name() + " has no video capture (a metadata or output node?)");
  }
  if (!(dev_caps & V4L2_CAP_STREAMING)) return InvalidArgumentError(m.Name() + " has no streaming I/O");
  const auto io = OptionValue(m.options, "io").value_or("mmap");
  if (io != "mmap" && io != "userptr") return InvalidArgumentError("v4l2 option io=" + io + ": mmap or userptr");
  m.userptr = io == "userptr";
  ROTOSCAN_ASSIGN_OR_RETURN(const int64_t count, IntOption(m.options, "buffers", 4, 2, 32));
  m.buffer_count = static_cast<int>(count);
  ROTOSCAN_ASSIGN_OR_RETURN(const int64_t readout, IntOption(m.options, "readout_us", -1, 0, 1'000'000));
  if (readout >= 0) m.readout_option = readout;
  m.caps.trigger_input = false;
  m.caps.exposure_active_output = false;
  m.caps.rolling_shutter = true;  // UVC webcam sensors are rolling-shutter CMOS
  m.caps.timestamp = TimestampSource::kExposureStart;  // refined from the first buffer's flags
  m.caps.device_timestamps = false;
  m.caps.manual_exposure = m.HasControl(V4L2_CID_EXPOSURE_ABSOLUTE);
  m.caps.manual_gain = m.HasControl(V4L2_CID_GAIN);
  m.caps.manual_white_balance = m.HasControl(V4L2_CID_WHITE_BALANCE_TEMPERATURE);
  m.caps.exposure_while_streaming = true;
  return camera;
}

const CameraCapabilities& V4l2Camera::capabilities() const { return impl_->caps; }
const CameraSettings& V4l2Camera::settings() const { return impl_->settings; }
uint32_t V4l2Camera::pixel_format() const { return impl_->fourcc; }
V4l2Counters V4l2Camera::counters() const { return impl_->counters; }

std::string V4l2Camera::Description() const {
  const Impl& m = *impl_;
  std::string d = m.Name() + " [" + reinterpret_cast<const char*>(m.cap.driver) + "]";
  if (m.configured) {
    d += " " + FourccName(m.fourcc) + " " + std::to_string(m.settings.width) + "x" +
         std::to_string(m.settings.height) + " " + std::to_string(m.settings.frame_rate_hz) + " fps, rolling shutter, " +
         (m.readout_option ? "readout " + std::to_string(*m.readout_option) + " us"
                           : "readout unknown (bounded by the frame period, " + std::to_string(m.caps.readout_us) +
                                 " us; set readout_us=)");
  }
  return d;
}

Result<CameraSettings> V4l2Camera::Configure(const CameraSettings& requested) {
  Impl& m = *impl_;
  ROTOSCAN_RETURN_IF_ERROR(requested.Check());
  if (m.streaming) return FailedPreconditionError(m.Name() + ": Configure while streaming");
  if (requested.triggered) {
    return InvalidArgumentError(m.Name() + ": UVC webcams have no trigger input (use free-running timing)");
  }
  if (!requested.exposure_cycle_us.empty()) {
    return InvalidArgumentError(m.Name() + ": exposure cycles need a trigger input (UVC webcams have none)");
  }
  if (requested.white_balance) {
    return InvalidArgumentError(m.Name() + ": white balance as RGB gains is not a UVC control; use the option "
                                           "wb_temperature=K (auto white balance is always turned off)");
  }
  if (requested.gain_db != 0.0) {
    return InvalidArgumentError(m.Name() + ": UVC gain has no unit (not dB); use the option gain=N");
  }
  m.FreeBuffers();
  m.configured = false;

  // Format and size.
  const auto formats = m.Formats();
  auto has = [&](uint32_t f) { return std::find(formats.begin(), formats.end(), f) != formats.end(); };
  auto offers = [&](uint32_t f, int w, int h) {
    if (!has(f)) return false;
    if (w == 0) return true;
    for (const auto& s : m.Sizes(f)) {
      if (s.first == w && s.second == h) return true;
    }
    return false;
  };
  const auto format_option = OptionValue(m.options, "format");
  uint32_t fourcc = 0;
  if (format_option) {
    if (*format_option == "mjpeg") {
      fourcc = V4L2_PIX_FMT_MJPEG;
    } else if (*format_option == "yuyv") {
      fourcc = V4L2_PIX_FMT_YUYV;
    } else {
      return InvalidArgumentError("v4l2 option format=" + *format_option + ": mjpeg or yuyv");
    }
    if (!has(fourcc)) return InvalidArgumentError(m.Name() + " does not offer " + FourccName(fourcc));
  } else if (offers(V4L2_PIX_FMT_YUYV, requested.width, requested.height)) {
    fourcc = V4L2_PIX_FMT_YUYV;
  } else if (has(V4L2_PIX_FMT_MJPEG)) {
    fourcc = V4L2_PIX_FMT_MJPEG;
  } else if (has(V4L2_PIX_FMT_YUYV)) {
    fourcc = V4L2_PIX_FMT_YUYV;
  } else {
    std::string list;
    for (uint32_t f : formats) list += " " + FourccName(f);
    return InvalidArgumentError(m.Name() + " offers neither MJPEG nor YUYV (it offers" + list + ")");
  }
  int width = requested.width, height = requested.height;
  if (width == 0) {
    for (const auto& s : m.Sizes(fourcc)) {
      if (int64_t{s.first} * s.second > int64_t{width} * height) {
        width = s.first;
        height = s.second;
      }
    }
    if (width == 0) return DeviceError(m.Name() + ": lists no frame size for " + FourccName(fourcc));
  }
  v4l2_format fmt{};
  fmt.type = V4L2_BUF_TYPE_VIDEO_CAPTURE;
  fmt.fmt.pix.width = static_cast<uint32_t>(width);
  fmt.fmt.pix.height = static_cast<uint32_t>(height);
  fmt.fmt.pix.pixelformat = fourcc;
  fmt.fmt.pix.field = V4L2_FIELD_NONE;
  if (Xioctl(m.fd, VIDIOC_S_FMT, &fmt) == -1) return DeviceError(m.Name() + ": VIDIOC_S_FMT: " + Errno());
  if (fmt.fmt.pix.pixelformat != fourcc || static_cast<int>(fmt.fmt.pix.width) != width ||
      static_cast<int>(fmt.fmt.pix.height) != height) {
    return InvalidArgumentError(m.Name() + ": asked for " + FourccName(fourcc) + " " + std::to_string(width) + "x" +
                                std::to_string(height) + ", the driver gives " +
                                FourccName(fmt.fmt.pix.pixelformat) + " " + std::to_string(fmt.fmt.pix.width) + "x" +
                                std::to_string(fmt.fmt.pix.height));
  }
  m.fourcc = fourcc;
  m.bytes_per_line = static_cast<int>(fmt.fmt.pix.bytesperline);
  m.image_size = fmt.fmt.pix.sizeimage;
  if (m.image_size == 0) m.image_size = static_cast<size_t>(width) * static_cast<size_t>(height) * 2;

  // Frame rate.
  CameraSettings got = requested;
  got.width = width;
  got.height = height;
  v4l2_streamparm parm{};
  parm.type = V4L2_BUF_TYPE_VIDEO_CAPTURE;
  parm.parm.capture.timeperframe.numerator = 1000;
  parm.parm.capture.timeperframe.denominator = static_cast<uint32_t>(std::lround(requested.frame_rate_hz * 1000.0));
  if (Xioctl(m.fd, VIDIOC_S_PARM, &parm) == 0 && parm.parm.capture.timeperframe.numerator > 0 &&
      parm.parm.capture.timeperframe.denominator > 0) {
    got.frame_rate_hz = static_cast<double>(parm.parm.capture.timeperframe.denominator) /
                        parm.parm.capture.timeperframe.numerator;
  } else {
    ROTOSCAN_LOG(kWarning) << m.Name() << ": cannot set the frame rate (VIDIOC_S_PARM); assuming "
                           << requested.frame_rate_hz << " frames/s";
  }
  m.frame_period_us = std::lround(1e6 / got.frame_rate_hz);

  // Exposure: manual (V4L2_EXPOSURE_MANUAL), in units of 100 us; a frame rate the camera holds (auto
  // priority off, else it may lower the rate in the dark).
  const ControlSpec auto_exposure{V4L2_CID_EXPOSURE_AUTO, "V4L2_CID_EXPOSURE_AUTO (auto exposure)"};
  const ControlSpec exposure{V4L2_CID_EXPOSURE_ABSOLUTE, "V4L2_CID_EXPOSURE_ABSOLUTE (exposure time)"};
  ROTOSCAN_RETURN_IF_ERROR(m.SetAndCheck(auto_exposure, V4L2_EXPOSURE_MANUAL));
  if (m.HasControl(V4L2_CID_EXPOSURE_AUTO_PRIORITY)) {
    ROTOSCAN_RETURN_IF_ERROR(m.SetAndCheck({V4L2_CID_EXPOSURE_AUTO_PRIORITY, "V4L2_CID_EXPOSURE_AUTO_PRIORITY"}, 0));
  }
  const int32_t exposure_units = static_cast<int32_t>(std::max<int64_t>(1, (requested.exposure_us + 50) / 100));
  ROTOSCAN_RETURN_IF_ERROR(m.SetAndCheck(exposure, exposure_units));
  got.exposure_us = int64_t{exposure_units} * 100;

  // Gain, in the camera's units.
  const ControlSpec gain{V4L2_CID_GAIN, "V4L2_CID_GAIN (gain)"};
  if (m.HasControl(V4L2_CID_AUTOGAIN)) {
    ROTOSCAN_RETURN_IF_ERROR(m.SetAndCheck({V4L2_CID_AUTOGAIN, "V4L2_CID_AUTOGAIN (auto gain)"}, 0));
  }
  ROTOSCAN_ASSIGN_OR_RETURN(const int32_t gain_default, m.DefaultOf(gain));
  ROTOSCAN_ASSIGN_OR_RETURN(const int64_t gain_value, IntOption(m.options, "gain", gain_default, INT32_MIN, INT32_MAX));
  ROTOSCAN_RETURN_IF_ERROR(m.SetAndCheck(gain, static_cast<int32_t>(gain_value)));

  // White balance: auto off, a fixed temperature.
  const ControlSpec auto_wb{V4L2_CID_AUTO_WHITE_BALANCE, "V4L2_CID_AUTO_WHITE_BALANCE (auto white balance)"};
  const ControlSpec wb{V4L2_CID_WHITE_BALANCE_TEMPERATURE, "V4L2_CID_WHITE_BALANCE_TEMPERATURE (white balance)"};
  ROTOSCAN_RETURN_IF_ERROR(m.SetAndCheck(auto_wb, 0));
  ROTOSCAN_ASSIGN_OR_RETURN(const int32_t wb_default, m.DefaultOf(wb));
  ROTOSCAN_ASSIGN_OR_RETURN(const int64_t wb_value, IntOption(m.options, "wb_temperature", wb_default, 1000, 20000));
  ROTOSCAN_RETURN_IF_ERROR(m.SetAndCheck(wb, static_cast<int32_t>(wb_value)));

  // Rolling shutter readout (file comment).
  m.caps.readout_us = m.readout_option.value_or(m.frame_period_us);
  m.caps.timestamp_uncertainty_us = m.frame_period_us;
  if (!m.readout_option) {
    ROTOSCAN_LOG(kWarning) << m.Name() << ": rolling-shutter readout time unknown; using the frame period ("
                           << m.frame_period_us << " us) as its bound (option readout_us=N to set it)";
  }
  m.settings = got;
  m.previous_exposure_us = got.exposure_us;
  m.exposure_change_us = INT64_MIN / 2;
  m.configured = true;
  return got;
}

Status V4l2Camera::Start() {
  Impl& m = *impl_;
  if (!m.configured) return FailedPreconditionError(m.Name() + ": Start before Configure");
  if (m.streaming) return Status();
  ROTOSCAN_RETURN_IF_ERROR(m.AllocateBuffers());
  for (uint32_t i = 0; i < m.buffers.size(); ++i) ROTOSCAN_RETURN_IF_ERROR(m.Queue(i));
  int type = V4L2_BUF_TYPE_VIDEO_CAPTURE;
  if (Xioctl(m.fd, VIDIOC_STREAMON, &type) == -1) return DeviceError(m.Name() + ": VIDIOC_STREAMON: " + Errno());
  m.streaming = true;
  m.sequence = SequenceExtender();
  m.last_id.reset();
  return Status();
}

Status V4l2Camera::Stop() {
  Impl& m = *impl_;
  if (!m.streaming) return Status();
  m.streaming = false;
  int type = V4L2_BUF_TYPE_VIDEO_CAPTURE;
  const bool ok = Xioctl(m.fd, VIDIOC_STREAMOFF, &type) == 0;
  const std::string e = ok ? "" : Errno();
  m.FreeBuffers();
  if (!ok) return DeviceError(m.Name() + ": VIDIOC_STREAMOFF: " + e);
  return Status();
}

Status V4l2Camera::SetExposure(int64_t exposure_us) {
  Impl& m = *impl_;
  if (!m.configured) return FailedPreconditionError(m.Name() + ": SetExposure before Configure");
  if (exposure_us <= 0) return InvalidArgumentError("exposure must be positive");
  const int32_t units = static_cast<int32_t>(std::max<int64_t>(1, (exposure_us + 50) / 100));
  ROTOSCAN_RETURN_IF_ERROR(
      m.SetAndCheck({V4L2_CID_EXPOSURE_ABSOLUTE, "V4L2_CID_EXPOSURE_ABSOLUTE (exposure time)"}, units));
  m.previous_exposure_us = m.settings.exposure_us;
  m.settings.exposure_us = int64_t{units} * 100;
  m.exposure_change_us = MonotonicNowUs();
  return Status();
}

Result<std::optional<Frame>> V4l2Camera::NextFrame(int64_t timeout_us) {
  Impl& m = *impl_;
  if (!m.streaming) return FailedPreconditionError(m.Name() + ": NextFrame while not streaming");
  const int64_t deadline = MonotonicNowUs() + std::max<int64_t>(0, timeout_us);
  for (;;) {
    v4l2_buffer b{};
    b.type = V4L2_BUF_TYPE_VIDEO_CAPTURE;
    b.memory = m.userptr ? V4L2_MEMORY_USERPTR : V4L2_MEMORY_MMAP;
    if (Xioctl(m.fd, VIDIOC_DQBUF, &b) == 0) {
      if (b.index >= m.buffers.size()) return DeviceError(m.Name() + ": VIDIOC_DQBUF gave an unknown buffer");
      std::optional<Frame> frame = m.Decode(b);
      ROTOSCAN_RETURN_IF_ERROR(m.Queue(b.index));
      if (frame) return frame;
      continue;  // a dropped frame: wait for the next one
    }
    if (errno != EAGAIN) {
      const int e = errno;
      return DeviceError(m.Name() + ": VIDIOC_DQBUF: " + std::strerror(e) +
                         (e == ENODEV ? " (the camera was unplugged)" : ""));
    }
    const int64_t left = deadline - MonotonicNowUs();
    if (left <= 0) return std::optional<Frame>();
    pollfd p{};
    p.fd = m.fd;
    p.events = POLLIN;
    const int r = poll(&p, 1, static_cast<int>(std::min<int64_t>((left + 999) / 1000, 1000)));
    if (r < 0 && errno != EINTR) return DeviceError(m.Name() + ": poll: " + Errno());
    if (r > 0 && (p.revents & (POLLERR | POLLHUP | POLLNVAL)) && !(p.revents & POLLIN)) {
      return DeviceError(m.Name() + ": the device reports an error (unplugged?)");
    }
  }
}

// ---------------------------------------------------------------------------------------------------
// Listing

Result<std::vector<DeviceListing>> ListV4l2Cameras() {
  std::vector<std::string> nodes;
  DIR* dir = opendir("/dev");
  if (dir == nullptr) return IoError(std::string("v4l2: cannot list /dev: ") + std::strerror(errno));
  while (const dirent* e = readdir(dir)) {
    if (std::strncmp(e->d_name, "video", 5) == 0) nodes.push_back(std::string("/dev/") + e->d_name);
  }
  closedir(dir);
  std::sort(nodes.begin(), nodes.end(), [](const std::string& a, const std::string& b) {
    return a.size() != b.size() ? a.size() < b.size() : a < b;  // video2 before video10
  });
  std::vector<DeviceListing> out;
  for (const std::string& node : nodes) {
    const int fd = open(node.c_str(), O_RDWR | O_NONBLOCK | O_CLOEXEC);
    if (fd < 0) {
      ROTOSCAN_LOG(kDebug) << "v4l2: cannot open " << node << ": " << Errno();
      continue;
    }
    v4l2_capability cap{};
    if (Xioctl(fd, VIDIOC_QUERYCAP, &cap) == -1) {
      close(fd);
      continue;
    }
    const uint32_t caps = (cap.capabilities & V4L2_CAP_DEVICE_CAPS) ? cap.device_caps : cap.capabilities;
    if (!(caps & V4L2_CAP_VIDEO_CAPTURE)) {
      close(fd);
      continue;
    }
    std::string description = std::string(reinterpret_cast<const char*>(cap.card)) + " (" +
                              reinterpret_cast<const char*>(cap.driver) + ")";
    for (uint32_t i = 0; i < 64; ++i) {
      v4l2_fmtdesc f{};
      f.index = i;
      f.type = V4L2_BUF_TYPE_VIDEO_CAPTURE;
      if (Xioctl(fd, VIDIOC_ENUM_FMT, &f) == -1) break;
      description += (i == 0 ? ": " : "; ") + FourccName(f.pixelformat);
      for (uint32_t j = 0; j < 64; ++j) {
        v4l2_frmsizeenum s{};
        s.index = j;
        s.pixel_format = f.pixelformat;
        if (Xioctl(fd, VIDIOC_ENUM_FRAMESIZES, &s) == -1) break;
        if (s.type != V4L2_FRMSIZE_TYPE_DISCRETE) {
          description += " up to " + std::to_string(s.stepwise.max_width) + "x" + std::to_string(s.stepwise.max_height);
          break;
        }
        description += " " + std::to_string(s.discrete.width) + "x" + std::to_string(s.discrete.height);
      }
    }
    close(fd);
    out.push_back({"v4l2:" + node, description});
  }
  return out;
}

void RegisterCaptureBackend_v4l2(BackendRegistry* registry) {
  CameraBackend b;
  b.name = "v4l2";
  b.description = "UVC webcams and V4L2 capture devices (MJPEG, YUYV), free-running";
  b.open = [](const std::string& argument, const OpenContext& context) -> Result<std::unique_ptr<Camera>> {
    ROTOSCAN_ASSIGN_OR_RETURN(auto camera, V4l2Camera::Open(argument, context));
    return std::unique_ptr<Camera>(std::move(camera));
  };
  b.list = &ListV4l2Cameras;
  registry->AddCamera(std::move(b));
}

}  // namespace rotoscan::capture

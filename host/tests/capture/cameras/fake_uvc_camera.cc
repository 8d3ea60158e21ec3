// See fake_uvc_camera.h. The structures and ioctl numbers are the kernel's (linux/videodev2.h).
#include "fake_uvc_camera.h"

#include <fcntl.h>
#include <unistd.h>

#include <linux/videodev2.h>
#include <umockdev.h>

#include <algorithm>
#include <cerrno>
#include <cstddef>
#include <cstdlib>
#include <cstring>
#include <deque>
#include <map>
#include <mutex>
#include <stdexcept>

#include <opencv2/imgcodecs.hpp>

#include "rotoscan/capture/clock.h"

namespace rotoscan::capture::testing {

namespace {

struct Control {
  uint32_t type;
  int32_t minimum, maximum, step, default_value;
  const char* name;
};

// The controls of a UVC webcam as uvcvideo maps them (ranges of a typical 720p camera).
std::map<uint32_t, Control> UvcControls() {
  return {
      {V4L2_CID_EXPOSURE_AUTO, {V4L2_CTRL_TYPE_MENU, 0, 3, 1, V4L2_EXPOSURE_APERTURE_PRIORITY, "Auto Exposure"}},
      {V4L2_CID_EXPOSURE_ABSOLUTE, {V4L2_CTRL_TYPE_INTEGER, 1, 10000, 1, 166, "Exposure Time, Absolute"}},
      {V4L2_CID_EXPOSURE_AUTO_PRIORITY, {V4L2_CTRL_TYPE_BOOLEAN, 0, 1, 1, 1, "Exposure, Dynamic Framerate"}},
      {V4L2_CID_GAIN, {V4L2_CTRL_TYPE_INTEGER, 0, 255, 1, 32, "Gain"}},
      {V4L2_CID_AUTO_WHITE_BALANCE, {V4L2_CTRL_TYPE_BOOLEAN, 0, 1, 1, 1, "White Balance, Automatic"}},
      {V4L2_CID_WHITE_BALANCE_TEMPERATURE, {V4L2_CTRL_TYPE_INTEGER, 2800, 6500, 10, 4000, "White Balance Temperature"}},
  };
}

struct QueuedBuffer {
  uint32_t index = 0;
  unsigned long userptr = 0;
  uint32_t length = 0;
};

}  // namespace

struct FakeUvcCamera::Impl {
  Options options;
  UMockdevTestbed* testbed = nullptr;
  UMockdevIoctlBase* handler = nullptr;
  std::string backing;  // the regular file behind the device node

  mutable std::mutex mutex;
  std::map<uint32_t, Control> controls = UvcControls();
  std::map<uint32_t, int32_t> values;
  uint32_t fourcc = 0;
  int width = 0, height = 0;
  uint32_t memory = 0;
  uint32_t buffer_count = 0;
  uint32_t buffer_length = 0;
  std::deque<QueuedBuffer> queued;
  bool streaming = false;
  int64_t t0_us = 0;
  uint32_t next_sequence = 0;
  bool drop_next = false, corrupt_next = false, unplugged = false;
  std::vector<Sent> sent;

  uint32_t SizeImage() const {
    return fourcc == V4L2_PIX_FMT_YUYV ? static_cast<uint32_t>(width * height * 2)
                                       : static_cast<uint32_t>(width * height * 3 + 4096);
  }

  std::vector<uint8_t> Encode(const cv::Mat& bgr) const {
    std::vector<uint8_t> bytes;
    if (fourcc == V4L2_PIX_FMT_MJPEG) {
      cv::imencode(".jpg", bgr, bytes, {cv::IMWRITE_JPEG_QUALITY, 95});
      return bytes;
    }
    // YUYV 4:2:2, BT.601 studio range: Y0 U Y1 V per pixel pair, chroma from the pair's mean.
    bytes.resize(static_cast<size_t>(width) * static_cast<size_t>(height) * 2);
    auto clamp = [](double v) { return static_cast<uint8_t>(std::min(255.0, std::max(0.0, v + 0.5))); };
    for (int y = 0; y < height; ++y) {
      for (int x = 0; x < width; x += 2) {
        double yy[2], u = 0, v = 0;
        for (int k = 0; k < 2; ++k) {
          const cv::Vec3b p = bgr.at<cv::Vec3b>(y, x + k);
          const double b = p[0], g = p[1], r = p[2];
          yy[k] = 16 + (65.481 * r + 128.553 * g + 24.966 * b) / 255.0;
          u += (128 + (-37.797 * r - 74.203 * g + 112.0 * b) / 255.0) / 2;
          v += (128 + (112.0 * r - 93.786 * g - 18.214 * b) / 255.0) / 2;
        }
        uint8_t* o = &bytes[(static_cast<size_t>(y) * static_cast<size_t>(width) + static_cast<size_t>(x)) * 2];
        o[0] = clamp(yy[0]);
        o[1] = clamp(u);
        o[2] = clamp(yy[1]);
        o[3] = clamp(v);
      }
    }
    return bytes;
  }

  static void Complete(UMockdevIoctlClient* client, long result, int error) {
    umockdev_ioctl_client_complete(client, result, error);
  }

  // Resolves the ioctl's argument struct of type T: a local copy synced back on completion.
  template <typename T>
  static UMockdevIoctlData* Arg(UMockdevIoctlClient* client) {
    GError* error = nullptr;
    UMockdevIoctlData* data = umockdev_ioctl_data_resolve(umockdev_ioctl_client_get_arg(client), 0, sizeof(T), &error);
    if (data == nullptr) {
      g_clear_error(&error);
      throw std::runtime_error("umockdev: cannot resolve the ioctl argument");
    }
    return data;
  }
  template <typename T>
  static void Write(UMockdevIoctlData* data, const T& value) {
    T copy = value;
    umockdev_ioctl_data_update(data, 0, reinterpret_cast<guint8*>(&copy), sizeof(T));
  }

  void FillFormat(v4l2_format* f) const {
    f->fmt.pix.width = static_cast<uint32_t>(width);
    f->fmt.pix.height = static_cast<uint32_t>(height);
    f->fmt.pix.pixelformat = fourcc;
    f->fmt.pix.field = V4L2_FIELD_NONE;
    f->fmt.pix.bytesperline = fourcc == V4L2_PIX_FMT_YUYV ? static_cast<uint32_t>(width * 2) : 0;
    f->fmt.pix.sizeimage = SizeImage();
    f->fmt.pix.colorspace = V4L2_COLORSPACE_SRGB;
  }

  std::vector<uint32_t> Formats() const {
    std::vector<uint32_t> f;
    if (options.mjpeg) f.push_back(V4L2_PIX_FMT_MJPEG);
    if (options.yuyv) f.push_back(V4L2_PIX_FMT_YUYV);
    return f;
  }

  gboolean Handle(UMockdevIoctlClient* client) {
    const unsigned long request = umockdev_ioctl_client_get_request(client);
    std::lock_guard<std::mutex> lock(mutex);
    if (unplugged) {
      Complete(client, -1, ENODEV);
      return TRUE;
    }
    switch (request) {
      case VIDIOC_QUERYCAP: {
        UMockdevIoctlData* d = Arg<v4l2_capability>(client);
        v4l2_capability c{};
        std::snprintf(reinterpret_cast<char*>(c.driver), sizeof(c.driver), "uvcvideo");
        std::snprintf(reinterpret_cast<char*>(c.card), sizeof(c.card), "Fake UVC Camera");
        std::snprintf(reinterpret_cast<char*>(c.bus_info), sizeof(c.bus_info), "usb-0000:00:14.0-1");
        c.version = 0x060100;
        c.device_caps = V4L2_CAP_VIDEO_CAPTURE | V4L2_CAP_STREAMING | V4L2_CAP_EXT_PIX_FORMAT;
        c.capabilities = c.device_caps | V4L2_CAP_DEVICE_CAPS;
        Write(d, c);
        g_object_unref(d);
        Complete(client, 0, 0);
        return TRUE;
      }
      case VIDIOC_ENUM_FMT: {
        UMockdevIoctlData* d = Arg<v4l2_fmtdesc>(client);
        v4l2_fmtdesc f = *reinterpret_cast<const v4l2_fmtdesc*>(d->data);
        const auto formats = Formats();
        if (f.type != V4L2_BUF_TYPE_VIDEO_CAPTURE || f.index >= formats.size()) {
          g_object_unref(d);
          Complete(client, -1, EINVAL);
          return TRUE;
        }
        f.pixelformat = formats[f.index];
        f.flags = f.pixelformat == V4L2_PIX_FMT_MJPEG ? V4L2_FMT_FLAG_COMPRESSED : 0;
        std::snprintf(reinterpret_cast<char*>(f.description), sizeof(f.description), "%s",
                      f.pixelformat == V4L2_PIX_FMT_MJPEG ? "Motion-JPEG" : "YUYV 4:2:2");
        Write(d, f);
        g_object_unref(d);
        Complete(client, 0, 0);
        return TRUE;
      }
      case VIDIOC_ENUM_FRAMESIZES: {
        UMockdevIoctlData* d = Arg<v4l2_frmsizeenum>(client);
        v4l2_frmsizeenum s = *reinterpret_cast<const v4l2_frmsizeenum*>(d->data);
        const auto formats = Formats();
        const bool known = std::find(formats.begin(), formats.end(), s.pixel_format) != formats.end();
        if (!known || s.index > 1) {
          g_object_unref(d);
          Complete(client, -1, EINVAL);
          return TRUE;
        }
        s.type = V4L2_FRMSIZE_TYPE_DISCRETE;
        s.discrete.width = static_cast<uint32_t>(s.index == 0 ? options.width : options.width / 2);
        s.discrete.height = static_cast<uint32_t>(s.index == 0 ? options.height : options.height / 2);
        Write(d, s);
        g_object_unref(d);
        Complete(client, 0, 0);
        return TRUE;
      }
      case VIDIOC_G_FMT:
      case VIDIOC_S_FMT:
      case VIDIOC_TRY_FMT: {
        UMockdevIoctlData* d = Arg<v4l2_format>(client);
        v4l2_format f = *reinterpret_cast<const v4l2_format*>(d->data);
        if (f.type != V4L2_BUF_TYPE_VIDEO_CAPTURE || (request != VIDIOC_G_FMT && streaming)) {
          g_object_unref(d);
          Complete(client, -1, streaming ? EBUSY : EINVAL);
          return TRUE;
        }
        if (request != VIDIOC_G_FMT) {
          const auto formats = Formats();
          uint32_t want = f.fmt.pix.pixelformat;
          if (std::find(formats.begin(), formats.end(), want) == formats.end()) want = formats.front();
          int w = options.width, h = options.height;  // the nearest of the two sizes
          if (static_cast<int>(f.fmt.pix.width) <= options.width / 2) {
            w = options.width / 2;
            h = options.height / 2;
          }
          if (request == VIDIOC_S_FMT) {
            fourcc = want;
            width = w;
            height = h;
            FillFormat(&f);
          } else {
            const uint32_t f0 = fourcc;
            const int w0 = width, h0 = height;
            fourcc = want;
            width = w;
            height = h;
            FillFormat(&f);
            fourcc = f0;
            width = w0;
            height = h0;
          }
        } else {
          FillFormat(&f);
        }
        Write(d, f);
        g_object_unref(d);
        Complete(client, 0, 0);
        return TRUE;
      }
      case VIDIOC_G_PARM:
      case VIDIOC_S_PARM: {
        UMockdevIoctlData* d = Arg<v4l2_streamparm>(client);
        v4l2_streamparm p = *reinterpret_cast<const v4l2_streamparm*>(d->data);
        p.parm.capture.capability = V4L2_CAP_TIMEPERFRAME;
        p.parm.capture.timeperframe.numerator = static_cast<uint32_t>(options.frame_period_us);
        p.parm.capture.timeperframe.denominator = 1'000'000;
        Write(d, p);
        g_object_unref(d);
        Complete(client, 0, 0);
        return TRUE;
      }
      case VIDIOC_QUERYCTRL: {
        UMockdevIoctlData* d = Arg<v4l2_queryctrl>(client);
        v4l2_queryctrl q = *reinterpret_cast<const v4l2_queryctrl*>(d->data);
        const auto it = controls.find(q.id);
        if (it == controls.end() || q.id == options.missing_control) {
          g_object_unref(d);
          Complete(client, -1, EINVAL);
          return TRUE;
        }
        q.type = it->second.type;
        q.minimum = it->second.minimum;
        q.maximum = it->second.maximum;
        q.step = it->second.step;
        q.default_value = it->second.default_value;
        q.flags = 0;
        std::snprintf(reinterpret_cast<char*>(q.name), sizeof(q.name), "%s", it->second.name);
        Write(d, q);
        g_object_unref(d);
        Complete(client, 0, 0);
        return TRUE;
      }
      case VIDIOC_G_CTRL:
      case VIDIOC_S_CTRL: {
        UMockdevIoctlData* d = Arg<v4l2_control>(client);
        v4l2_control c = *reinterpret_cast<const v4l2_control*>(d->data);
        const auto it = controls.find(c.id);
        if (it == controls.end() || c.id == options.missing_control) {
          g_object_unref(d);
          Complete(client, -1, EINVAL);
          return TRUE;
        }
        if (request == VIDIOC_S_CTRL) {
          if (c.value < it->second.minimum || c.value > it->second.maximum) {
            g_object_unref(d);
            Complete(client, -1, ERANGE);
            return TRUE;
          }
          if (c.id != options.ignored_control) values[c.id] = c.value;
        } else {
          const auto v = values.find(c.id);
          c.value = v != values.end() ? v->second : it->second.default_value;
          Write(d, c);
        }
        g_object_unref(d);
        Complete(client, 0, 0);
        return TRUE;
      }
      case VIDIOC_REQBUFS: {
        UMockdevIoctlData* d = Arg<v4l2_requestbuffers>(client);
        v4l2_requestbuffers r = *reinterpret_cast<const v4l2_requestbuffers*>(d->data);
        if (r.memory != V4L2_MEMORY_MMAP && r.memory != V4L2_MEMORY_USERPTR) {
          g_object_unref(d);
          Complete(client, -1, EINVAL);
          return TRUE;
        }
        memory = r.memory;
        buffer_count = std::min<uint32_t>(r.count, 8);
        const uint32_t page = static_cast<uint32_t>(sysconf(_SC_PAGESIZE));
        buffer_length = (SizeImage() + page - 1) / page * page;
        queued.clear();
        if (memory == V4L2_MEMORY_MMAP && buffer_count > 0) {
          const int fd = open(backing.c_str(), O_RDWR);
          if (fd < 0 || ftruncate(fd, static_cast<off_t>(buffer_count) * buffer_length) != 0) {
            if (fd >= 0) close(fd);
            g_object_unref(d);
            Complete(client, -1, ENOMEM);
            return TRUE;
          }
          close(fd);
        }
        r.count = buffer_count;
        r.capabilities = V4L2_BUF_CAP_SUPPORTS_MMAP | V4L2_BUF_CAP_SUPPORTS_USERPTR;
        Write(d, r);
        g_object_unref(d);
        Complete(client, 0, 0);
        return TRUE;
      }
      case VIDIOC_QUERYBUF: {
        UMockdevIoctlData* d = Arg<v4l2_buffer>(client);
        v4l2_buffer b = *reinterpret_cast<const v4l2_buffer*>(d->data);
        if (b.index >= buffer_count || memory != V4L2_MEMORY_MMAP) {
          g_object_unref(d);
          Complete(client, -1, EINVAL);
          return TRUE;
        }
        b.length = buffer_length;
        b.m.offset = b.index * buffer_length;
        b.memory = V4L2_MEMORY_MMAP;
        Write(d, b);
        g_object_unref(d);
        Complete(client, 0, 0);
        return TRUE;
      }
      case VIDIOC_QBUF: {
        UMockdevIoctlData* d = Arg<v4l2_buffer>(client);
        const v4l2_buffer b = *reinterpret_cast<const v4l2_buffer*>(d->data);
        g_object_unref(d);
        if (b.index >= buffer_count || b.memory != memory ||
            (memory == V4L2_MEMORY_USERPTR && (b.m.userptr == 0 || b.length < SizeImage()))) {
          Complete(client, -1, EINVAL);
          return TRUE;
        }
        queued.push_back({b.index, memory == V4L2_MEMORY_USERPTR ? b.m.userptr : 0, b.length});
        Complete(client, 0, 0);
        return TRUE;
      }
      case VIDIOC_DQBUF: return Dequeue(client);
      case VIDIOC_STREAMON:
        streaming = true;
        t0_us = MonotonicNowUs();
        next_sequence = 0;
        Complete(client, 0, 0);
        return TRUE;
      case VIDIOC_STREAMOFF:
        streaming = false;
        queued.clear();
        Complete(client, 0, 0);
        return TRUE;
      default: Complete(client, -1, ENOTTY); return TRUE;
    }
  }

  gboolean Dequeue(UMockdevIoctlClient* client) {
    if (!streaming) {
      Complete(client, -1, EINVAL);
      return TRUE;
    }
    if (queued.empty()) {
      Complete(client, -1, EAGAIN);
      return TRUE;
    }
    if (drop_next) {
      drop_next = false;
      ++next_sequence;  // the camera's count goes on: a gap
    }
    const QueuedBuffer q = queued.front();
    queued.pop_front();
    Sent s;
    s.sequence = next_sequence++;
    s.stamp_us = t0_us + static_cast<int64_t>(s.sequence) * options.frame_period_us;
    s.image = MakeImage(width, height, s.sequence);
    std::vector<uint8_t> bytes = Encode(s.image);
    if (corrupt_next && fourcc == V4L2_PIX_FMT_MJPEG) {
      corrupt_next = false;
      s.corrupt = true;
      bytes.resize(bytes.size() / 3);
    }
    if (bytes.size() > buffer_length) bytes.resize(buffer_length);
    s.bytes = bytes;
    sent.push_back(s);

    UMockdevIoctlData* d = Arg<v4l2_buffer>(client);
    v4l2_buffer b = *reinterpret_cast<const v4l2_buffer*>(d->data);
    b.index = q.index;
    b.bytesused = static_cast<uint32_t>(bytes.size());
    b.flags = V4L2_BUF_FLAG_TIMESTAMP_MONOTONIC | V4L2_BUF_FLAG_DONE |
              (options.start_of_exposure ? V4L2_BUF_FLAG_TSTAMP_SRC_SOE : V4L2_BUF_FLAG_TSTAMP_SRC_EOF);
    b.field = V4L2_FIELD_NONE;
    b.timestamp.tv_sec = s.stamp_us / 1'000'000;
    b.timestamp.tv_usec = s.stamp_us % 1'000'000;
    b.sequence = s.sequence;
    b.memory = memory;
    b.length = buffer_length;
    if (memory == V4L2_MEMORY_USERPTR) {
      b.m.userptr = q.userptr;
      Write(d, b);
      GError* error = nullptr;
      UMockdevIoctlData* mem = umockdev_ioctl_data_resolve(d, offsetof(v4l2_buffer, m.userptr), q.length, &error);
      if (mem == nullptr) {
        g_clear_error(&error);
        g_object_unref(d);
        Complete(client, -1, EFAULT);
        return TRUE;
      }
      umockdev_ioctl_data_update(mem, 0, bytes.data(), static_cast<gsize>(bytes.size()));
      g_object_unref(mem);
    } else {
      b.m.offset = q.index * buffer_length;
      const int fd = open(backing.c_str(), O_RDWR);
      const bool ok = fd >= 0 && pwrite(fd, bytes.data(), bytes.size(), static_cast<off_t>(b.m.offset)) ==
                                     static_cast<ssize_t>(bytes.size());
      if (fd >= 0) close(fd);
      if (!ok) {
        g_object_unref(d);
        Complete(client, -1, EIO);
        return TRUE;
      }
      Write(d, b);
    }
    g_object_unref(d);
    Complete(client, 0, 0);
    return TRUE;
  }

  static gboolean OnIoctl(UMockdevIoctlBase*, UMockdevIoctlClient* client, gpointer self) {
    return static_cast<Impl*>(self)->Handle(client);
  }
};

bool FakeUvcCamera::InMockEnvironment() {
  const char* preload = std::getenv("LD_PRELOAD");
  return preload != nullptr && std::string(preload).find("libumockdev-preload") != std::string::npos;
}

cv::Mat FakeUvcCamera::MakeImage(int width, int height, uint32_t sequence) {
  cv::Mat image(height, width, CV_8UC3);
  for (int y = 0; y < height; ++y) {
    for (int x = 0; x < width; ++x) {
      image.at<cv::Vec3b>(y, x) = cv::Vec3b(static_cast<uint8_t>(40 + 2 * y), static_cast<uint8_t>(60 + x),
                                            static_cast<uint8_t>(50 + x + y));
    }
  }
  // A bright red-white column, 4 px wide, at a place given by the sequence number.
  const int column = 4 + static_cast<int>(sequence % static_cast<uint32_t>(std::max(1, width - 12)));
  for (int y = 0; y < height; ++y) {
    for (int x = column; x < column + 4; ++x) image.at<cv::Vec3b>(y, x) = cv::Vec3b(200, 210, 255);
  }
  return image;
}

FakeUvcCamera::FakeUvcCamera(const Options& options) : impl_(new Impl) {
  impl_->options = options;
  impl_->fourcc = options.mjpeg ? V4L2_PIX_FMT_MJPEG : V4L2_PIX_FMT_YUYV;
  impl_->width = options.width;
  impl_->height = options.height;
  impl_->testbed = umockdev_testbed_new();
  impl_->handler = umockdev_ioctl_base_new();
  g_signal_connect(impl_->handler, "handle-ioctl", G_CALLBACK(&Impl::OnIoctl), impl_.get());
  GError* error = nullptr;
  // The socket first, then the node (see host/tests/device/mock_usb_board.cc).
  if (!umockdev_testbed_attach_ioctl(impl_->testbed, options.devnode.c_str(), impl_->handler, &error)) {
    std::string message = error->message;
    g_error_free(error);
    throw std::runtime_error("umockdev: attaching the ioctl handler: " + message);
  }
  // A node with contents ("=00") is a regular file in the testbed (without, umockdev makes a PTY): the
  // client's mmap() of it maps that file, which is where MMAP buffers live.
  const std::string name = options.devnode.substr(std::string("/dev/").size());
  const std::string description = "P: /devices/pci0000:00/0000:00:14.0/usb1/1-1/1-1:1.0/video4linux/" + name +
                                  "\nN: " + name + "=00\nE: DEVNAME=" + options.devnode +
                                  "\nE: SUBSYSTEM=video4linux\nE: MAJOR=81\nE: MINOR=0\n"
                                  "E: ID_V4L_CAPABILITIES=:capture:\nA: dev=81:0\nA: name=Fake UVC Camera\n";
  if (!umockdev_testbed_add_from_string(impl_->testbed, description.c_str(), &error)) {
    std::string message = error->message;
    g_error_free(error);
    throw std::runtime_error("umockdev: adding " + options.devnode + ": " + message);
  }
  gchar* root = umockdev_testbed_get_root_dir(impl_->testbed);
  impl_->backing = std::string(root) + options.devnode;
  g_free(root);
}

FakeUvcCamera::~FakeUvcCamera() {
  g_object_unref(impl_->testbed);
  g_object_unref(impl_->handler);
}

void FakeUvcCamera::DropNextFrame() {
  std::lock_guard<std::mutex> lock(impl_->mutex);
  impl_->drop_next = true;
}

void FakeUvcCamera::CorruptNextFrame() {
  std::lock_guard<std::mutex> lock(impl_->mutex);
  impl_->corrupt_next = true;
}

void FakeUvcCamera::Unplug() {
  std::lock_guard<std::mutex> lock(impl_->mutex);
  impl_->unplugged = true;
}

std::vector<FakeUvcCamera::Sent> FakeUvcCamera::sent() const {
  std::lock_guard<std::mutex> lock(impl_->mutex);
  return impl_->sent;
}

int32_t FakeUvcCamera::control(uint32_t id) const {
  std::lock_guard<std::mutex> lock(impl_->mutex);
  const auto v = impl_->values.find(id);
  if (v != impl_->values.end()) return v->second;
  const auto c = impl_->controls.find(id);
  return c != impl_->controls.end() ? c->second.default_value : 0;
}

std::string FakeUvcCamera::memory() const {
  std::lock_guard<std::mutex> lock(impl_->mutex);
  return impl_->memory == V4L2_MEMORY_USERPTR ? "userptr" : impl_->memory == V4L2_MEMORY_MMAP ? "mmap" : "none";
}

}  // namespace rotoscan::capture::testing

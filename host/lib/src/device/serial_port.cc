// termios implementation of SerialPort (see serial_port.h).
#include "rotoscan/device/serial_port.h"

#include <dirent.h>
#include <fcntl.h>
#include <poll.h>
#include <sys/file.h>
#include <sys/stat.h>
#include <termios.h>
#include <unistd.h>

#include <algorithm>
#include <cerrno>
#include <cstring>
#include <ctime>
#include <map>

#include "rotoscan/core/check.h"

namespace rotoscan::device {

int64_t MonotonicNowUs() {
  timespec ts{};
  clock_gettime(CLOCK_MONOTONIC, &ts);
  return static_cast<int64_t>(ts.tv_sec) * 1'000'000 + ts.tv_nsec / 1000;
}

namespace {

std::string Errno(int e) {
  return std::strerror(e);
}

bool IsGoneErrno(int e) {
  return e == EIO || e == ENXIO || e == ENODEV || e == EBADF || e == EPIPE;
}

speed_t BaudConstant(int baud) {
  switch (baud) {
    case 9600: return B9600;
    case 19200: return B19200;
    case 38400: return B38400;
    case 57600: return B57600;
    case 115200: return B115200;
    case 230400: return B230400;
    default: return 0;
  }
}

int PollTimeoutMs(int64_t deadline_us) {
  const int64_t left = deadline_us - MonotonicNowUs();
  if (left <= 0) return 0;
  return static_cast<int>(std::min<int64_t>((left + 999) / 1000, 1'000'000));
}

}  // namespace

Result<std::unique_ptr<SerialPort>> SerialPort::Open(const std::string& path, int baud) {
  const speed_t speed = BaudConstant(baud);
  if (speed == 0) return InvalidArgumentError("serial port " + path + ": unsupported baud rate " + std::to_string(baud));
  const int fd = ::open(path.c_str(), O_RDWR | O_NOCTTY | O_NONBLOCK | O_CLOEXEC);
  if (fd < 0) {
    const int e = errno;
    if (e == ENOENT) return NotFoundError("serial port " + path + " does not exist (board unplugged?)");
    if (e == EACCES) {
      return DeviceError("opening serial port " + path + ": " + Errno(e) +
                         " (add your user to the 'dialout' group)");
    }
    return DeviceError("opening serial port " + path + ": " + Errno(e));
  }
  if (!isatty(fd)) {
    ::close(fd);
    return DeviceError(path + " is not a serial port (not a tty)");
  }
  if (flock(fd, LOCK_EX | LOCK_NB) != 0) {
    const int e = errno;
    ::close(fd);
    if (e == EWOULDBLOCK) return DeviceError("serial port " + path + " is in use by another program");
    return DeviceError("locking serial port " + path + ": " + Errno(e));
  }
  termios tio{};
  if (tcgetattr(fd, &tio) != 0) {
    const int e = errno;
    ::close(fd);
    return DeviceError("reading the settings of " + path + ": " + Errno(e));
  }
  cfmakeraw(&tio);
  tio.c_cflag &= ~static_cast<tcflag_t>(PARENB | CSTOPB | CSIZE | CRTSCTS);
  tio.c_cflag |= CS8 | CREAD | CLOCAL;
  tio.c_iflag &= ~static_cast<tcflag_t>(IXON | IXOFF | IXANY);
  // VMIN 1 with O_NONBLOCK: read() gives EAGAIN when nothing is there and 0 only at a hang-up (with VMIN 0
  // it would give 0 for "nothing yet" too, and an unplug could not be told apart).
  tio.c_cc[VMIN] = 1;
  tio.c_cc[VTIME] = 0;
  cfsetispeed(&tio, speed);
  cfsetospeed(&tio, speed);
  if (tcsetattr(fd, TCSANOW, &tio) != 0) {
    const int e = errno;
    ::close(fd);
    return DeviceError("configuring " + path + " (" + std::to_string(baud) + " 8N1 raw): " + Errno(e));
  }
  termios check{};
  if (tcgetattr(fd, &check) != 0 || cfgetospeed(&check) != speed || (check.c_cflag & CSIZE) != CS8 ||
      (check.c_cflag & PARENB) != 0 || (check.c_lflag & (ICANON | ECHO)) != 0) {
    ::close(fd);
    return DeviceError(path + " did not keep " + std::to_string(baud) + " 8N1 raw");
  }
  return std::unique_ptr<SerialPort>(new SerialPort(fd, path));
}

SerialPort::~SerialPort() {
  if (fd_ >= 0) ::close(fd_);
}

Status SerialPort::Write(std::string_view bytes, int64_t timeout_us) {
  if (gone_) return DeviceError("serial port " + path_ + " is gone (unplugged?)");
  const int64_t deadline = MonotonicNowUs() + timeout_us;
  size_t sent = 0;
  while (sent < bytes.size()) {
    const ssize_t n = ::write(fd_, bytes.data() + sent, bytes.size() - sent);
    if (n > 0) {
      sent += static_cast<size_t>(n);
      continue;
    }
    const int e = errno;
    if (n < 0 && e == EINTR) continue;
    if (n < 0 && (e == EAGAIN || e == EWOULDBLOCK)) {
      pollfd p{fd_, POLLOUT, 0};
      const int r = ::poll(&p, 1, PollTimeoutMs(deadline));
      if (r == 0) return TimeoutError("serial port " + path_ + ": output did not drain");
      if (r > 0 && (p.revents & (POLLHUP | POLLERR | POLLNVAL)) != 0) {
        gone_ = true;
        return DeviceError("serial port " + path_ + " hung up (unplugged?)");
      }
      continue;
    }
    if (n < 0 && IsGoneErrno(e)) {
      gone_ = true;
      return DeviceError("writing to serial port " + path_ + ": " + Errno(e) + " (unplugged?)");
    }
    return DeviceError("writing to serial port " + path_ + ": " + Errno(e));
  }
  return Status::Ok();
}

Status SerialPort::Fill(int64_t deadline_us) {
  pollfd p{fd_, POLLIN, 0};
  int r = 0;
  do {
    r = ::poll(&p, 1, PollTimeoutMs(deadline_us));
  } while (r < 0 && errno == EINTR);
  if (r < 0) return DeviceError("waiting on serial port " + path_ + ": " + Errno(errno));
  if (r == 0) return Status::Ok();
  const int64_t now = MonotonicNowUs();
  char chunk[512];
  bool got = false;
  for (;;) {
    const ssize_t n = ::read(fd_, chunk, sizeof(chunk));
    if (n > 0) {
      buffer_.append(chunk, static_cast<size_t>(n));
      got = true;
      continue;
    }
    if (n < 0 && errno == EINTR) continue;
    if (n < 0 && (errno == EAGAIN || errno == EWOULDBLOCK)) break;
    // n == 0 (end of file: hung up) or a hard error.
    gone_ = true;
    break;
  }
  if (got) buffer_time_us_ = now;
  if (!got && (p.revents & (POLLHUP | POLLERR | POLLNVAL)) != 0) gone_ = true;
  return Status::Ok();
}

std::optional<SerialLine> SerialPort::PopLine() {
  for (;;) {
    const size_t end = buffer_.find_first_of("\r\n");
    if (end == std::string::npos) return std::nullopt;
    std::string text = buffer_.substr(0, end);
    buffer_.erase(0, end + 1);
    if (!text.empty()) return SerialLine{std::move(text), buffer_time_us_};
  }
}

Result<std::optional<SerialLine>> SerialPort::ReadLine(int64_t deadline_us) {
  for (;;) {
    if (auto line = PopLine()) return std::optional<SerialLine>(std::move(line));
    if (gone_) return DeviceError("serial port " + path_ + " is gone (unplugged?)");
    if (MonotonicNowUs() >= deadline_us) return std::optional<SerialLine>();
    ROTOSCAN_RETURN_IF_ERROR(Fill(deadline_us));
  }
}

void SerialPort::FlushInput() {
  if (!gone_) tcflush(fd_, TCIFLUSH);
  buffer_.clear();
}

bool SerialPort::CheckAlive() {
  if (gone_) return false;
  pollfd p{fd_, POLLIN, 0};
  if (::poll(&p, 1, 0) > 0) {
    if ((p.revents & POLLIN) != 0) {
      (void)Fill(MonotonicNowUs());
    } else if ((p.revents & (POLLHUP | POLLERR | POLLNVAL)) != 0) {
      gone_ = true;
    }
  }
  struct stat st{};
  if (::stat(path_.c_str(), &st) != 0) gone_ = true;  // the device node (or its link) went away
  return !gone_;
}

std::vector<SerialPortInfo> ListSerialPorts() {
  std::map<std::string, std::string> by_id;  // resolved path -> by-id link
  if (DIR* dir = opendir("/dev/serial/by-id")) {
    while (const dirent* e = readdir(dir)) {
      if (e->d_name[0] == '.') continue;
      const std::string link = std::string("/dev/serial/by-id/") + e->d_name;
      char resolved[PATH_MAX];
      if (realpath(link.c_str(), resolved) != nullptr) by_id[resolved] = link;
    }
    closedir(dir);
  }
  std::vector<SerialPortInfo> ports;
  if (DIR* dir = opendir("/dev")) {
    while (const dirent* e = readdir(dir)) {
      const std::string name = e->d_name;
      if (name.rfind("ttyUSB", 0) != 0 && name.rfind("ttyACM", 0) != 0) continue;
      SerialPortInfo info;
      info.path = "/dev/" + name;
      auto it = by_id.find(info.path);
      if (it != by_id.end()) info.by_id = it->second;
      ports.push_back(info);
    }
    closedir(dir);
  }
  std::sort(ports.begin(), ports.end(),
            [](const SerialPortInfo& a, const SerialPortInfo& b) { return a.path < b.path; });
  return ports;
}

}  // namespace rotoscan::device

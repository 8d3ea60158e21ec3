#include "fake_ciclop.h"

#include <fcntl.h>
#include <poll.h>
#include <pty.h>
#include <sys/eventfd.h>
#include <termios.h>
#include <unistd.h>

#include <algorithm>
#include <cerrno>
#include <cmath>
#include <cstdio>
#include <cstdlib>
#include <cstring>
#include <ctime>

namespace rotoscan::device::testing {

namespace {

constexpr int64_t kByteUs = 87;  // 10 bits at 115200 baud = 86.8 us

int64_t NowUs() {
  timespec ts{};
  clock_gettime(CLOCK_MONOTONIC, &ts);
  return static_cast<int64_t>(ts.tv_sec) * 1'000'000 + ts.tv_nsec / 1000;
}

std::string Fixed3(double v) {
  char text[32];
  std::snprintf(text, sizeof(text), "%.3f", v);
  return text;
}

// Distance covered `tau` seconds into a rest-to-rest trapezoid over `d` degrees.
double Travelled(double d, double v, double a, double tau) {
  if (tau <= 0) return 0.0;
  double ta = v / a;
  double da = 0.5 * v * v / a;
  double tc = 0.0;
  if (2 * da > d) {
    ta = std::sqrt(d / a);
    v = a * ta;
    da = 0.5 * d;
  } else {
    tc = (d - 2 * da) / v;
  }
  const double total = 2 * ta + tc;
  if (tau >= total) return d;
  if (tau < ta) return 0.5 * a * tau * tau;
  if (tau < ta + tc) return da + v * (tau - ta);
  const double left = total - tau;
  return d - 0.5 * a * left * left;
}

double Duration(double d, double v, double a) {
  if (d * a >= v * v) return d / v + v / a;
  return 2.0 * std::sqrt(d / a);
}

}  // namespace

FakeCiclop::FakeCiclop(FakeCiclopOptions options) : options_(std::move(options)), rng_(options_.seed) {}

FakeCiclop::~FakeCiclop() {
  {
    std::lock_guard<std::mutex> lock(mutex_);
    stop_ = true;
  }
  Wake();
  if (thread_.joinable()) thread_.join();
  std::lock_guard<std::mutex> lock(mutex_);
  ClosePty();
  if (wake_fd_ >= 0) ::close(wake_fd_);
}

bool FakeCiclop::Start() {
  std::lock_guard<std::mutex> lock(mutex_);
  wake_fd_ = eventfd(0, EFD_NONBLOCK | EFD_CLOEXEC);
  if (wake_fd_ < 0) {
    error_ = std::string("eventfd: ") + std::strerror(errno);
    return false;
  }
  OpenPty();
  if (!plugged_) return false;
  Boot(NowUs(), /*hard=*/true);
  // The board is up before the test opens it: its boot banner is already in the pty.
  thread_ = std::thread([this] { Run(); });
  return true;
}

void FakeCiclop::OpenPty() {
  termios tio{};
  cfmakeraw(&tio);
  cfsetispeed(&tio, B115200);
  cfsetospeed(&tio, B115200);
  char name[256] = {};
  int master = -1;
  int slave = -1;
  if (openpty(&master, &slave, name, &tio, nullptr) != 0) {
    error_ = std::string("openpty: ") + std::strerror(errno);
    return;
  }
  fcntl(master, F_SETFL, fcntl(master, F_GETFL) | O_NONBLOCK);
  fcntl(master, F_SETFD, FD_CLOEXEC);
  fcntl(slave, F_SETFD, FD_CLOEXEC);
  const std::string tmp = options_.link_path + ".new";
  ::unlink(tmp.c_str());
  if (::symlink(name, tmp.c_str()) != 0 || ::rename(tmp.c_str(), options_.link_path.c_str()) != 0) {
    error_ = "linking " + options_.link_path + " to " + name + ": " + std::strerror(errno);
    ::close(master);
    ::close(slave);
    return;
  }
  master_ = master;
  keeper_ = slave;
  plugged_ = true;
  partial_.clear();
}

void FakeCiclop::ClosePty() {
  if (master_ >= 0) ::close(master_);
  if (keeper_ >= 0) ::close(keeper_);
  master_ = keeper_ = -1;
  if (plugged_) ::unlink(options_.link_path.c_str());
  plugged_ = false;
}

void FakeCiclop::Wake() {
  if (wake_fd_ >= 0) {
    const uint64_t one = 1;
    (void)!::write(wake_fd_, &one, sizeof(one));
  }
}

void FakeCiclop::Boot(int64_t now_us, bool hard) {
  StopMotion(now_us);
  const double board_now = PhysicalAt(now_us) - origin_deg_;
  for (int n = 0; n < 2; ++n) {
    if (lasers_[n]) laser_events_.push_back({now_us, n + 1, false});
    lasers_[n] = false;
  }
  feed_ = 0.0;
  agenda_.clear();
  partial_.clear();
  exec_free_us_ = tx_free_us_ = now_us;
  if (hard) {
    motor_ = false;
    origin_deg_ = PhysicalAt(now_us);  // a hard reset counts from 0 where the table stands
    board_target_deg_ = 0.0;
    ++boots_;
  } else {
    board_target_deg_ = board_now;  // GRBL keeps its step count over a soft reset
  }
  const std::string banner = "\r\n" + options_.banner + "\r\n";
  agenda_.emplace(now_us + (hard ? options_.boot_us : 2'000), [this, banner](int64_t) { WriteNow(banner); });
}

double FakeCiclop::PhysicalAt(int64_t t) const {
  double pos = 0.0;
  for (const FakeMove& m : moves_) {
    if (t < m.start_us) break;
    const int64_t until = m.stopped_us >= 0 ? std::min(t, m.stopped_us) : t;
    const double d = std::abs(m.to_deg - m.from_deg);
    const double s = Travelled(d, m.rate, m.accel, static_cast<double>(until - m.start_us) * 1e-6);
    const double whole = std::floor(s * options_.steps_per_deg + 1e-6) / options_.steps_per_deg;
    pos = m.from_deg + (m.to_deg >= m.from_deg ? whole : -whole);
    if (m.stopped_us >= 0 && t >= m.stopped_us) continue;
    if (t < m.end_us) return pos;
  }
  return pos;
}

void FakeCiclop::StopMotion(int64_t now_us) {
  while (!moves_.empty() && moves_.back().stopped_us < 0 && moves_.back().start_us > now_us) moves_.pop_back();
  if (!moves_.empty() && moves_.back().stopped_us < 0 && moves_.back().end_us > now_us) {
    moves_.back().stopped_us = now_us;
  }
  board_target_deg_ = PhysicalAt(now_us) - origin_deg_;
}

namespace {
int64_t EndOf(const FakeMove& m) {
  return m.stopped_us >= 0 ? std::min(m.stopped_us, m.end_us) : m.end_us;
}
}  // namespace

std::string FakeCiclop::StatusReport(int64_t now_us) const {
  const bool running = !moves_.empty() && EndOf(moves_.back()) > now_us;
  const std::string x = Fixed3(PhysicalAt(now_us) - origin_deg_);
  return std::string(running ? "<Run" : "<Idle") + ",MPos:" + x + ",0.000,0.000,WPos:" + x + ",0.000,0.000>";
}

void FakeCiclop::WriteNow(const std::string& text) {
  if (!plugged_) return;
  size_t off = 0;
  while (off < text.size()) {
    const ssize_t n = ::write(master_, text.data() + off, text.size() - off);
    if (n <= 0) return;  // the pty is full or gone: what a real board's TX buffer would lose too
    off += static_cast<size_t>(n);
  }
}

void FakeCiclop::Reply(const std::string& text, int64_t ready_us, bool is_ok) {
  if (is_ok && lose_oks_ > 0) {
    --lose_oks_;
    return;
  }
  std::uniform_int_distribution<int64_t> latency(options_.reply_latency_min_us, options_.reply_latency_max_us);
  const int64_t due = std::max(ready_us + latency(rng_), tx_free_us_);
  const std::string bytes = text + "\r\n";
  tx_free_us_ = due + kByteUs * static_cast<int64_t>(bytes.size());
  agenda_.emplace(due, [this, bytes](int64_t) { WriteNow(bytes); });
}

void FakeCiclop::OnBytes(const char* data, size_t n, int64_t now_us) {
  if (silent_) return;
  for (size_t i = 0; i < n; ++i) {
    const char c = data[i];
    rx_wire_free_us_ = std::max(rx_wire_free_us_, now_us) + kByteUs;
    const int64_t arrived = rx_wire_free_us_;
    if (c == '\x18') {
      partial_.clear();
      agenda_.emplace(arrived, [this](int64_t now) { Boot(now, /*hard=*/false); });
    } else if (c == '?') {
      agenda_.emplace(arrived, [this](int64_t now) { Reply(StatusReport(now), now, false); });
    } else if (c == '\r' || c == '\n') {
      if (partial_.empty()) continue;
      const int64_t run_at = std::max(exec_free_us_, arrived) + options_.exec_delay_us;
      exec_free_us_ = run_at;
      const std::string line = partial_;
      partial_.clear();
      agenda_.emplace(run_at, [this, line](int64_t now) { Execute(line, now); });
    } else if (static_cast<unsigned char>(c) <= ' ') {
      continue;
    } else if (partial_.size() < 80) {  // horus-fw's LINE_BUFFER_SIZE on the ATmega328P
      partial_ += static_cast<char>(c >= 'a' && c <= 'z' ? c - 'a' + 'A' : c);
    }
  }
}

void FakeCiclop::Execute(const std::string& line, int64_t now) {
  lines_.push_back(line);
  auto error = [&](const char* message) { Reply(std::string("error: ") + message, now, false); };
  if (line[0] == '$') {
    if (line == "$G") {
      Reply("[G1 G54 T0 F" + std::to_string(std::llround(feed_ * 60)) + ".]", now, false);
    } else if (line == "$$") {
      Reply("$100=" + Fixed3(options_.steps_per_deg) + " (x, step/deg)", now, false);
      Reply("$110=" + Fixed3(options_.max_rate_deg_per_s) + " (x max rate, deg/sec)", now, false);
      Reply("$120=" + Fixed3(options_.acceleration_deg_per_s2) + " (x accel, deg/sec^2)", now, false);
    } else {
      error("Invalid statement");
      return;
    }
    Reply("ok", now, true);
    return;
  }
  int g = -1;
  int m = -1;
  double f = -1.0;
  double x = 0.0;
  bool has_x = false;
  int t = 0;
  size_t i = 0;
  while (i < line.size()) {
    const char letter = line[i++];
    if (letter < 'A' || letter > 'Z') return error("Expected command letter");
    const char* begin = line.c_str() + i;
    char* stop = nullptr;
    const double value = std::strtod(begin, &stop);
    if (stop == begin) return error("Bad number format");
    i += static_cast<size_t>(stop - begin);
    switch (letter) {
      case 'G':
        if (value != 0 && value != 1 && value != 50) return error("Unsupported command");
        g = static_cast<int>(value);
        break;
      case 'M':
        if (value != 17 && value != 18 && value != 70 && value != 71) return error("Unsupported command");
        m = static_cast<int>(value);
        break;
      case 'F':
        if (value < 0) return error("Value < 0");
        f = value;
        break;
      case 'T':
        if (value < 0) return error("Value < 0");
        t = static_cast<int>(value);
        break;
      case 'X':
        x = value;
        has_x = true;
        break;
      default:
        return error("Unsupported command");
    }
  }
  if (has_x && (f >= 0 ? f : feed_) == 0.0) return error("Undefined feed rate");
  if (f >= 0) feed_ = f;
  if (g == 50) {
    StopMotion(now);
    origin_deg_ = PhysicalAt(now);
    board_target_deg_ = 0.0;
  }
  if (has_x) {
    const double target = std::round(x * options_.steps_per_deg) / options_.steps_per_deg;
    FakeMove move;
    move.start_us = moves_.empty() ? now : std::max(now, EndOf(moves_.back()));
    move.from_deg = origin_deg_ + board_target_deg_;
    move.to_deg = origin_deg_ + target;
    move.rate = std::min(feed_, options_.max_rate_deg_per_s);
    move.accel = options_.acceleration_deg_per_s2;
    move.end_us = move.start_us + static_cast<int64_t>(std::llround(
                                      1e6 * Duration(std::abs(move.to_deg - move.from_deg), move.rate, move.accel)));
    if (move.to_deg != move.from_deg) moves_.push_back(move);
    board_target_deg_ = target;
  }
  if ((m == 70 || m == 71) && (t == 1 || t == 2)) {
    const bool on = m == 71;
    if (lasers_[t - 1] != on) laser_events_.push_back({now, t, on});
    lasers_[t - 1] = on;
  }
  if (m == 17) motor_ = true;
  if (m == 18) motor_ = false;
  Reply("ok", now, true);
}

void FakeCiclop::Run() {
  std::unique_lock<std::mutex> lock(mutex_);
  while (!stop_) {
    int64_t now = NowUs();
    while (!agenda_.empty() && agenda_.begin()->first <= now) {
      auto action = std::move(agenda_.begin()->second);
      agenda_.erase(agenda_.begin());
      action(now);
      now = NowUs();
    }
    const int64_t wait_us = agenda_.empty() ? 100'000 : std::max<int64_t>(agenda_.begin()->first - now, 0);
    pollfd fds[2] = {{wake_fd_, POLLIN, 0}, {plugged_ ? master_ : -1, POLLIN, 0}};
    const int polled_master = master_;
    lock.unlock();
    timespec timeout{static_cast<time_t>(wait_us / 1'000'000), static_cast<long>((wait_us % 1'000'000) * 1000)};
    ::ppoll(fds, 2, &timeout, nullptr);
    lock.lock();
    if (unplug_requested_) {
      ClosePty();
      agenda_.clear();  // answers on their way are lost with the cable
      partial_.clear();
      unplug_requested_ = false;
      unplugged_.notify_all();
      continue;
    }
    if ((fds[0].revents & POLLIN) != 0) {
      uint64_t count = 0;
      (void)!::read(wake_fd_, &count, sizeof(count));
    }
    if (plugged_ && master_ == polled_master && (fds[1].revents & POLLIN) != 0) {
      char buffer[512];
      for (;;) {
        const ssize_t n = ::read(master_, buffer, sizeof(buffer));
        if (n <= 0) break;
        OnBytes(buffer, static_cast<size_t>(n), NowUs());
      }
    }
  }
}

void FakeCiclop::LoseOks(int n) {
  std::lock_guard<std::mutex> lock(mutex_);
  lose_oks_ += n;
}

void FakeCiclop::SendGarbage(const std::string& bytes) {
  std::lock_guard<std::mutex> lock(mutex_);
  WriteNow(bytes);
}

void FakeCiclop::Unplug() {
  // The board's thread closes the pty itself, outside poll(): a file being polled is only released (and
  // the client's side hung up) when poll() returns, so this returns once the client can see the unplug.
  std::unique_lock<std::mutex> lock(mutex_);
  unplug_requested_ = true;
  Wake();
  unplugged_.wait(lock, [this] { return !unplug_requested_; });
}

void FakeCiclop::Replug() {
  {
    std::lock_guard<std::mutex> lock(mutex_);
    OpenPty();
    Boot(NowUs(), /*hard=*/true);  // DTR resets an Arduino-type board when the port is opened again
  }
  Wake();
}

void FakeCiclop::Reboot() {
  {
    std::lock_guard<std::mutex> lock(mutex_);
    Boot(NowUs(), /*hard=*/true);
    agenda_.clear();
    WriteNow("\r\n" + options_.banner + "\r\n");  // at once: the test goes on knowing it is there
  }
  Wake();
}

void FakeCiclop::SetSilent(bool silent) {
  std::lock_guard<std::mutex> lock(mutex_);
  silent_ = silent;
}

std::vector<FakeLaserEvent> FakeCiclop::laser_events() const {
  std::lock_guard<std::mutex> lock(mutex_);
  return laser_events_;
}

bool FakeCiclop::LaserAt(int laser, int64_t time_us) const {
  std::lock_guard<std::mutex> lock(mutex_);
  bool on = false;
  for (const FakeLaserEvent& e : laser_events_) {
    if (e.time_us > time_us) break;
    if (e.laser == laser) on = e.on;
  }
  return on;
}

double FakeCiclop::TableAngleAt(int64_t time_us) const {
  std::lock_guard<std::mutex> lock(mutex_);
  return PhysicalAt(time_us);
}

std::vector<FakeMove> FakeCiclop::moves() const {
  std::lock_guard<std::mutex> lock(mutex_);
  return moves_;
}

std::vector<std::string> FakeCiclop::lines() const {
  std::lock_guard<std::mutex> lock(mutex_);
  return lines_;
}

int FakeCiclop::boots() const {
  std::lock_guard<std::mutex> lock(mutex_);
  return boots_;
}

bool FakeCiclop::motor() const {
  std::lock_guard<std::mutex> lock(mutex_);
  return motor_;
}

}  // namespace rotoscan::device::testing

// CiclopClient: horus-fw's G-code dialect over a SerialPort (see ciclop_client.h for the dialect, the
// timing and the fault handling).
//
// Design notes:
//  * Every line goes through Send(): one try = write, then read lines until "ok" / "error:" / the
//    deadline. Lines that are not the answer (status reports, "[...]" messages, garbage) are skipped; a
//    banner means the board reset under us and is handled like an unplug, because the board has then lost
//    its lasers, motor state, feed rate and position.
//  * The "$G" fence works because horus-fw (like GRBL) executes and answers lines strictly in order from
//    one main loop: once "[G..." and its "ok" are read, no answer to an older line can still be on its way.
//    "?" is not a fence (it is answered from the real-time path, out of line order), so it is only used
//    for the table's state and position.
//  * Angles: the board counts from 0 at its boot (or keeps its count over a soft reset); the client reads
//    MPos after every reset and keeps `offset_deg_` so that the caller's angles stay the same across
//    re-connections.
#include "rotoscan/device/ciclop_client.h"

#include <poll.h>

#include <algorithm>
#include <cmath>
#include <cstdio>
#include <cstdlib>
#include <numeric>

#include "rotoscan/core/check.h"
#include "rotoscan/core/logging.h"

namespace rotoscan::device {

Status CiclopOptions::Check() const {
  if (port.empty()) return InvalidArgumentError("ciclop: empty serial port path");
  if (banner_timeout_us <= 0 || ok_timeout_us <= 0 || reconnect_timeout_us < 0 || reconnect_interval_us <= 0 ||
      status_poll_interval_us <= 0) {
    return InvalidArgumentError("ciclop: timeouts must be > 0");
  }
  if (reset_attempts < 1 || retries < 0) return InvalidArgumentError("ciclop: reset_attempts >= 1, retries >= 0");
  if (!(feed_deg_per_s > 0) || !(acceleration_deg_per_s2 > 0) || !(max_rate_deg_per_s > 0) ||
      !(steps_per_deg > 0)) {
    return InvalidArgumentError("ciclop: feed rate, acceleration, max rate and steps per degree must be > 0");
  }
  return Status::Ok();
}

namespace {

bool StartsWith(const std::string& s, const std::string& prefix) {
  return s.rfind(prefix, 0) == 0;
}

bool IsBanner(const std::string& line) {
  return (StartsWith(line, "Horus ") || StartsWith(line, "Grbl ")) &&
         line.find("['$' for help]") != std::string::npos;
}

bool IsPrintable(const std::string& line) {
  return std::all_of(line.begin(), line.end(),
                     [](char c) { return (c >= 0x20 && c < 0x7f) || c == '\t'; });
}

std::string FormatNumber(double v) {
  char text[32];
  std::snprintf(text, sizeof(text), "%.4f", v);
  std::string s = text;
  while (!s.empty() && s.back() == '0') s.pop_back();
  if (!s.empty() && s.back() == '.') s.pop_back();
  if (s == "-0") s = "0";
  return s;
}

// Parses "<Idle,MPos:1.000,0.000,0.000,WPos:...>" (GRBL 0.9) or "<Idle|MPos:1.000,...|...>" (GRBL 1.1).
std::optional<CiclopStatus> ParseStatus(const SerialLine& line) {
  const std::string& t = line.text;
  if (t.size() < 3 || t.front() != '<' || t.back() != '>') return std::nullopt;
  CiclopStatus status;
  const size_t end = t.find_first_of(",|>", 1);
  status.state = t.substr(1, end - 1);
  const size_t mpos = t.find("MPos:");
  if (mpos == std::string::npos) return std::nullopt;
  const char* begin = t.c_str() + mpos + 5;
  char* stop = nullptr;
  status.board_x_deg = std::strtod(begin, &stop);
  if (stop == begin) return std::nullopt;
  status.time_us = line.time_us;
  return status;
}

}  // namespace

CiclopClient::CiclopClient(CiclopOptions options) : options_(std::move(options)) {
  feed_ = options_.feed_deg_per_s;
  accel_ = options_.acceleration_deg_per_s2;
  max_rate_ = options_.max_rate_deg_per_s;
  steps_per_deg_ = options_.steps_per_deg;
}

CiclopClient::~CiclopClient() {
  Close();
}

Status CiclopClient::Connect() {
  ROTOSCAN_RETURN_IF_ERROR(options_.Check());
  Close();
  ROTOSCAN_RETURN_IF_ERROR(OpenAndReset());
  if (Status settings = ReadSettings(); !settings.ok()) {
    port_.reset();
    return settings;
  }
  in_restore_ = true;
  Status status = [&]() -> Status {
    ROTOSCAN_ASSIGN_OR_RETURN(CiclopStatus st, QueryStatusOnce());
    offset_deg_ = -st.board_x_deg;
    angle_deg_ = 0.0;
    angle_known_ = true;
    move_pending_ = false;
    motor_ = false;
    ROTOSCAN_RETURN_IF_ERROR(Send("G1F" + FormatNumber(feed_), Kind::kIdempotent).status());
    for (int n = 1; n <= 2; ++n) {
      ROTOSCAN_RETURN_IF_ERROR(Send("M70T" + std::to_string(n), Kind::kIdempotent).status());
      lasers_[n - 1] = false;
    }
    return Status::Ok();
  }();
  in_restore_ = false;
  if (!status.ok()) {
    port_.reset();
    return status.WithContext("setting up the Ciclop board on " + options_.port);
  }
  ROTOSCAN_LOG(kInfo) << "Ciclop board on " << options_.port << ": " << banner_ << " (acceleration " << accel_
                      << " deg/s^2, max rate " << max_rate_ << " deg/s, " << steps_per_deg_ << " steps/deg)";
  return Status::Ok();
}

void CiclopClient::Close() {
  if (port_ == nullptr) return;
  if (!port_->gone()) {
    in_restore_ = true;
    for (int n = 1; n <= 2; ++n) {
      if (Send("M70T" + std::to_string(n), Kind::kIdempotent).ok()) lasers_[n - 1] = false;
    }
    if (motor_ && Send("M18", Kind::kIdempotent).ok()) motor_ = false;
    in_restore_ = false;
  }
  port_.reset();
}

Status CiclopClient::OpenAndReset() {
  port_.reset();
  ROTOSCAN_ASSIGN_OR_RETURN(port_, SerialPort::Open(options_.port, options_.baud));
  Status status = ResetBoard();
  if (!status.ok()) port_.reset();
  return status;
}

Status CiclopClient::ResetBoard() {
  Status fence_failed;  // the last attempt's banner came but '$G' was not answered
  for (int attempt = 0; attempt < options_.reset_attempts; ++attempt) {
    port_->FlushInput();
    ROTOSCAN_RETURN_IF_ERROR(port_->Write(std::string(1, '\x18')));
    const int64_t deadline = MonotonicNowUs() + options_.banner_timeout_us;
    for (;;) {
      ROTOSCAN_ASSIGN_OR_RETURN(std::optional<SerialLine> line, ReadBoardLine(deadline));
      if (!line) break;
      if (!IsBanner(line->text)) continue;  // boot noise, answers to an earlier program
      if (!StartsWith(line->text, "Horus ")) {
        return DeviceError("the board on " + options_.port + " is not running horus-fw: it says '" +
                           line->text + "' (flash horus-fw, as Horus does)");
      }
      banner_ = line->text;
      // A board reset by DTR at open and again by Ctrl-X prints two banners: the fence drains both.
      // The banner read may also be an earlier reset's (the board's boot), with our Ctrl-X still being
      // handled: a reset empties the board's receive buffer (GRBL's serial_reset_read_buffer), so '$G'
      // can be lost with it. Then reset again rather than fail (seen with the fake board under load).
      auto fenced = Fence();
      if (fenced.ok()) return Status::Ok();
      if (fenced.status().code() != StatusCode::kTimeout) return fenced.status();
      fence_failed = fenced.status();
      ROTOSCAN_LOG(kDebug) << options_.port << ": " << fence_failed.message() << " after a banner (try "
                           << attempt + 1 << "): resetting again";
      break;
    }
    if (fence_failed.ok()) {
      ROTOSCAN_LOG(kDebug) << options_.port << ": no banner after Ctrl-X (try " << attempt + 1 << ")";
    }
  }
  if (!fence_failed.ok()) return fence_failed;
  return TimeoutError("no banner from the board on " + options_.port + " after " +
                      std::to_string(options_.reset_attempts) + " resets (Ctrl-X), waiting " +
                      std::to_string(options_.banner_timeout_us / 1000) +
                      " ms each: is it a Ciclop board with horus-fw, at " + std::to_string(options_.baud) +
                      " baud?");
}

Status CiclopClient::ReadSettings() {
  ROTOSCAN_RETURN_IF_ERROR(port_->Write("$$\n"));
  const int64_t deadline = MonotonicNowUs() + options_.ok_timeout_us;
  for (;;) {
    ROTOSCAN_ASSIGN_OR_RETURN(std::optional<SerialLine> line, ReadBoardLine(deadline));
    if (!line) {
      ROTOSCAN_LOG(kWarning) << options_.port << ": no answer to '$$': move durations predicted from defaults";
      return Status::Ok();
    }
    const std::string& t = line->text;
    if (t == "ok") return Status::Ok();
    if (StartsWith(t, "error:")) {
      ROTOSCAN_LOG(kWarning) << options_.port << ": '$$' answered '" << t << "': defaults used";
      return Status::Ok();
    }
    int key = 0;
    double value = 0.0;
    if (std::sscanf(t.c_str(), "$%d=%lf", &key, &value) == 2 && value > 0) {
      if (key == 100) steps_per_deg_ = value;
      if (key == 110) max_rate_ = value;
      if (key == 120) accel_ = value;
    }
  }
}

Result<std::optional<SerialLine>> CiclopClient::ReadBoardLine(int64_t deadline_us) {
  Result<std::optional<SerialLine>> line = port_->ReadLine(deadline_us);
  if (line.ok() && line->has_value()) last_contact_us_ = (*line)->time_us;
  return line;
}

Status CiclopClient::HandleStray(const SerialLine& line) {
  const std::string& t = line.text;
  if (IsBanner(t)) {
    return DeviceError("the board on " + options_.port + " reset itself ('" + t + "')");
  }
  if (StartsWith(t, "ALARM")) return DeviceError("the board on " + options_.port + " raised '" + t + "'");
  if (t == "ok" || t.front() == '<' || t.front() == '[') {
    ROTOSCAN_LOG(kDebug) << options_.port << ": stray line '" << t << "'";
    return Status::Ok();
  }
  ++garbage_lines_;
  ROTOSCAN_LOG(kDebug) << options_.port << ": garbage line of " << t.size() << " bytes"
                       << (IsPrintable(t) ? ": '" + t + "'" : std::string());
  return Status::Ok();
}

Result<std::optional<Ack>> CiclopClient::TryOnce(const std::string& line, int64_t sent_us, Kind kind) {
  ROTOSCAN_RETURN_IF_ERROR(port_->Write(line + "\n"));
  if (kind == Kind::kMove) move_pending_ = true;  // from here on the table may turn
  const int64_t deadline = MonotonicNowUs() + options_.ok_timeout_us;
  for (;;) {
    ROTOSCAN_ASSIGN_OR_RETURN(std::optional<SerialLine> answer, ReadBoardLine(deadline));
    if (!answer) return std::optional<Ack>();
    if (answer->text == "ok") {
      Ack ack;
      ack.sent_us = sent_us;
      ack.ok_us = answer->time_us;
      return std::optional<Ack>(ack);
    }
    if (StartsWith(answer->text, "error")) {
      return DeviceError("the board on " + options_.port + " refused '" + line + "': " + answer->text);
    }
    ROTOSCAN_RETURN_IF_ERROR(HandleStray(*answer));
  }
}

Result<std::optional<int64_t>> CiclopClient::Fence() {
  ROTOSCAN_RETURN_IF_ERROR(port_->Write("$G\n"));
  const int64_t deadline = MonotonicNowUs() + options_.ok_timeout_us;
  std::optional<int64_t> late_ok;
  bool state_seen = false;
  for (;;) {
    ROTOSCAN_ASSIGN_OR_RETURN(std::optional<SerialLine> line, ReadBoardLine(deadline));
    if (!line) {
      return TimeoutError("the board on " + options_.port + " does not answer '$G' within " +
                          std::to_string(options_.ok_timeout_us / 1000) + " ms");
    }
    const std::string& t = line->text;
    if (StartsWith(t, "[G")) {
      state_seen = true;
    } else if (t == "ok") {
      if (state_seen) return late_ok;
      if (!late_ok) late_ok = line->time_us;
    } else if (IsBanner(t)) {
      continue;  // a second banner after a reset; Fence() is also how a reset is drained
    } else if (StartsWith(t, "error")) {
      if (!state_seen) continue;  // a late error answer to the pending line: the caller re-sends
      return DeviceError("the board on " + options_.port + " answered '$G' with '" + t + "'");
    } else {
      ROTOSCAN_RETURN_IF_ERROR(HandleStray(*line));
    }
  }
}

Result<CiclopStatus> CiclopClient::QueryStatusOnce() {
  ROTOSCAN_RETURN_IF_ERROR(port_->Write("?"));
  const int64_t deadline = MonotonicNowUs() + options_.ok_timeout_us;
  for (;;) {
    ROTOSCAN_ASSIGN_OR_RETURN(std::optional<SerialLine> line, ReadBoardLine(deadline));
    if (!line) {
      return TimeoutError("the board on " + options_.port + " does not answer the status query '?' within " +
                          std::to_string(options_.ok_timeout_us / 1000) + " ms");
    }
    if (line->text.front() == '<') {
      if (auto status = ParseStatus(*line)) return *status;
      ++garbage_lines_;
      continue;
    }
    ROTOSCAN_RETURN_IF_ERROR(HandleStray(*line));
  }
}

Result<Ack> CiclopClient::Send(const std::string& line, Kind kind, double move_board_from, double move_board_to) {
  if (port_ == nullptr) return FailedPreconditionError("Ciclop board on " + options_.port + " is not connected");
  const double half_step = 0.5 / steps_per_deg_ + 1e-4;
  std::optional<int64_t> first_sent;
  int tries = 0;
  bool reconnected = false;
  for (;;) {
    if (port_ == nullptr || port_->gone()) {
      if (in_restore_) return DeviceError("serial port " + options_.port + " is gone");
      if (reconnected) return DeviceError("the board on " + options_.port + " went away again");
      ROTOSCAN_RETURN_IF_ERROR(Reconnect(MonotonicNowUs()));
      reconnected = true;
      if (kind == Kind::kMove) {
        if (!angle_known_) {
          return DeviceError("the board on " + options_.port + " was lost after '" + line +
                             "' was sent: the table may have moved; its angle is unknown (SetAngle)");
        }
        // The line never left: the caller computes it again in the board's new frame.
        move_not_sent_ = true;
        return DeviceError("the board on " + options_.port + " was re-connected before '" + line + "' was sent");
      }
    }
    const int64_t sent = MonotonicNowUs();
    if (!first_sent) first_sent = sent;
    ++tries;
    Result<std::optional<Ack>> once = TryOnce(line, sent, kind);
    if (!once.ok()) {
      if (port_->gone() || StartsWith(once.status().message(), "the board on " + options_.port + " reset")) {
        if (in_restore_) return once.status();
        if (!port_->gone()) port_.reset();  // a board that reset itself is re-opened like an unplugged one
        continue;
      }
      return once.status();
    }
    if (once->has_value()) {
      Ack ack = **once;
      ack.sent_us = *first_sent;
      ack.tries = tries;
      RecordLatency(ack);
      return ack;
    }
    // No "ok" in time: lost on the way, or the line was lost. Fence to find out.
    ++lost_oks_;
    ROTOSCAN_LOG(kWarning) << options_.port << ": no 'ok' for '" << line << "' within "
                           << options_.ok_timeout_us / 1000 << " ms; resynchronising";
    Result<std::optional<int64_t>> fence = Fence();
    if (!fence.ok()) {
      if (port_->gone()) continue;
      return TimeoutError("the board on " + options_.port + " stopped answering: no 'ok' to '" + line +
                          "' within " + std::to_string(options_.ok_timeout_us / 1000) +
                          " ms, and no answer to '$G' either");
    }
    if (fence->has_value()) {
      Ack ack;
      ack.sent_us = *first_sent;
      ack.ok_us = **fence;
      ack.tries = tries;
      RecordLatency(ack);
      return ack;
    }
    if (tries > options_.retries) {
      return TimeoutError("the board on " + options_.port + " never acknowledged '" + line + "' (" +
                          std::to_string(tries) + " tries)");
    }
    if (kind == Kind::kMove) {
      Result<CiclopStatus> st = QueryStatusOnce();
      if (!st.ok()) {
        if (port_->gone()) continue;
        return st.status();
      }
      if (st->state != "Idle" || std::abs(st->board_x_deg - move_board_to) < half_step) {
        // It ran (the table is turning or there): never send it again.
        Ack ack;
        ack.sent_us = *first_sent;
        ack.ok_us = st->time_us;
        ack.tries = tries;
        RecordLatency(ack);
        return ack;
      }
      if (std::abs(st->board_x_deg - move_board_from) >= half_step) {
        return DeviceError("the board on " + options_.port + " stands at " + FormatNumber(st->board_x_deg) +
                           " deg, neither where '" + line + "' started nor its target");
      }
      ROTOSCAN_LOG(kWarning) << options_.port << ": '" << line
                             << "' did not run (board Idle where it was): sending it again";
    }
  }
}

void CiclopClient::RecordLatency(const Ack& ack) {
  latencies_.push_back(ack.latency_us());
}

LatencyStats CiclopClient::latency() const {
  LatencyStats stats;
  stats.count = static_cast<int>(latencies_.size());
  if (latencies_.empty()) return stats;
  stats.max_us = *std::max_element(latencies_.begin(), latencies_.end());
  stats.min_us = *std::min_element(latencies_.begin(), latencies_.end());
  stats.mean_us = std::accumulate(latencies_.begin(), latencies_.end(), int64_t{0}) / stats.count;
  return stats;
}

Status CiclopClient::Restore() {
  in_restore_ = true;
  Status status = [&]() -> Status {
    ROTOSCAN_RETURN_IF_ERROR(ReadSettings());
    ROTOSCAN_ASSIGN_OR_RETURN(CiclopStatus st, QueryStatusOnce());
    if (move_pending_) {
      angle_known_ = false;
      move_pending_ = false;
      ROTOSCAN_LOG(kError) << options_.port << ": the board went away during a move to " << angle_deg_
                           << " deg: the table angle is unknown";
    }
    offset_deg_ = angle_deg_ - st.board_x_deg;
    ROTOSCAN_RETURN_IF_ERROR(Send("G1F" + FormatNumber(feed_), Kind::kIdempotent).status());
    for (int n = 1; n <= 2; ++n) {
      ROTOSCAN_RETURN_IF_ERROR(Send("M70T" + std::to_string(n), Kind::kIdempotent).status());
      lasers_[n - 1] = false;
    }
    ROTOSCAN_RETURN_IF_ERROR(Send(motor_ ? "M17" : "M18", Kind::kIdempotent).status());
    return Status::Ok();
  }();
  in_restore_ = false;
  return status;
}

Status CiclopClient::Reconnect(int64_t lost_us) {
  ROTOSCAN_LOG(kWarning) << "Ciclop board on " << options_.port << " lost; re-connecting";
  const int64_t contact_before = last_contact_us_;
  const int64_t deadline = MonotonicNowUs() + options_.reconnect_timeout_us;
  Status last;
  for (;;) {
    last = OpenAndReset();
    if (last.ok()) {
      last = Restore();
      if (last.ok()) break;
      port_.reset();
    }
    if (MonotonicNowUs() >= deadline) {
      port_.reset();
      return DeviceError("the Ciclop board on " + options_.port + " went away and did not come back within " +
                         std::to_string(options_.reconnect_timeout_us / 1000) + " ms (" + last.ToString() + ")");
    }
    ::poll(nullptr, 0, static_cast<int>(options_.reconnect_interval_us / 1000));  // wait for the re-plug
  }
  reconnections_.push_back({contact_before, lost_us, MonotonicNowUs()});
  ROTOSCAN_LOG(kWarning) << "Ciclop board on " << options_.port << " back; lasers off, motor "
                         << (motor_ ? "on" : "off") << ", table at " << angle_deg_ << " deg"
                         << (angle_known_ ? "" : " (unknown)");
  return Status::Ok();
}

Result<Ack> CiclopClient::SetLaser(int laser, bool on) {
  ROTOSCAN_CHECK(laser == 1 || laser == 2) << "laser " << laser << " (1 or 2)";
  ROTOSCAN_ASSIGN_OR_RETURN(Ack ack, Send((on ? "M71T" : "M70T") + std::to_string(laser), Kind::kIdempotent));
  lasers_[laser - 1] = on;
  return ack;
}

Result<Ack> CiclopClient::SetMotor(bool on) {
  ROTOSCAN_ASSIGN_OR_RETURN(Ack ack, Send(on ? "M17" : "M18", Kind::kIdempotent));
  motor_ = on;
  return ack;
}

Result<Ack> CiclopClient::SetFeed(double deg_per_s) {
  ROTOSCAN_CHECK(deg_per_s > 0) << "feed rate " << deg_per_s;
  ROTOSCAN_ASSIGN_OR_RETURN(Ack ack, Send("G1F" + FormatNumber(deg_per_s), Kind::kIdempotent));
  feed_ = deg_per_s;
  return ack;
}

Status CiclopClient::SetAngle(double angle_deg) {
  if (port_ == nullptr) return FailedPreconditionError("Ciclop board on " + options_.port + " is not connected");
  ROTOSCAN_ASSIGN_OR_RETURN(CiclopStatus st, QueryStatus());
  offset_deg_ = angle_deg - st.board_x_deg;
  angle_deg_ = angle_deg;
  angle_known_ = true;
  move_pending_ = false;
  return Status::Ok();
}

int64_t CiclopClient::MoveDurationUs(double distance_deg) const {
  const double d = std::abs(distance_deg);
  const double v = std::min(feed_, max_rate_);
  const double a = accel_;
  const double seconds = d * a >= v * v ? d / v + v / a : 2.0 * std::sqrt(d / a);
  return static_cast<int64_t>(std::ceil(seconds * 1e6));
}

Result<MoveAck> CiclopClient::MoveTo(double angle_deg, bool wait) {
  ROTOSCAN_CHECK(std::isfinite(angle_deg)) << "angle " << angle_deg;
  if (!angle_known_) {
    return FailedPreconditionError("the table angle of the Ciclop board on " + options_.port +
                                   " is unknown since it went away during a move: SetAngle() first");
  }
  if (move_pending_) ROTOSCAN_RETURN_IF_ERROR(WaitIdle(options_.reconnect_timeout_us).status());
  MoveAck move;
  move.from_deg = angle_deg_;
  move.to_deg = angle_deg;
  // An unplug seen now is handled before the line is built in the board's frame.
  if (!CheckAlive()) ROTOSCAN_RETURN_IF_ERROR(QueryStatus().status());
  double board_from = angle_deg_ - offset_deg_;
  double board_to = angle_deg - offset_deg_;
  move_not_sent_ = false;
  Result<Ack> ack = Send("G1X" + FormatNumber(board_to), Kind::kMove, board_from, board_to);
  if (!ack.ok() && move_not_sent_) {
    move_not_sent_ = false;
    board_from = angle_deg_ - offset_deg_;
    board_to = angle_deg - offset_deg_;
    ack = Send("G1X" + FormatNumber(board_to), Kind::kMove, board_from, board_to);
  }
  if (!ack.ok()) {
    if (StartsWith(ack.status().message(), "the board on " + options_.port + " refused")) move_pending_ = false;
    return ack.status();
  }
  angle_deg_ = angle_deg;
  move.ack = *ack;
  move.predicted_end_us = ack->ok_us + MoveDurationUs(board_to - board_from);
  if (wait) {
    ROTOSCAN_ASSIGN_OR_RETURN(
        int64_t idle, WaitIdle(std::max<int64_t>(2 * (move.predicted_end_us - MonotonicNowUs()), 0) +
                               options_.reconnect_timeout_us));
    move.idle_us = idle;
  }
  return move;
}

Result<CiclopStatus> CiclopClient::QueryStatus() {
  if (port_ == nullptr) return FailedPreconditionError("Ciclop board on " + options_.port + " is not connected");
  Result<CiclopStatus> st = QueryStatusOnce();
  if (!st.ok() && port_->gone() && !in_restore_) {
    ROTOSCAN_RETURN_IF_ERROR(Reconnect(MonotonicNowUs()));
    return QueryStatusOnce();
  }
  return st;
}

Result<int64_t> CiclopClient::WaitIdle(int64_t timeout_us) {
  if (port_ == nullptr) return FailedPreconditionError("Ciclop board on " + options_.port + " is not connected");
  const double half_step = 0.5 / steps_per_deg_ + 1e-4;
  const int64_t deadline = MonotonicNowUs() + timeout_us;
  for (;;) {
    ROTOSCAN_ASSIGN_OR_RETURN(CiclopStatus st, QueryStatus());
    if (!angle_known_) {
      return DeviceError("the Ciclop board on " + options_.port +
                         " went away during a move: the table angle is unknown (SetAngle)");
    }
    const double target = angle_deg_ - offset_deg_;
    if (st.state == "Idle") {
      if (std::abs(st.board_x_deg - target) < half_step) {
        move_pending_ = false;
        return st.time_us;
      }
      if (!move_pending_) return st.time_us;
      return DeviceError("the Ciclop board on " + options_.port + " stopped at " + FormatNumber(st.board_x_deg) +
                         " deg (board frame) instead of " + FormatNumber(target));
    }
    if (st.state == "Alarm") return DeviceError("the Ciclop board on " + options_.port + " is in alarm");
    if (MonotonicNowUs() >= deadline) {
      return TimeoutError("the Ciclop table did not stop within " + std::to_string(timeout_us / 1000) + " ms");
    }
    // Wait one poll interval, reading (and judging) whatever the board says meanwhile.
    Result<std::optional<SerialLine>> line = ReadBoardLine(MonotonicNowUs() + options_.status_poll_interval_us);
    if (line.ok() && line->has_value()) ROTOSCAN_RETURN_IF_ERROR(HandleStray(**line));
  }
}

Result<Ack> CiclopClient::Command(const std::string& line) {
  ROTOSCAN_CHECK(!line.empty() && line.find_first_of("\r\n") == std::string::npos) << "one line: '" << line << "'";
  return Send(line, Kind::kIdempotent);
}

bool CiclopClient::CheckAlive() {
  return port_ != nullptr && port_->CheckAlive();
}

}  // namespace rotoscan::device

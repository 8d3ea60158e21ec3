#include "rotoscan/capture/scan.h"

#include <algorithm>
#include <cmath>
#include <map>
#include <set>
#include <sstream>

#include "rotoscan/core/logging.h"

namespace rotoscan::capture {
namespace {

constexpr double kPi = 3.14159265358979323846;
constexpr int64_t kKeepAliveUs = 400'000;  // our board's laser safety stops a program after 2 s of silence
constexpr int64_t kScheduleMarginUs = 200;  // after a frame's predicted end, before the next change
constexpr int64_t kLaserSafetyUs = 2'000'000;  // our board's default MotionConfig::laser_timeout_ms
constexpr int64_t kNoFrameUs = 10'000'000;  // triggered: no frame for this long (moves included) is an error
using bundle::LaserState;

uint8_t MaskOf(LaserState s) {
  return s == LaserState::kLeft ? kLaserLeft : s == LaserState::kRight ? kLaserRight : 0;
}

// The shots of a step, in the order they are taken.
std::vector<LaserState> Wanted(const ScanOptions& o, int step) {
  std::vector<LaserState> w;
  if (o.lasers) w = {LaserState::kLeft, LaserState::kRight, LaserState::kOff};
  if (!o.shared_off && o.natural_every > 0 && step % o.natural_every == 0) w.push_back(LaserState::kNatural);
  return w;
}

int64_t ExposureOf(const ScanOptions& o, LaserState s) {
  return s == LaserState::kNatural ? o.natural_exposure_us : o.laser_exposure_us;
}

// The state the scan shares between its parts.
struct Run {
  Board& board;
  Camera& camera;
  Clock& clock;
  const ScanOptions& options;
  bundle::BundleWriter& writer;
  ProgressScope& progress;
  ScanSummary& summary;
  double step_rad = 0.0;
  std::set<std::string> written;  // files written in this run
  std::optional<uint64_t> last_frame_id;
  std::optional<int64_t> last_frame_start;
  double period_sum = 0.0;
  int period_count = 0;

  bool Done(int step, LaserState s) const {
    const std::string file = bundle::FrameFileName(step, s, options.pose);
    return written.count(file) != 0 || writer.HasFrame(file);
  }
  bool StepDone(int step) const {
    for (LaserState s : Wanted(options, step)) {
      if (!Done(step, s)) return false;
    }
    return true;
  }
  // Every frame the camera delivers goes through here (ids, period).
  void Count(const Frame& f) {
    ++summary.frames_captured;
    progress.AdvanceSecondary();  // the bar's frames/s: every frame the camera delivers, used or not
    if (last_frame_id && f.frame_id > *last_frame_id + 1) {
      summary.frames_dropped += static_cast<int>(f.frame_id - *last_frame_id - 1);
    }
    if (last_frame_id && last_frame_start && f.frame_id > *last_frame_id) {
      const double d = static_cast<double>(f.exposure_start_us - *last_frame_start) /
                       static_cast<double>(f.frame_id - *last_frame_id);
      if (d > 0) {
        period_sum += d;
        ++period_count;
      }
    }
    last_frame_id = f.frame_id;
    last_frame_start = f.exposure_start_us;
  }
  Status Write(int step, LaserState s, const Frame& f, uint32_t trigger_seq, uint64_t device_time) {
    bundle::FrameRecord record;
    record.step = step;
    record.table_angle_rad = step * step_rad;
    record.laser = s;
    record.trigger_seq = trigger_seq;
    record.device_time_us = device_time;
    record.exposure_us = static_cast<double>(f.exposure_us);
    record.pose = options.pose;
    ROTOSCAN_RETURN_IF_ERROR(writer.AddFrame(record, f.image));
    written.insert(bundle::FrameFileName(step, s, options.pose));
    ++summary.frames_used;
    if (options.on_frame) {
      CapturedFrame c{step, s, record.table_angle_rad, &f};
      ROTOSCAN_RETURN_IF_ERROR(options.on_frame(c));
    }
    if (StepDone(step)) {
      progress.Advance();
      if (options.on_step_done) options.on_step_done(step);
    }
    return Status::Ok();
  }
  Status CheckCancel() const {
    if (progress.Cancelled()) return CancelledError("scan interrupted; resume it with --resume");
    return Status::Ok();
  }
};

struct Shot {
  int step;
  LaserState laser;
};

// ---- free-running ----

// Puts the board and camera in the state of a shot (table, lasers, exposure); returns the interval in which
// the changes took effect (earliest of the first, latest of the last), or nullopt when nothing changed.
Result<std::optional<BoardChange>> Apply(Run& run, int step, LaserState s, int64_t* exposure) {
  std::optional<BoardChange> all;
  auto add = [&all](const BoardChange& c) {
    if (!all) all = c;
    all->latest_us = std::max(all->latest_us, c.latest_us);
  };
  if (std::abs(run.board.table_angle_rad() - step * run.step_rad) > 1e-9) {
    ROTOSCAN_ASSIGN_OR_RETURN(const BoardChange c, run.board.MoveTo(step * run.step_rad));
    add(c);
  }
  if (run.board.lasers() != MaskOf(s)) {
    ROTOSCAN_ASSIGN_OR_RETURN(const BoardChange c, run.board.SetLasers(MaskOf(s)));
    add(c);
  }
  const int64_t want = ExposureOf(run.options, s);
  if (want != *exposure) {
    BoardChange c;
    c.earliest_us = run.clock.NowUs();
    ROTOSCAN_RETURN_IF_ERROR(run.camera.SetExposure(want));
    c.latest_us = run.clock.NowUs();
    *exposure = want;
    add(c);
  }
  return all;
}

// Frames are judged by their exposure windows; the change to the next shot is scheduled at the predicted
// end of the frame that will serve the current one (from the measured frame period), before that frame
// has even arrived, so that a camera's delivery latency costs no frame. A wrong prediction is seen in the
// windows (the frame is refused and the shot taken again), never trusted.
Status FreeRunning(Run& run) {
  const ScanOptions& o = run.options;
  CameraSettings settings = run.camera.settings();
  settings.triggered = false;
  settings.exposure_cycle_us.clear();
  settings.frame_rate_hz = o.frame_rate_hz;
  settings.exposure_us = o.lasers ? o.laser_exposure_us : o.natural_exposure_us;
  ROTOSCAN_RETURN_IF_ERROR(run.camera.Configure(settings).status());
  const int64_t uncertainty = run.camera.capabilities().timestamp_uncertainty_us;
  const int64_t readout = run.camera.capabilities().readout_us;
  int64_t exposure = settings.exposure_us;
  std::vector<Shot> targets;
  for (int step = 0; step < o.steps; ++step) {
    for (LaserState s : Wanted(o, step)) {
      if (!run.Done(step, s)) targets.push_back({step, s});
    }
  }
  ROTOSCAN_ASSIGN_OR_RETURN(BoardChange first, run.board.SetLasers(0));
  int64_t settled = first.latest_us;  // frames for the current shot must start after this
  ROTOSCAN_RETURN_IF_ERROR(run.camera.Start());
  size_t i = 0;
  if (!targets.empty()) {
    ROTOSCAN_ASSIGN_OR_RETURN(auto c, Apply(run, targets[0].step, targets[0].laser, &exposure));
    if (c) settled = std::max(settled, c->latest_us);
  }
  std::optional<BoardChange> next;  // the change to shot i + 1, issued ahead
  // After a wrong prediction for shot i, the change to shot i + 1 waits for shot i's frame instead: a
  // prediction that keeps failing (a camera whose timestamps or exposure changes lag) must not make the
  // scan go back and forth between two shots for ever.
  bool predict = true;
  while (i < targets.size()) {
    ROTOSCAN_RETURN_IF_ERROR(run.CheckCancel());
    const int64_t period = run.period_count > 0 ? std::llround(run.period_sum / run.period_count) : 0;
    if (predict && !next && i + 1 < targets.size() && period > 0 && run.last_frame_start) {
      // The first frame starting after `settled` serves shot i; it ends at its start + readout + exposure.
      int64_t start = *run.last_frame_start;
      while (start - uncertainty <= settled) start += period;
      const int64_t end = start + readout + exposure + uncertainty + kScheduleMarginUs;
      if (end > run.clock.NowUs()) run.clock.WaitUntilUs(end);
      ROTOSCAN_ASSIGN_OR_RETURN(auto c, Apply(run, targets[i + 1].step, targets[i + 1].laser, &exposure));
      if (!c) c = BoardChange{run.clock.NowUs(), run.clock.NowUs(), 0, 0.0, false};
      next = c;
    }
    ROTOSCAN_ASSIGN_OR_RETURN(auto frame, run.camera.NextFrame(o.frame_timeout_us));
    if (!frame) {
      return TimeoutError("no frame from " + run.camera.Description() + " within " +
                          std::to_string(o.frame_timeout_us / 1000) + " ms");
    }
    run.Count(*frame);
    const Shot& target = targets[i];
    const bool after = frame->exposure_start_us - uncertainty > settled;
    const bool before = !next || frame->ExposureEndUs() + uncertainty < next->earliest_us;
    if (after && before && frame->exposure_us == ExposureOf(o, target.laser)) {
      ROTOSCAN_RETURN_IF_ERROR(run.Write(target.step, target.laser, *frame, 0, frame->device_time_us.value_or(0)));
      ++i;
      predict = true;
      if (next) {
        settled = next->latest_us;
        next.reset();
      } else if (i < targets.size()) {
        ROTOSCAN_ASSIGN_OR_RETURN(auto c, Apply(run, targets[i].step, targets[i].laser, &exposure));
        if (c) settled = std::max(settled, c->latest_us);
      }
      continue;
    }
    ++run.summary.frames_rejected;
    if (next && frame->exposure_start_us + uncertainty >= next->earliest_us) {
      // The change came too early for shot i's frame (a wrong prediction): go back to shot i, and take it
      // without predicting.
      ROTOSCAN_ASSIGN_OR_RETURN(auto c, Apply(run, target.step, target.laser, &exposure));
      if (c) settled = std::max(settled, c->latest_us);
      next.reset();
      predict = false;
    }
  }
  return run.camera.Stop();
}

// ---- hardware-triggered ----

// Runs the loaded program from `first_step` (or a one-step program) and writes the frames it can tie
// to their trigger edges; returns the shots still missing. The program's step i is the scan's step
// i * stride + step_offset (a pass of natural frames every k steps has stride k).
Result<std::vector<Shot>> TriggeredRun(Run& run, const std::vector<LaserState>& shots, int first_step,
                                       int step_count, int step_offset, int stride) {
  const ScanOptions& o = run.options;
  ROTOSCAN_RETURN_IF_ERROR(run.camera.Stop());
  ROTOSCAN_RETURN_IF_ERROR(run.camera.Start());  // the exposure cycle starts again at the first shot
  ROTOSCAN_RETURN_IF_ERROR(run.board.StartProgram(static_cast<uint32_t>(first_step)));
  std::map<uint32_t, TriggerEdge> edges;  // by seq
  std::vector<Frame> frames;
  bool done = false;
  int64_t quiet_since = run.clock.NowUs();
  int64_t last_frame_us = quiet_since, last_edge_us = quiet_since;
  const double period = 1e6 / o.frame_rate_hz;
  const int64_t wait_after_done = static_cast<int64_t>(4 * period) + o.natural_exposure_us + 200'000;
  // Frames and edges are written per step as soon as the step's shots have all been seen.
  std::set<uint32_t> taken;
  std::set<std::pair<int, int>> got;  // (step, shot)
  std::optional<int64_t> previous_d;
  size_t tied = 0;
  // Ties frame `i` to its trigger edge: by time first (the edge on the host clock vs the frame's exposure
  // start), then by sequence: frame id - trigger seq must agree with the previous tied frame's or the next
  // frame's, else the frame is not used (a dropped or extra frame shifts it, a lost event leaves no edge).
  auto candidate = [&](size_t i) -> std::optional<uint32_t> {
    const int64_t t = frames[i].exposure_start_us;
    const TriggerEdge* best = nullptr;
    for (auto it = edges.begin(); it != edges.end(); ++it) {
      const int64_t err = std::llabs(it->second.host_us - t);
      if (err <= o.match_tolerance_us && (best == nullptr || err < std::llabs(best->host_us - t))) best = &it->second;
    }
    if (best == nullptr) return std::nullopt;
    return best->event.trigger_seq;
  };
  auto d_of = [&](size_t i, uint32_t seq) {
    return static_cast<int64_t>(frames[i].frame_id) - static_cast<int64_t>(seq);
  };
  auto tie = [&](size_t i, bool last) -> Status {
    const auto seq = candidate(i);
    if (!seq) {
      ++run.summary.frames_unmatched;
      return Status::Ok();
    }
    const int64_t d = d_of(i, *seq);
    std::optional<uint32_t> next_seq;
    if (!last && i + 1 < frames.size()) next_seq = candidate(i + 1);
    const bool agrees = (previous_d && *previous_d == d) || (next_seq && d_of(i + 1, *next_seq) == d) ||
                        (!previous_d && !next_seq);
    if (!agrees || taken.count(*seq) != 0) {
      ++run.summary.frames_unmatched;
      return Status::Ok();
    }
    const TriggerEdge& edge = edges.at(*seq);
    if (!edge.event.step_index || edge.event.shot >= shots.size()) {
      ++run.summary.frames_unmatched;
      return Status::Ok();
    }
    const int step = static_cast<int>(*edge.event.step_index) * stride + step_offset;
    const LaserState laser = shots[edge.event.shot];
    // The board's own position at the edge must be the step's: an edge of another program (late events
    // after a resume) or a table that is not where the host sent it is never tied to this step.
    const double half_motor_step = 0.5 * run.board.capabilities().degrees_per_step * kPi / 180.0;
    if (edge.event.laser_mask != MaskOf(laser) || frames[i].exposure_us != ExposureOf(o, laser) ||
        std::abs(edge.table_angle_rad - step * run.step_rad) > half_motor_step) {
      ++run.summary.frames_unmatched;
      return Status::Ok();
    }
    previous_d = d;
    taken.insert(*seq);
    got.insert({step, edge.event.shot});
    if (run.Done(step, laser)) return Status::Ok();  // a re-take's shot that was fine the first time
    Status written = run.Write(step, laser, frames[i], *seq, edge.event.time_us);
    frames[i].image.release();  // written: the memory goes back (ids and times stay for the neighbours)
    return written;
  };
  int64_t last_alive = run.clock.NowUs();
  auto keep_alive = [&]() -> Status {
    if (done || run.clock.NowUs() - last_alive <= kKeepAliveUs) return Status::Ok();
    ROTOSCAN_RETURN_IF_ERROR(run.board.KeepAlive());
    last_alive = run.clock.NowUs();
    return Status::Ok();
  };
  int resumes = 0;                     // quiet spells that asked the board to resume
  std::string last_resume = "none";  // and what it answered
  while (true) {
    ROTOSCAN_RETURN_IF_ERROR(run.CheckCancel());
    ROTOSCAN_RETURN_IF_ERROR(keep_alive());
    while (true) {
      bool program_done = false;
      ROTOSCAN_ASSIGN_OR_RETURN(auto edge, run.board.NextTrigger(0, &program_done));
      if (program_done) {
        done = true;
        quiet_since = run.clock.NowUs();
      }
      if (!edge) break;
      last_edge_us = run.clock.NowUs();
      edges[edge->event.trigger_seq] = *edge;
    }
    ROTOSCAN_ASSIGN_OR_RETURN(auto frame, run.camera.NextFrame(2000));
    if (frame) {
      run.Count(*frame);
      frames.push_back(std::move(*frame));
      // Two frames later the edges of a frame and of the next have surely arrived: tie it now, so the
      // bundle, the progress and live processing follow the scan.
      const int64_t busy_from = run.clock.NowUs();
      while (tied + 2 < frames.size()) {
        ROTOSCAN_RETURN_IF_ERROR(tie(tied++, false));
        ROTOSCAN_RETURN_IF_ERROR(keep_alive());
      }
      // The board's and the camera's silence is counted from here, once the host listens again: writing a
      // frame (fsync on a slow or busy disk, on_frame) has taken tens of seconds on a loaded machine, and
      // the frames and edges of that time are waiting, not missing. Counted from before the writing, such a
      // stall ended the scan with "no trigger edge and no frame" (or, once the program was done, left its
      // last frames unread and re-took them) while the board and camera had done their part.
      const int64_t busy_us = run.clock.NowUs() - busy_from;
      if (busy_us > kKeepAliveUs) {
        ROTOSCAN_LOG(kWarning) << "writing frames took " << busy_us / 1000 << " ms (a slow or busy disk?)"
                               << (busy_us > kLaserSafetyUs ? ": the board's laser safety may stop the program; "
                                                              "it is resumed"
                                                            : "");
      }
      quiet_since = last_frame_us = run.clock.NowUs();
    }
    const int expected = (step_count - first_step) * static_cast<int>(shots.size());
    if (done && (static_cast<int>(frames.size()) >= expected || run.clock.NowUs() - quiet_since > wait_after_done)) {
      break;
    }
    // Quiet for several shots: the board's "program done" may have been lost, or the program stopped
    // (laser safety after an unplug), or the table is still on a long move. Ask the board; it restarts the
    // program where it stopped if needed (a running program is left alone).
    if (!done && run.clock.NowUs() - quiet_since > wait_after_done) {
      const int64_t now = run.clock.NowUs();
      if (now - last_frame_us > kNoFrameUs) {
        // Name what the board says it did: a program the board stopped, or one that never raised an edge.
        std::string board = run.board.ProgramDiagnosis();
        if (!board.empty()) board = "; " + board;
        return TimeoutError(std::string(last_edge_us > last_frame_us ? "trigger edges but no frame"
                                                                     : "no trigger edge and no frame") +
                            " for " + std::to_string(kNoFrameUs / 1'000'000) +
                            " s: is the camera's trigger input wired to the board? (program of " +
                            std::to_string(step_count - first_step) + " steps from step " +
                            std::to_string(first_step * stride + step_offset) + "; " + std::to_string(edges.size()) +
                            " edges and " + std::to_string(frames.size()) + " frames heard; last keep-alive " +
                            std::to_string((now - last_alive) / 1000) + " ms ago; " + std::to_string(resumes) +
                            " restarts asked, the last answered: " + last_resume + board + ")");
      }
      ROTOSCAN_ASSIGN_OR_RETURN(const auto resumed, run.board.ResumeProgram());
      ++resumes;
      last_resume = resumed ? "running at step " + std::to_string(*resumed) : std::string("finished");
      ROTOSCAN_LOG(kDebug) << "triggered run quiet for " << (now - quiet_since) / 1000 << " ms: program " << last_resume;
      if (!resumed) done = true;
      quiet_since = run.clock.NowUs();
    }
  }
  for (; tied < frames.size(); ++tied) ROTOSCAN_RETURN_IF_ERROR(tie(tied, tied + 1 == frames.size()));
  std::vector<Shot> missing;
  for (int i = first_step; i < step_count; ++i) {
    const int s = i * stride + step_offset;
    for (size_t k = 0; k < shots.size(); ++k) {
      if (got.count({s, static_cast<int>(k)}) == 0 && !run.Done(s, shots[k])) missing.push_back({s, shots[k]});
    }
  }
  return missing;
}

// One program of a triggered scan: its shots at every `stride`-th step of the scan.
struct Pass {
  std::vector<LaserState> shots;
  int stride = 1;
};

// The passes of a triggered scan: one program with every shot of a step, or, with a natural frame every k
// steps (k > 1), the laser shots at every step and then the natural frames in a second program whose moves
// are k steps long (a board program takes the same shots at each of its steps).
std::vector<Pass> Passes(const ScanOptions& o) {
  if (o.natural_every <= 1 || o.shared_off) return {{Wanted(o, 0), 1}};
  std::vector<Pass> passes;
  if (o.lasers) passes.push_back({{LaserState::kLeft, LaserState::kRight, LaserState::kOff}, 1});
  passes.push_back({{LaserState::kNatural}, o.natural_every});
  return passes;
}

Status TriggeredPass(Run& run, const Pass& pass, double motor_steps) {
  const ScanOptions& o = run.options;
  const double period = 1e6 / o.frame_rate_hz;
  const int count = (o.steps + pass.stride - 1) / pass.stride;  // program steps: scan steps 0, k, 2k, ...
  auto pass_done = [&](int i) {
    for (LaserState s : pass.shots) {
      if (!run.Done(i * pass.stride, s)) return false;
    }
    return true;
  };
  int first = 0;
  while (first < count && pass_done(first)) ++first;
  if (first >= count) return Status::Ok();
  CameraSettings settings = run.camera.settings();
  settings.triggered = true;
  settings.frame_rate_hz = o.frame_rate_hz;
  settings.exposure_us = ExposureOf(o, pass.shots.front());
  settings.exposure_cycle_us.clear();
  for (LaserState s : pass.shots) settings.exposure_cycle_us.push_back(ExposureOf(o, s));
  ROTOSCAN_RETURN_IF_ERROR(run.camera.Stop());
  ROTOSCAN_RETURN_IF_ERROR(run.camera.Configure(settings).status());
  const int64_t readout = run.camera.capabilities().readout_us;
  device::ScanProgram program;
  program.step_count = static_cast<uint32_t>(count);
  program.steps_per_move = static_cast<int32_t>(std::lround(motor_steps)) * pass.stride;
  program.settle_us = o.settle_us;
  program.laser_lead_us = o.laser_lead_us;
  for (LaserState s : pass.shots) {
    // The board waits `window` after each edge: the camera's frame period less the board's own
    // overhead per shot (arm margin + laser lead), and never less than the exposure and readout.
    const double window = std::max(period - 100.0 - o.laser_lead_us,
                                   static_cast<double>(ExposureOf(o, s) + readout + 200));
    program.shots.push_back({MaskOf(s), static_cast<uint32_t>(std::lround(window))});
  }
  ROTOSCAN_RETURN_IF_ERROR(program.Check());
  ROTOSCAN_ASSIGN_OR_RETURN(const BoardChange home, run.board.MoveTo(0.0));
  (void)home;
  ROTOSCAN_RETURN_IF_ERROR(run.board.LoadProgram(program));
  ROTOSCAN_ASSIGN_OR_RETURN(auto missing, TriggeredRun(run, pass.shots, first, count, 0, pass.stride));
  for (int round = 0; round < o.max_retakes && !missing.empty(); ++round) {
    std::set<int> steps;
    for (const Shot& m : missing) steps.insert(m.step);
    ROTOSCAN_LOG(kInfo) << "re-taking " << missing.size() << " shots at " << steps.size() << " steps";
    std::vector<Shot> still;
    for (int step : steps) {
      ROTOSCAN_ASSIGN_OR_RETURN(const BoardChange moved, run.board.MoveTo(step * run.step_rad));
      (void)moved;
      device::ScanProgram one = program;
      one.step_count = 1;
      ROTOSCAN_RETURN_IF_ERROR(run.board.LoadProgram(one));
      const int before = run.summary.frames_used;
      ROTOSCAN_ASSIGN_OR_RETURN(auto left, TriggeredRun(run, pass.shots, 0, 1, step, 1));
      run.summary.shots_retaken += run.summary.frames_used - before;
      still.insert(still.end(), left.begin(), left.end());
    }
    missing = std::move(still);
  }
  if (!missing.empty()) {
    return DeviceError(std::to_string(missing.size()) + " shots still missing after " +
                       std::to_string(o.max_retakes) + " rounds of re-takes (first: step " +
                       std::to_string(missing.front().step) + " " + bundle::LaserStateName(missing.front().laser) + ")");
  }
  return Status::Ok();
}

Status Triggered(Run& run) {
  const double per_step = run.board.capabilities().degrees_per_step * kPi / 180.0;
  const double motor_steps = run.step_rad / per_step;
  if (std::abs(motor_steps - std::round(motor_steps)) > 1e-6 || std::round(motor_steps) < 1) {
    return InvalidArgumentError("a table step of " + std::to_string(run.step_rad * 180 / kPi) +
                                "° is not a whole number of motor steps (" +
                                std::to_string(run.board.capabilities().degrees_per_step) + "° each)");
  }
  for (const Pass& pass : Passes(run.options)) ROTOSCAN_RETURN_IF_ERROR(TriggeredPass(run, pass, motor_steps));
  return run.camera.Stop();
}

// Hands the frames of a resumed bundle to the observers (ScanOptions::replay_resumed), step by step.
Status ReplayResumed(Run& run, const bundle::BundleHeader& header) {
  const ScanOptions& o = run.options;
  bundle::Bundle partial;
  partial.directory = run.writer.working_directory();
  partial.header = header;
  for (int step = 0; step < o.steps; ++step) {
    bool any = false;
    for (LaserState s : Wanted(o, step)) {
      bundle::FrameRecord record;
      record.file = bundle::FrameFileName(step, s, o.pose);
      if (!run.writer.HasFrame(record.file)) continue;
      any = true;
      if (!o.on_frame) continue;
      ROTOSCAN_ASSIGN_OR_RETURN(cv::Mat image, bundle::ReadFrame(partial, record));
      Frame frame;
      frame.image = std::move(image);
      frame.exposure_us = ExposureOf(o, s);
      CapturedFrame c{step, s, step * run.step_rad, &frame, true};
      ROTOSCAN_RETURN_IF_ERROR(o.on_frame(c));
    }
    if (any && run.StepDone(step) && o.on_step_done) o.on_step_done(step);
  }
  return Status::Ok();
}

}  // namespace

const char* TimingName(Timing timing) {
  switch (timing) {
    case Timing::kAuto: return "auto";
    case Timing::kTriggered: return "triggered";
    case Timing::kFreeRunning: return "free-running";
  }
  return "?";
}

Result<Timing> ParseTiming(const std::string& name) {
  for (Timing t : {Timing::kAuto, Timing::kTriggered, Timing::kFreeRunning}) {
    if (name == TimingName(t)) return t;
  }
  return InvalidArgumentError("timing must be auto, triggered or free-running (got '" + name + "')");
}

Status ScanOptions::Check() const {
  if (steps < 1 || steps > 100'000) return InvalidArgumentError("steps must be in 1..100000");
  if (step_deg < 0 || step_deg > 360) return InvalidArgumentError("step must be in [0, 360] degrees");
  if (!(frame_rate_hz > 0 && frame_rate_hz <= 10'000)) return InvalidArgumentError("frame rate out of range");
  if (laser_exposure_us <= 0 || natural_exposure_us <= 0) return InvalidArgumentError("exposures must be positive");
  if (natural_every < 0) return InvalidArgumentError("natural_every must be >= 0");
  if (!lasers && natural_every == 0) return InvalidArgumentError("no frames to take (no lasers, no natural)");
  if (shared_off && !lasers) return InvalidArgumentError("a shared off frame needs the lasers (a scan, not views)");
  if (shared_off && natural_every > 1) {
    return InvalidArgumentError("with a shared off frame every step's off frame is its color frame: "
                                "a natural frame every k steps does not apply");
  }
  if (match_tolerance_us <= 0 || frame_timeout_us <= 0 || max_retakes < 0) {
    return InvalidArgumentError("bad matching or timeout options");
  }
  return Status::Ok();
}

std::string ScanSummary::Summary() const {
  std::ostringstream s;
  s << TimingName(timing) << ": " << steps << " steps";
  if (steps_resumed > 0) s << " (" << steps_resumed << " done before)";
  s << "; frames captured " << frames_captured << ", used " << frames_used << ", rejected " << frames_rejected
    << ", dropped by the camera " << frames_dropped << ", unmatched " << frames_unmatched << ", re-taken "
    << shots_retaken << "; lost events " << lost_events;
  if (frames_time_us > 0) {
    s << "; " << elapsed_us / 1e6 << " s for " << frames_time_us / 1e6 << " s of frames ("
      << static_cast<double>(elapsed_us) / static_cast<double>(frames_time_us) << "x)";
  }
  return s.str();
}

Result<ScanSummary> RunScan(Board& board, Camera& camera, Clock& clock, const std::filesystem::path& out,
                            const ScanOptions& options, Progress* progress) {
  ROTOSCAN_RETURN_IF_ERROR(options.Check());
  ScanSummary summary;
  summary.steps = options.steps;
  Timing timing = options.timing;
  const bool can_trigger = board.capabilities().trigger_output && camera.capabilities().trigger_input;
  if (timing == Timing::kAuto) timing = can_trigger ? Timing::kTriggered : Timing::kFreeRunning;
  if (timing == Timing::kTriggered && !can_trigger) {
    return InvalidArgumentError("hardware triggering needs a board with a trigger output and a camera with a "
                                "trigger input (" + board.Description() + ", " + camera.Description() + ")");
  }
  summary.timing = timing;
  bundle::BundleHeader header = options.header;
  if (options.shared_off) {
    header.shared_off_frame = true;
    header.format_version = std::max(header.format_version, 2);
    header.camera.natural_exposure_us = static_cast<double>(options.laser_exposure_us);  // the color frame's
  }
  const double step_deg = options.step_deg > 0 ? options.step_deg : 360.0 / options.steps;
  header.table_step_rad = step_deg * kPi / 180.0;
  bundle::BundleWriter::Options writer_options;
  writer_options.resume = options.resume;
  writer_options.overwrite = options.overwrite;
  ROTOSCAN_ASSIGN_OR_RETURN(auto writer, bundle::BundleWriter::Create(out, header, writer_options));
  ProgressScope scope(progress, "scan", static_cast<uint64_t>(options.steps));
  scope.SetUnits(options.lasers ? "steps" : "views", "frames");
  Run run{board, camera, clock, options, *writer, scope, summary, header.table_step_rad, {}, {}, {}, 0.0, 0};
  for (int s = 0; s < options.steps; ++s) {
    if (run.StepDone(s)) {
      ++summary.steps_resumed;
      scope.Advance();
    }
  }
  if (options.resume && options.replay_resumed && writer->resumed_frame_count() > 0) {
    ROTOSCAN_RETURN_IF_ERROR(ReplayResumed(run, header));
  }
  const int64_t start = clock.NowUs();
  Status status = board.EnableMotor(true);
  if (status.ok()) status = timing == Timing::kTriggered ? Triggered(run) : FreeRunning(run);
  summary.elapsed_us = clock.NowUs() - start;
  summary.lost_events = board.lost_events();
  if (run.period_count > 0) summary.measured_frame_period_us = run.period_sum / run.period_count;
  summary.frames_time_us =
      static_cast<int64_t>(std::llround(summary.frames_used * 1e6 / options.frame_rate_hz));
  const Status shutdown = board.Shutdown();  // lasers off, motor off, whatever happened
  (void)camera.Stop();
  if (!status.ok()) return status;  // the writer keeps the partial bundle for --resume
  if (!shutdown.ok()) {
    ROTOSCAN_LOG(kWarning) << "board shutdown: " << shutdown.message();
  }
  ROTOSCAN_RETURN_IF_ERROR(writer->Finish());
  summary.bundle = writer->final_directory();
  return summary;
}

}  // namespace rotoscan::capture

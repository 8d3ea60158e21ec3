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
using bundle::LaserState;

uint8_t MaskOf(LaserState s) {
  return s == LaserState::kLeft ? kLaserLeft : s == LaserState::kRight ? kLaserRight : 0;
}

// The shots of a step, in the order they are taken.
std::vector<LaserState> Wanted(const ScanOptions& o, int step) {
  std::vector<LaserState> w;
  if (o.lasers) w = {LaserState::kLeft, LaserState::kRight, LaserState::kOff};
  if (o.natural_every > 0 && step % o.natural_every == 0) w.push_back(LaserState::kNatural);
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

// ---- free-running ----

Status FreeRunning(Run& run) {
  const ScanOptions& o = run.options;
  CameraSettings settings = run.camera.settings();
  settings.triggered = false;
  settings.exposure_cycle_us.clear();
  settings.frame_rate_hz = o.frame_rate_hz;
  settings.exposure_us = o.lasers ? o.laser_exposure_us : o.natural_exposure_us;
  ROTOSCAN_RETURN_IF_ERROR(run.camera.Configure(settings).status());
  const int64_t uncertainty = run.camera.capabilities().timestamp_uncertainty_us;
  int64_t exposure = settings.exposure_us;
  // The latest time any change may have taken effect: frames must start after it.
  ROTOSCAN_ASSIGN_OR_RETURN(BoardChange change, run.board.SetLasers(0));
  int64_t settled_us = change.latest_us;
  ROTOSCAN_RETURN_IF_ERROR(run.camera.Start());
  for (int step = 0; step < o.steps; ++step) {
    if (run.StepDone(step)) continue;
    ROTOSCAN_RETURN_IF_ERROR(run.CheckCancel());
    if (std::abs(run.board.table_angle_rad() - step * run.step_rad) > 1e-9) {
      ROTOSCAN_ASSIGN_OR_RETURN(change, run.board.MoveTo(step * run.step_rad));
      settled_us = std::max(settled_us, change.latest_us);
    }
    for (LaserState s : Wanted(o, step)) {
      if (run.Done(step, s)) continue;
      if (run.board.lasers() != MaskOf(s)) {
        ROTOSCAN_ASSIGN_OR_RETURN(change, run.board.SetLasers(MaskOf(s)));
        settled_us = std::max(settled_us, change.latest_us);
      }
      const int64_t want_exposure = ExposureOf(o, s);
      if (want_exposure != exposure) {
        ROTOSCAN_RETURN_IF_ERROR(run.camera.SetExposure(want_exposure));
        exposure = want_exposure;
        settled_us = std::max(settled_us, run.clock.NowUs());
      }
      while (true) {
        ROTOSCAN_RETURN_IF_ERROR(run.CheckCancel());
        ROTOSCAN_ASSIGN_OR_RETURN(auto frame, run.camera.NextFrame(o.frame_timeout_us));
        if (!frame) return TimeoutError("no frame from " + run.camera.Description() + " within " +
                                        std::to_string(o.frame_timeout_us / 1000) + " ms");
        run.Count(*frame);
        // The whole exposure window (all rows) must lie after the last change; the next change is only
        // issued after this frame has arrived, so the window also ends before it.
        if (frame->exposure_start_us - uncertainty <= settled_us || frame->exposure_us != want_exposure) {
          ++run.summary.frames_rejected;
          continue;
        }
        ROTOSCAN_RETURN_IF_ERROR(run.Write(step, s, *frame, 0, frame->device_time_us.value_or(0)));
        break;
      }
    }
  }
  return run.camera.Stop();
}

// ---- hardware-triggered ----

struct Shot {
  int step;
  LaserState laser;
};

// Runs the loaded program from `first_step` (or a one-step program) and writes the frames it can tie
// to their trigger edges; returns the shots still missing.
Result<std::vector<Shot>> TriggeredRun(Run& run, const std::vector<LaserState>& shots, int first_step,
                                       int step_count, int step_offset) {
  const ScanOptions& o = run.options;
  ROTOSCAN_RETURN_IF_ERROR(run.camera.Stop());
  ROTOSCAN_RETURN_IF_ERROR(run.camera.Start());  // the exposure cycle starts again at the first shot
  ROTOSCAN_RETURN_IF_ERROR(run.board.StartProgram(static_cast<uint32_t>(first_step)));
  std::map<uint32_t, TriggerEdge> edges;  // by seq
  std::vector<Frame> frames;
  bool done = false;
  int asks = 0;
  int64_t quiet_since = run.clock.NowUs();
  const double period = 1e6 / o.frame_rate_hz;
  const int64_t wait_after_done = static_cast<int64_t>(4 * period) + o.natural_exposure_us + 200'000;
  // Frames and edges are written per step as soon as the step's shots have all been seen.
  while (true) {
    ROTOSCAN_RETURN_IF_ERROR(run.CheckCancel());
    while (true) {
      bool program_done = false;
      ROTOSCAN_ASSIGN_OR_RETURN(auto edge, run.board.NextTrigger(0, &program_done));
      if (program_done) {
        done = true;
        quiet_since = run.clock.NowUs();
      }
      if (!edge) break;
      edges[edge->event.trigger_seq] = *edge;
    }
    ROTOSCAN_ASSIGN_OR_RETURN(auto frame, run.camera.NextFrame(2000));
    if (frame) {
      run.Count(*frame);
      frames.push_back(std::move(*frame));
      quiet_since = run.clock.NowUs();
    }
    const int expected = step_count * static_cast<int>(shots.size());
    if (done && (static_cast<int>(frames.size()) >= expected || run.clock.NowUs() - quiet_since > wait_after_done)) {
      break;
    }
    // Quiet for several shots: the board's "program done" may have been lost, or the program stopped
    // (laser safety after an unplug). Ask the board; it restarts the program where it stopped if needed.
    if (!done && run.clock.NowUs() - quiet_since > wait_after_done) {
      if (++asks > 3) {
        return TimeoutError("no trigger or frame for " + std::to_string(wait_after_done / 1000) +
                            " ms, 3 times: is the camera's trigger input wired to the board?");
      }
      ROTOSCAN_ASSIGN_OR_RETURN(const auto resumed, run.board.ResumeProgram());
      if (!resumed) done = true;
      quiet_since = run.clock.NowUs();
    }
  }
  // Tie frames to edges: by time first (the edge on the host clock vs the frame's exposure start), then
  // by sequence: frame id - trigger seq must agree with a neighbour's, else the frame is not used.
  std::vector<std::pair<size_t, uint32_t>> candidates;  // frame index, seq
  std::vector<TriggerEdge> sorted;
  for (const auto& [seq, e] : edges) sorted.push_back(e);
  std::sort(sorted.begin(), sorted.end(), [](const auto& a, const auto& b) { return a.host_us < b.host_us; });
  for (size_t i = 0; i < frames.size(); ++i) {
    const int64_t t = frames[i].exposure_start_us;
    auto it = std::lower_bound(sorted.begin(), sorted.end(), t - o.match_tolerance_us,
                               [](const TriggerEdge& e, int64_t v) { return e.host_us < v; });
    const TriggerEdge* best = nullptr;
    for (; it != sorted.end() && it->host_us <= t + o.match_tolerance_us; ++it) {
      if (best == nullptr || std::llabs(it->host_us - t) < std::llabs(best->host_us - t)) best = &*it;
    }
    if (best != nullptr) candidates.emplace_back(i, best->event.trigger_seq);
  }
  std::set<uint32_t> taken;
  std::set<std::pair<int, int>> got;  // (step, shot)
  for (size_t k = 0; k < candidates.size(); ++k) {
    const auto [i, seq] = candidates[k];
    const auto d = static_cast<int64_t>(frames[i].frame_id) - static_cast<int64_t>(seq);
    auto d_of = [&](size_t j) {
      return static_cast<int64_t>(frames[candidates[j].first].frame_id) - static_cast<int64_t>(candidates[j].second);
    };
    const bool agrees = (k > 0 && d_of(k - 1) == d) || (k + 1 < candidates.size() && d_of(k + 1) == d) ||
                        candidates.size() == 1;
    if (!agrees || taken.count(seq) != 0) {
      ++run.summary.frames_unmatched;
      continue;
    }
    const TriggerEdge& edge = edges.at(seq);
    if (!edge.event.step_index || edge.event.shot >= shots.size()) {
      ++run.summary.frames_unmatched;
      continue;
    }
    const int step = static_cast<int>(*edge.event.step_index) + step_offset;
    const LaserState laser = shots[edge.event.shot];
    if (edge.event.laser_mask != MaskOf(laser) || frames[i].exposure_us != ExposureOf(o, laser)) {
      ++run.summary.frames_unmatched;
      continue;
    }
    taken.insert(seq);
    got.insert({step, edge.event.shot});
    if (run.Done(step, laser)) continue;  // a re-take's shot that was fine the first time
    ROTOSCAN_RETURN_IF_ERROR(run.Write(step, laser, frames[i], seq, edge.event.time_us));
  }
  run.summary.frames_unmatched += static_cast<int>(frames.size() - candidates.size());
  std::vector<Shot> missing;
  for (int s = first_step + step_offset; s < step_offset + step_count; ++s) {
    for (size_t k = 0; k < shots.size(); ++k) {
      if (got.count({s, static_cast<int>(k)}) == 0 && !run.Done(s, shots[k])) missing.push_back({s, shots[k]});
    }
  }
  return missing;
}

Status Triggered(Run& run) {
  const ScanOptions& o = run.options;
  const double per_step = run.board.capabilities().degrees_per_step * kPi / 180.0;
  const double motor_steps = run.step_rad / per_step;
  if (std::abs(motor_steps - std::round(motor_steps)) > 1e-6 || std::round(motor_steps) < 1) {
    return InvalidArgumentError("a table step of " + std::to_string(run.step_rad * 180 / kPi) +
                                "° is not a whole number of motor steps (" +
                                std::to_string(run.board.capabilities().degrees_per_step) + "° each)");
  }
  if (o.natural_every > 1) {
    return InvalidArgumentError("triggered capture takes the same shots at every step: natural_every must be 0 or 1");
  }
  const std::vector<LaserState> shots = Wanted(o, 0);
  const double period = 1e6 / o.frame_rate_hz;
  CameraSettings settings = run.camera.settings();
  settings.triggered = true;
  settings.frame_rate_hz = o.frame_rate_hz;
  settings.exposure_us = o.laser_exposure_us;
  settings.exposure_cycle_us.clear();
  for (LaserState s : shots) settings.exposure_cycle_us.push_back(ExposureOf(o, s));
  ROTOSCAN_ASSIGN_OR_RETURN(const CameraSettings applied, run.camera.Configure(settings));
  const int64_t readout = run.camera.capabilities().readout_us;
  device::ScanProgram program;
  program.step_count = static_cast<uint32_t>(o.steps);
  program.steps_per_move = static_cast<int32_t>(std::lround(motor_steps));
  program.settle_us = o.settle_us;
  program.laser_lead_us = o.laser_lead_us;
  for (LaserState s : shots) {
    // The board waits `window` after each edge: the camera's frame period less the board's own
    // overhead per shot (arm margin + laser lead), and never less than the exposure and readout.
    const double window = std::max(period - 100.0 - o.laser_lead_us,
                                   static_cast<double>(ExposureOf(o, s) + readout + 200));
    program.shots.push_back({MaskOf(s), static_cast<uint32_t>(std::lround(window))});
  }
  (void)applied;
  ROTOSCAN_RETURN_IF_ERROR(program.Check());
  int first = 0;
  while (first < o.steps && run.StepDone(first)) ++first;
  if (first < o.steps) {
    ROTOSCAN_ASSIGN_OR_RETURN(const BoardChange home, run.board.MoveTo(0.0));
    (void)home;
    ROTOSCAN_RETURN_IF_ERROR(run.board.LoadProgram(program));
    ROTOSCAN_ASSIGN_OR_RETURN(auto missing, TriggeredRun(run, shots, first, o.steps, 0));
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
        ROTOSCAN_ASSIGN_OR_RETURN(auto left, TriggeredRun(run, shots, 0, 1, step));
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
  }
  return run.camera.Stop();
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
  const double step_deg = options.step_deg > 0 ? options.step_deg : 360.0 / options.steps;
  header.table_step_rad = step_deg * kPi / 180.0;
  bundle::BundleWriter::Options writer_options;
  writer_options.resume = options.resume;
  writer_options.overwrite = options.overwrite;
  ROTOSCAN_ASSIGN_OR_RETURN(auto writer, bundle::BundleWriter::Create(out, header, writer_options));
  ProgressScope scope(progress, "scan", static_cast<uint64_t>(options.steps));
  Run run{board, camera, clock, options, *writer, scope, summary, header.table_step_rad, {}, {}, {}, 0.0, 0};
  for (int s = 0; s < options.steps; ++s) {
    if (run.StepDone(s)) {
      ++summary.steps_resumed;
      scope.Advance();
    }
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

// The truth of a simulated rig, as the virtual camera needs it: when each laser was lit, where the table
// stood, and when the trigger line fired, all on the scan's host clock. The sim board provides it from the
// firmware simulator's pin-edge log (firmware/port/sim); tests can provide it for a board in another
// thread (the firmware core behind a mocked USB bus). Tests also use it to check frames against the
// moments lasers really switched.
#pragma once

#include <cstdint>
#include <vector>

namespace rotoscan::capture {

class RigTruth {
 public:
  virtual ~RigTruth() = default;
  // Fractions of [from_us, to_us) during which the left and the right laser were lit (0..1).
  virtual void LaserFractions(int64_t from_us, int64_t to_us, double* left, double* right) = 0;
  // Table angle (radians) at `us`.
  virtual double TableAngleAt(int64_t us) = 0;
  // Rising edges of the camera trigger line in (after_us, until_us], oldest first.
  virtual std::vector<int64_t> TriggerEdges(int64_t after_us, int64_t until_us) = 0;
  // Times any laser output changed level in [from_us, to_us].
  virtual std::vector<int64_t> LaserSwitches(int64_t from_us, int64_t to_us) = 0;
};

}  // namespace rotoscan::capture

#include "rotoscan/capture/board.h"

namespace rotoscan::capture {

namespace {
Status NoTrigger(const Board& board) {
  return UnimplementedError(board.Description() + " cannot trigger a camera in hardware (no scan programs)");
}
}  // namespace

Status Board::LoadProgram(const device::ScanProgram& /*program*/) { return NoTrigger(*this); }
Status Board::StartProgram(uint32_t /*first_step*/) { return NoTrigger(*this); }
Status Board::AbortProgram() { return NoTrigger(*this); }
Result<std::optional<TriggerEdge>> Board::NextTrigger(int64_t /*timeout_us*/, bool* /*program_done*/) {
  return NoTrigger(*this);
}
Result<std::optional<uint32_t>> Board::ResumeProgram() { return NoTrigger(*this); }

}  // namespace rotoscan::capture

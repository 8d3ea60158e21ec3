// In-process implementation of Transport: a VirtualBoard in the same process, in virtual time.
//
// The host clock is virtual too and moves only while Read() waits, in steps of `tick_us` during which the
// board's time moves by the same amount. A test therefore runs the same way every time, and a 30 s scan
// takes as long as the board's main loop needs to compute it.
#include <algorithm>

#include "rotoscan/core/check.h"
#include "rotoscan/device/transport.h"

namespace rotoscan::device {

Status InProcessTransportOptions::Check() const {
  if (tick_us <= 0) return InvalidArgumentError("in-process transport: tick_us must be > 0");
  return Status::Ok();
}

namespace {

class InProcessTransport final : public Transport {
 public:
  InProcessTransport(VirtualBoard* board, const InProcessTransportOptions& options)
      : board_(board), options_(options) {}

  Status Open() override {
    open_ = true;
    return Status::Ok();
  }
  void Close() override { open_ = false; }
  bool IsOpen() const override { return open_; }

  Status Write(const std::vector<uint8_t>& bytes) override {
    if (!open_) return FailedPreconditionError("write to a closed transport");
    board_->Receive(bytes.data(), bytes.size());
    return Status::Ok();
  }

  Status Read(std::vector<uint8_t>* bytes, int64_t timeout_us) override {
    ROTOSCAN_CHECK(bytes != nullptr);
    if (!open_) return FailedPreconditionError("read from a closed transport");
    const int64_t deadline = now_us_ + std::max<int64_t>(timeout_us, 0);
    while (true) {
      uint8_t chunk[512];
      size_t n;
      bool got = false;
      while ((n = board_->Transmit(chunk, sizeof(chunk))) > 0) {
        bytes->insert(bytes->end(), chunk, chunk + n);
        got = true;
      }
      if (got || now_us_ >= deadline) return Status::Ok();
      const int64_t step = std::min(options_.tick_us, deadline - now_us_);
      board_->Advance(step);
      now_us_ += step;
    }
  }

  int64_t NowUs() const override { return now_us_; }
  std::string Description() const override { return "in-process board"; }

 private:
  VirtualBoard* board_;
  InProcessTransportOptions options_;
  bool open_ = false;
  int64_t now_us_ = 0;
};

}  // namespace

std::unique_ptr<Transport> MakeInProcessTransport(VirtualBoard* board,
                                                  const InProcessTransportOptions& options) {
  ROTOSCAN_CHECK(board != nullptr);
  ROTOSCAN_CHECK(options.Check().ok()) << options.Check().ToString();
  return std::make_unique<InProcessTransport>(board, options);
}

}  // namespace rotoscan::device

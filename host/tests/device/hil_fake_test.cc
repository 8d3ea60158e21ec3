// The libusb transport against the mocked USB endpoint with the scripted fake board: enumeration, claim,
// the client's GET_INFO, and the transport's fault paths. Runs under umockdev-wrapper (CTest label hil).
#include <chrono>
#include <thread>

#include <gtest/gtest.h>

#include "fake_board.h"
#include "mock_usb_board.h"
#include "rotoscan/device/client.h"
#include "rotoscan/device/transport.h"

namespace rotoscan::device {
namespace {

using testing::FakeBoard;
using testing::MockUsbBoard;

class HilFakeTest : public ::testing::Test {
 protected:
  void SetUp() override {
    ASSERT_TRUE(MockUsbBoard::InMockEnvironment()) << "run this test under umockdev-wrapper (ctest does)";
  }
};

TEST_F(HilFakeTest, EnumeratesAndListsTheBoard) {
  FakeBoard board;
  MockUsbBoard usb(&board);
  auto boards = ListUsbBoards();
  ASSERT_TRUE(boards.ok()) << boards.status().ToString();
  ASSERT_EQ(boards->size(), 1u);
  EXPECT_EQ((*boards)[0].vendor_id, kUsbVendorId);
  EXPECT_EQ((*boards)[0].bus, 1);
  EXPECT_EQ((*boards)[0].address, 2);
}

TEST_F(HilFakeTest, ClaimsAndTalks) {
  FakeBoard board;
  MockUsbBoard usb(&board);
  auto transport = MakeLibusbTransport();
  ASSERT_TRUE(transport.ok()) << transport.status().ToString();
  auto client = Client::Connect(std::move(transport).value());
  ASSERT_TRUE(client.ok()) << client.status().ToString();
  EXPECT_EQ((*client)->info().firmware_version, "0.4.2");
  EXPECT_NE((*client)->transport().Description().find("bus 1 address 2"), std::string::npos);
  for (int i = 0; i < 20; ++i) ASSERT_TRUE((*client)->SetLasers(static_cast<uint8_t>(i % 4)).ok());
  EXPECT_EQ((*client)->stats().retransmits, 0);
  EXPECT_EQ(board.received.size(), 21u);
}

TEST_F(HilFakeTest, NoBoardIsNotFound) {
  auto transport = MakeLibusbTransport();
  ASSERT_TRUE(transport.ok());
  const Status status = (*transport)->Open();
  EXPECT_EQ(status.code(), StatusCode::kNotFound);
  EXPECT_NE(status.message().find("no Rotoscan board found"), std::string::npos);
}

TEST_F(HilFakeTest, LostAndCorruptedCommandsAreRetransmitted) {
  FakeBoard board;
  MockUsbBoard usb(&board);
  ClientOptions options;
  options.ack_timeout_us = 50'000;
  auto client = Client::Connect(MakeLibusbTransport().value(), options);
  ASSERT_TRUE(client.ok()) << client.status().ToString();
  usb.DropNextOut();
  ASSERT_TRUE((*client)->SetLasers(1).ok());
  EXPECT_EQ((*client)->stats().retransmits, 1);
  usb.CorruptNextOut();
  ASSERT_TRUE((*client)->SetLasers(2).ok());
  EXPECT_EQ((*client)->stats().retransmits, 2);
  usb.DuplicateNextOut();
  ASSERT_TRUE((*client)->SetLasers(3).ok());
  EXPECT_EQ(board.executed[board.received.back().first], 1);
  EXPECT_EQ(usb.counters().dropped, 1);
  EXPECT_EQ(usb.counters().corrupted, 1);
  EXPECT_EQ(usb.counters().duplicated, 1);
}

TEST_F(HilFakeTest, UnplugAndReplugReopensAtTheNewAddress) {
  FakeBoard board;
  MockUsbBoard usb(&board);
  auto client = Client::Connect(MakeLibusbTransport().value());
  ASSERT_TRUE(client.ok()) << client.status().ToString();
  usb.Unplug();
  std::thread replug([&usb] {
    std::this_thread::sleep_for(std::chrono::milliseconds(100));
    usb.Replug();
  });
  const Status status = (*client)->SetLasers(1);
  replug.join();
  ASSERT_TRUE(status.ok()) << status.ToString();
  EXPECT_EQ((*client)->stats().reconnects, 1);
  EXPECT_NE((*client)->transport().Description().find("address 3"), std::string::npos)
      << (*client)->transport().Description();
}

}  // namespace
}  // namespace rotoscan::device

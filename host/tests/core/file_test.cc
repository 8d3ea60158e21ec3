#include "rotoscan/core/file.h"

#include <gtest/gtest.h>

#include <fstream>

#include "testing/testing.h"

namespace rotoscan {
namespace {
namespace fs = std::filesystem;

size_t CountEntries(const fs::path& dir) {
  size_t n = 0;
  for ([[maybe_unused]] const auto& entry : fs::directory_iterator(dir)) ++n;
  return n;
}

TEST(FileTest, WritesAndReadsBack) {
  testing::ScratchDir dir;
  ASSERT_TRUE(WriteFileAtomically(dir / "a.txt", "hello").ok());
  const auto content = ReadFile(dir / "a.txt");
  ASSERT_TRUE(content.ok());
  EXPECT_EQ(*content, "hello");
  // Replacing an existing file works and leaves no temporary behind.
  ASSERT_TRUE(WriteFileAtomically(dir / "a.txt", "bye").ok());
  EXPECT_EQ(*ReadFile(dir / "a.txt"), "bye");
  EXPECT_EQ(CountEntries(dir.path()), 1u);
}

TEST(FileTest, FailedWriterLeavesNothingAndKeepsTheOldFile) {
  testing::ScratchDir dir;
  ASSERT_TRUE(WriteFileAtomically(dir / "cloud.ply", "old").ok());
  const Status s = WriteAtomically(dir / "cloud.ply", [](const fs::path& tmp) {
    std::ofstream(tmp) << "half of a cloud";
    return CorruptDataError("frame 17 is truncated");
  });
  EXPECT_EQ(s.code(), StatusCode::kCorruptData);
  EXPECT_EQ(*ReadFile(dir / "cloud.ply"), "old");
  EXPECT_EQ(CountEntries(dir.path()), 1u);
}

TEST(FileTest, ThrowingWriterLeavesNothing) {
  testing::ScratchDir dir;
  EXPECT_THROW((void)WriteAtomically(dir / "x",
                                     [](const fs::path& tmp) -> Status {
                                       std::ofstream(tmp) << "partial";
                                       throw std::runtime_error("boom");
                                     }),
               std::runtime_error);
  EXPECT_EQ(CountEntries(dir.path()), 0u);
}

TEST(FileTest, WritesDirectoriesAtomically) {
  testing::ScratchDir dir;
  const Status s = WriteAtomically(dir / "bundle", [](const fs::path& tmp) {
    fs::create_directories(tmp / "frames");
    std::ofstream(tmp / "bundle.json") << "{}";
    return Status::Ok();
  });
  ASSERT_TRUE(s.ok()) << s.ToString();
  EXPECT_TRUE(fs::exists(dir / "bundle" / "bundle.json"));
  EXPECT_TRUE(fs::is_directory(dir / "bundle" / "frames"));
}

TEST(FileTest, ClearErrors) {
  testing::ScratchDir dir;
  EXPECT_EQ(ReadFile(dir / "missing.yaml").status().code(), StatusCode::kNotFound);
  EXPECT_EQ(ReadFile(dir.path()).status().code(), StatusCode::kInvalidArgument);
  ASSERT_TRUE(WriteFileAtomically(dir / "big", std::string(100, 'x')).ok());
  EXPECT_EQ(ReadFile(dir / "big", 10).status().code(), StatusCode::kInvalidArgument);
  EXPECT_EQ(WriteFileAtomically(dir / "no" / "such" / "dir.txt", "x").code(), StatusCode::kNotFound);
  EXPECT_EQ(WriteFileAtomically("", "x").code(), StatusCode::kInvalidArgument);
}

}  // namespace
}  // namespace rotoscan

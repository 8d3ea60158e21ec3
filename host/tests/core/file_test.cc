#include "rotoscan/core/file.h"

#include <gtest/gtest.h>

#include <sys/stat.h>
#include <sys/sysmacros.h>

#include <csignal>
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

// Issue 20, defect 1: on a full disk the write fails, the previous file stays and no temporary is left.
TEST(FileTest, FullDiskFailsAndKeepsThePreviousFile) {
  testing::ScratchDir dir;
  ASSERT_TRUE(WriteFileAtomically(dir / "calib.yaml", "good").ok());
  const int code = testing::RunWithFullDisk(1000, [&] {
    const Status s = WriteFileAtomically(dir / "calib.yaml", std::string(5000, 'x'));
    if (s.ok()) return 0;
    return s.code() == StatusCode::kIoError && s.message().find("calib.yaml") != std::string::npos ? 1 : 2;
  });
  EXPECT_EQ(code, 1);
  EXPECT_EQ(*ReadFile(dir / "calib.yaml"), "good");
  EXPECT_EQ(testing::ListTree(dir.path()), std::vector<std::string>{"calib.yaml"});
}

// Issue 20, defect 4: a device, a FIFO or a symlink at the output path is never replaced.
TEST(FileTest, OutputThatIsADeviceFifoOrSymlinkIsNeverReplaced) {
  testing::ScratchDir dir;
  ASSERT_EQ(::mkfifo((dir / "fifo").c_str(), 0644), 0);
  ASSERT_TRUE(WriteFileAtomically(dir / "target", "kept").ok());
  fs::create_symlink(dir / "target", dir / "link");
  fs::create_symlink("/dev/null", dir / "null");
  for (const char* name : {"fifo", "link", "null"}) {
    const Status s = WriteFileAtomically(dir / name, "x");
    EXPECT_EQ(s.code(), StatusCode::kInvalidArgument) << name;
    EXPECT_NE(s.message().find(name), std::string::npos) << s.ToString();
  }
  EXPECT_TRUE(fs::is_fifo(fs::symlink_status(dir / "fifo")));
  EXPECT_TRUE(fs::is_symlink(dir / "link"));
  EXPECT_EQ(*ReadFile(dir / "target"), "kept");
  EXPECT_EQ(testing::ListTree(dir.path()), (std::vector<std::string>{"fifo", "link", "null", "target"}));
  // A character device itself (our own node, like /dev/null; only where we may make one: root, no
  // container restriction). Never /dev/null itself: a broken check would replace the system's.
  if (::mknod((dir / "device").c_str(), S_IFCHR | 0666, makedev(1, 3)) == 0) {
    const Status s = WriteFileAtomically(dir / "device", "x");
    EXPECT_EQ(s.code(), StatusCode::kInvalidArgument) << s.ToString();
    EXPECT_NE(s.message().find("a device"), std::string::npos) << s.ToString();
    EXPECT_TRUE(fs::is_character_file(dir / "device"));
  }
}

TEST(FileTest, ReadFileRefusesAFifo) {
  testing::ScratchDir dir;
  ASSERT_EQ(::mkfifo((dir / "fifo").c_str(), 0644), 0);
  EXPECT_EQ(ReadFile(dir / "fifo").status().code(), StatusCode::kInvalidArgument);  // would block
}

// Issue 20, defects 4, 7, 8: every output is checked before the work starts.
TEST(FileTest, OutputPathsAreCheckedBeforeTheWork) {
  testing::ScratchDir dir;
  ASSERT_TRUE(WriteFileAtomically(dir / "cloud.ply", "ply").ok());
  ASSERT_EQ(::mkfifo((dir / "fifo").c_str(), 0644), 0);
  fs::create_directories(dir / "bundle");
  auto check = [&](std::vector<OutputPath> outputs, std::vector<fs::path> inputs = {}) {
    return CheckOutputPaths(outputs, inputs);
  };
  EXPECT_TRUE(check({{dir / "mesh.ply", "--out"}, {dir / "mesh.png", "--preview"}}, {dir / "cloud.ply"}).ok());
  EXPECT_TRUE(check({{dir / "cloud.ply", "--out"}}).ok());  // replacing a regular file is fine
  EXPECT_TRUE(check({{dir / "bundle", "--out", OutputKind::kDirectory}}).ok());
  // Output = input, also through another spelling.
  fs::create_directories(dir / "x");
  Status s = check({{dir / "x" / ".." / "cloud.ply", "--out"}}, {dir / "cloud.ply"});
  EXPECT_EQ(s.code(), StatusCode::kInvalidArgument);
  EXPECT_NE(s.message().find("is also an input"), std::string::npos) << s.ToString();
  fs::create_symlink(dir / "x", dir / "y");
  fs::create_hard_link(dir / "cloud.ply", dir / "x" / "hard.ply");
  EXPECT_EQ(check({{dir / "y" / "hard.ply", "--out"}}, {dir / "cloud.ply"}).code(), StatusCode::kInvalidArgument);
  // Two outputs on one path.
  s = check({{dir / "m.ply", "--out"}, {dir / "m.ply", "--preview"}});
  EXPECT_EQ(s.code(), StatusCode::kInvalidArgument);
  EXPECT_NE(s.message().find("--preview"), std::string::npos) << s.ToString();
  // Missing directory, a file as directory, a directory as file, a FIFO, a device.
  s = check({{dir / "nodir" / "r.json", "--report"}});
  EXPECT_EQ(s.code(), StatusCode::kNotFound);
  EXPECT_NE(s.message().find("--report"), std::string::npos) << s.ToString();
  EXPECT_NE(s.message().find("nodir"), std::string::npos) << s.ToString();
  EXPECT_EQ(check({{dir / "cloud.ply" / "r.json", "--out"}}).code(), StatusCode::kInvalidArgument);
  s = check({{dir / "bundle", "--out"}});
  EXPECT_EQ(s.code(), StatusCode::kInvalidArgument);
  EXPECT_NE(s.message().find("a directory"), std::string::npos) << s.ToString();
  EXPECT_EQ(check({{dir / "cloud.ply", "--out", OutputKind::kDirectory}}).code(), StatusCode::kInvalidArgument);
  s = check({{dir / "fifo", "--out"}});
  EXPECT_NE(s.message().find("a FIFO"), std::string::npos) << s.ToString();
  s = check({{"/dev/null", "--out"}});
  EXPECT_EQ(s.code(), StatusCode::kInvalidArgument);
  EXPECT_NE(s.message().find("a device"), std::string::npos) << s.ToString();
  EXPECT_EQ(check({{"", "--out"}}).code(), StatusCode::kInvalidArgument);
  // A directory output holding one of the inputs (it would be replaced).
  ASSERT_TRUE(WriteFileAtomically(dir / "bundle" / "scene.json", "{}").ok());
  EXPECT_EQ(check({{dir / "bundle", "--out", OutputKind::kDirectory}}, {dir / "bundle" / "scene.json"}).code(),
            StatusCode::kInvalidArgument);
  // A directory we may not write in (not as root: root may write anywhere).
  if (::geteuid() != 0) {
    fs::create_directories(dir / "ro");
    fs::permissions(dir / "ro", fs::perms::owner_read | fs::perms::owner_exec);
    EXPECT_EQ(check({{dir / "ro" / "a.ply", "--out"}}).code(), StatusCode::kInvalidArgument);
    fs::permissions(dir / "ro", fs::perms::owner_all);
  }
}

// A process killed in the middle of a write (SIGXFSZ at the file size limit) leaves the previous file and
// nothing else.
TEST(FileTest, KillInTheMiddleOfAWriteLeavesThePreviousFile) {
  testing::ScratchDir dir;
  ASSERT_TRUE(WriteFileAtomically(dir / "cloud.ply", "good").ok());
  const int code = testing::RunWithFullDisk(
      4096, [&] { return WriteFileAtomically(dir / "cloud.ply", std::string(100000, 'x')).ok() ? 0 : 1; },
      /*kill_at_limit=*/true);
  EXPECT_EQ(code, 128 + SIGXFSZ);
  EXPECT_EQ(*ReadFile(dir / "cloud.ply"), "good");
  EXPECT_EQ(testing::ListTree(dir.path()), std::vector<std::string>{"cloud.ply"});
}

// A directory that disappears while the writer works: an error, nothing left.
TEST(FileTest, OutputDirectoryRemovedDuringTheWrite) {
  testing::ScratchDir dir;
  fs::create_directories(dir / "out");
  const Status s = WriteAtomically(dir / "out" / "cloud.ply", [&](const fs::path& tmp) -> Status {
    fs::remove_all(dir / "out");
    return WriteFileAtomically(tmp, "ply");
  });
  EXPECT_FALSE(s.ok());
  EXPECT_TRUE(testing::ListTree(dir.path()).empty());
}

}  // namespace
}  // namespace rotoscan

namespace rotoscan {
namespace {

// Issue 20: a mesh and its preview (or calib.yaml and its report) are committed together or not at all.
TEST(FileTest, FilesWrittenTogetherAllOrNone) {
  testing::ScratchDir dir;
  ASSERT_TRUE(WriteFilesTogether({FileWithContent(dir / "mesh.ply", "mesh 1"),
                                  FileWithContent(dir / "mesh.png", "preview 1")})
                  .ok());
  EXPECT_EQ(*ReadFile(dir / "mesh.ply"), "mesh 1");
  EXPECT_EQ(*ReadFile(dir / "mesh.png"), "preview 1");
  EXPECT_EQ(testing::ListTree(dir.path()), (std::vector<std::string>{"mesh.ply", "mesh.png"}));

  // The second file's writer fails: the first is never renamed, no temporary is left.
  const Status failed = WriteFilesTogether(
      {FileWithContent(dir / "mesh.ply", "mesh 2"),
       PendingFile{dir / "mesh.png", [](const fs::path& tmp) {
                     std::ofstream(tmp) << "half a picture";
                     return IoError("cannot write mesh.png: File too large");
                   }}});
  EXPECT_EQ(failed.code(), StatusCode::kIoError);
  EXPECT_EQ(*ReadFile(dir / "mesh.ply"), "mesh 1");
  EXPECT_EQ(*ReadFile(dir / "mesh.png"), "preview 1");
  EXPECT_EQ(testing::ListTree(dir.path()), (std::vector<std::string>{"mesh.ply", "mesh.png"}));

  // The second rename fails (its target became a directory while the files were written): the first,
  // already renamed, gets its previous content back; a third file that had none is removed again.
  const Status rolled_back = WriteFilesTogether(
      {FileWithContent(dir / "mesh.ply", "mesh 3"), FileWithContent(dir / "new.txt", "new"),
       PendingFile{dir / "mesh.png", [&](const fs::path& tmp) {
                     fs::remove(dir / "mesh.png");
                     fs::create_directory(dir / "mesh.png");
                     std::ofstream(tmp) << "preview 3";
                     return Status::Ok();
                   }}});
  EXPECT_EQ(rolled_back.code(), StatusCode::kInvalidArgument) << rolled_back.ToString();
  EXPECT_NE(rolled_back.message().find("mesh.png"), std::string::npos);
  EXPECT_EQ(*ReadFile(dir / "mesh.ply"), "mesh 1");
  EXPECT_FALSE(fs::exists(dir / "new.txt"));
  EXPECT_EQ(testing::ListTree(dir.path()), (std::vector<std::string>{"mesh.ply", "mesh.png"}));

  // The same target twice is a caller's mistake, refused before anything is written.
  EXPECT_EQ(WriteFilesTogether({FileWithContent(dir / "a", "1"), FileWithContent(dir / "a", "2")}).code(),
            StatusCode::kInvalidArgument);
}

// A full disk in the second file's write (RLIMIT_FSIZE in a child process): the first stays as it was.
TEST(FileTest, FullDiskInTheSecondFileKeepsBoth) {
  testing::ScratchDir dir;
  ASSERT_TRUE(WriteFileAtomically(dir / "mesh.ply", "old mesh").ok());
  ASSERT_TRUE(WriteFileAtomically(dir / "mesh.png", "old preview").ok());
  const int code = testing::RunWithFullDisk(4096, [&] {
    return WriteFilesTogether({FileWithContent(dir / "mesh.ply", std::string(1000, 'm')),
                               FileWithContent(dir / "mesh.png", std::string(100000, 'p'))})
                   .ok()
               ? 0
               : 1;
  });
  EXPECT_EQ(code, 1);
  EXPECT_EQ(*ReadFile(dir / "mesh.ply"), "old mesh");
  EXPECT_EQ(*ReadFile(dir / "mesh.png"), "old preview");
  EXPECT_EQ(testing::ListTree(dir.path()), (std::vector<std::string>{"mesh.ply", "mesh.png"}));
}

}  // namespace
}  // namespace rotoscan

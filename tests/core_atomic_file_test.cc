// Atomic writes: a file is written beside its path and renamed into place, and an error says why
// it could not be, naming the path, with no temporary file left behind. And reading one back
// whole (core/read_file.h).
#include <gtest/gtest.h>
#include <signal.h>
#include <sys/resource.h>
#include <sys/wait.h>
#include <unistd.h>

#include <filesystem>
#include <fstream>
#include <random>
#include <string>

#include "core/atomic_file.h"
#include "core/error.h"
#include "core/image.h"
#include "core/read_file.h"

namespace flamerig {
namespace {

namespace fs = std::filesystem;

TEST(AtomicFile, WritesTheWholeFileOrSaysWhyNot) {
  const fs::path dir =
      fs::temp_directory_path() / ("flamerig_atomic_" + std::to_string(::getpid()));
  fs::remove_all(dir);
  fs::create_directories(dir / "a_folder" / "inside");
  WriteFileAtomically((dir / "file.txt").string(), "bytes\n");
  std::ifstream in(dir / "file.txt");
  std::string text((std::istreambuf_iterator<char>(in)), {});
  EXPECT_EQ(text, "bytes\n");
  // Onto a folder that holds something: the rename's own reason (it said "Success", the result of
  // removing the temporary file after it).
  try {
    WriteFileAtomically((dir / "a_folder").string(), "bytes\n");
    FAIL() << "no error";
  } catch (const IoError& e) {
    const std::string what = e.what();
    EXPECT_NE(what.find("a_folder: cannot move the written file into place: "), std::string::npos)
        << what;
    EXPECT_EQ(what.find("Success"), std::string::npos) << what;
    EXPECT_NE(what.find(std::error_code(EISDIR, std::generic_category()).message()),
              std::string::npos)
        << what;
  }
  std::size_t files = 0;
  for (const auto& e : fs::directory_iterator(dir)) files += e.is_regular_file();
  EXPECT_EQ(files, 1u);  // file.txt, and no temporary file
  fs::remove_all(dir);
}

// A PNG onto a disk that fills (RLIMIT_FSIZE in a child: writes fail with EFBIG, as ENOSPC on a
// full disk): an error naming the file and the reason, and no file, whole or empty, under its
// name. cv::imwrite said true there, and `export` left empty PNGs behind (2026-12-02).
TEST(AtomicFile, APictureOnAFullDiskIsAnErrorAndNoFile) {
  const fs::path dir =
      fs::temp_directory_path() / ("flamerig_atomic_png_" + std::to_string(::getpid()));
  fs::remove_all(dir);
  fs::create_directories(dir);
  ImageU8 noise(256, 256, 3);  // does not compress: about 200 KB as PNG
  std::mt19937 rng(1);
  for (auto& p : noise.pixels) p = static_cast<std::uint8_t>(rng());
  const fs::path png = dir / "cam0.png";
  int pipe_fd[2];
  ASSERT_EQ(::pipe(pipe_fd), 0);
  const pid_t child = ::fork();
  ASSERT_GE(child, 0);
  if (child == 0) {
    ::close(pipe_fd[0]);
    ::signal(SIGXFSZ, SIG_IGN);
    const rlimit limit{16384, 16384};
    ::setrlimit(RLIMIT_FSIZE, &limit);
    std::string said = "no error";
    try {
      WritePng(png.string(), noise);
    } catch (const IoError& e) {
      said = e.what();
    }
    (void)!::write(pipe_fd[1], said.data(), said.size());
    ::_exit(0);
  }
  ::close(pipe_fd[1]);
  std::string said;
  char buffer[512];
  for (ssize_t n; (n = ::read(pipe_fd[0], buffer, sizeof buffer)) > 0;) said.append(buffer, n);
  ::close(pipe_fd[0]);
  ::waitpid(child, nullptr, 0);
  EXPECT_NE(said.find(png.string()), std::string::npos) << said;
  EXPECT_NE(said.find(std::error_code(EFBIG, std::generic_category()).message()), std::string::npos)
      << said;
  EXPECT_FALSE(fs::exists(png));
  EXPECT_TRUE(fs::is_empty(dir)) << "a temporary file was left";
  // Without the limit the same picture is written and reads back.
  WritePng(png.string(), noise);
  EXPECT_EQ(ReadImageU8(png.string(), 3).pixels, noise.pixels);
  fs::remove_all(dir);
}

// The IoError `read` throws, or "(no error)".
template <typename Read>
std::string IoErrorOf(Read read) {
  try {
    read();
  } catch (const IoError& e) {
    return e.what();
  }
  return "(no error)";
}

// What a writer wrote comes back byte for byte (NULs and all); an empty file is an empty string;
// what cannot be read is an IoError naming the path and the system's reason, and only a file
// that is not there is "not present".
TEST(ReadFile, ReadsTheWholeFileOrSaysWhyNot) {
  const fs::path dir = fs::temp_directory_path() / ("flamerig_read_" + std::to_string(::getpid()));
  fs::remove_all(dir);
  fs::create_directories(dir / "a_folder");
  std::string bytes(70000, '\0');
  std::mt19937 random(7);
  for (char& b : bytes) b = static_cast<char>(random() & 0xff);
  WriteFileAtomically((dir / "blob").string(), bytes);
  EXPECT_EQ(ReadFile((dir / "blob").string()), bytes);
  EXPECT_EQ(ReadFileIfPresent((dir / "blob").string()).value_or(""), bytes);
  WriteFileAtomically((dir / "empty").string(), "");
  EXPECT_EQ(ReadFile((dir / "empty").string()), "");
  ASSERT_TRUE(ReadFileIfPresent((dir / "empty").string()).has_value());

  const std::string missing = (dir / "missing.yaml").string();
  EXPECT_FALSE(ReadFileIfPresent(missing).has_value());
  std::string what = IoErrorOf([&] { ReadFile(missing); });
  EXPECT_NE(what.find(missing + ": cannot be read: No such file"), std::string::npos) << what;
  const std::string folder = (dir / "a_folder").string();
  for (const std::string& error :
       {IoErrorOf([&] { ReadFile(folder); }), IoErrorOf([&] { ReadFileIfPresent(folder); })})
    EXPECT_NE(error.find("a_folder: cannot be read: it is a folder"), std::string::npos) << error;
  // A file without read permission (root reads it anyway).
  fs::permissions(dir / "blob", fs::perms::none);
  if (::geteuid() != 0) {
    EXPECT_THROW(ReadFileIfPresent((dir / "blob").string()), IoError);
    what = IoErrorOf([&] { ReadFile((dir / "blob").string()); });
    EXPECT_NE(what.find("blob: cannot be read: Permission denied"), std::string::npos) << what;
  }
  fs::permissions(dir / "blob", fs::perms::owner_all);
  fs::remove_all(dir);
}

}  // namespace
}  // namespace flamerig

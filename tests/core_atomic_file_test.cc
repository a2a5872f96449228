// Atomic writes: a file is written beside its path and renamed into place, and an error says why
// it could not be, naming the path, with no temporary file left behind.
#include <gtest/gtest.h>
#include <unistd.h>

#include <filesystem>
#include <fstream>
#include <string>

#include "core/atomic_file.h"
#include "core/error.h"

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

}  // namespace
}  // namespace flamerig

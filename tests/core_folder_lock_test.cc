// FolderLock: a second holder of a folder gets an error naming the first; the lock goes with its
// holder, even one killed with SIGKILL (no stale locks).
#include <gtest/gtest.h>
#include <signal.h>
#include <sys/wait.h>
#include <unistd.h>

#include <filesystem>
#include <memory>
#include <optional>

#include "core/error.h"
#include "core/folder_lock.h"

namespace flamerig {
namespace {

namespace fs = std::filesystem;

fs::path Folder() {
  const fs::path p = fs::temp_directory_path() / ("flamerig_lock_" + std::to_string(::getpid()));
  fs::remove_all(p);
  return p;
}

std::string LockError(const fs::path& folder) {
  try {
    FolderLock second(folder.string(), "flamerig run");
  } catch (const InputError& e) {
    return e.what();
  }
  return "";
}

TEST(FolderLock, ASecondHolderIsToldWhoHasIt) {
  const fs::path folder = Folder();
  {
    FolderLock first((folder / "out").string(), "flamerig capture");
    EXPECT_TRUE(fs::exists(first.path()));
    const std::string m = LockError(folder / "out");
    EXPECT_NE(m.find((folder / "out").string() + " is in use by another flamerig"),
              std::string::npos)
        << m;
    EXPECT_NE(m.find("flamerig capture, pid " + std::to_string(::getpid())), std::string::npos)
        << m;
  }
  EXPECT_EQ(LockError(folder / "out"), "");  // released with its holder
  fs::remove_all(folder);
}

TEST(FolderLock, AKilledHolderLeavesNoStaleLock) {
  const fs::path folder = Folder();
  int ready[2];
  ASSERT_EQ(::pipe(ready), 0);
  const pid_t child = ::fork();
  ASSERT_GE(child, 0);
  if (child == 0) {
    FolderLock held(folder.string(), "a child");
    (void)!::write(ready[1], "x", 1);
    ::pause();
    ::_exit(0);
  }
  char c;
  ASSERT_EQ(::read(ready[0], &c, 1), 1);
  EXPECT_NE(LockError(folder).find("a child, pid " + std::to_string(child)), std::string::npos);
  ::kill(child, SIGKILL);
  ::waitpid(child, nullptr, 0);
  EXPECT_EQ(LockError(folder), "");
  fs::remove_all(folder);
}

}  // namespace
}  // namespace flamerig

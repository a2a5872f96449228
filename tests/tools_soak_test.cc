// The capture soak (tools/soak.h), bounded for CI: 15 s of recording with faults injected at
// random; nothing the daemon reported as recorded may be lost, every frame must read back byte for
// byte, and memory must stay under its bound. `flamerig benchmark soak --seconds 3600` soaks for an
// hour and writes its figures to BENCHMARKS.md.
#include <gtest/gtest.h>
#include <unistd.h>

#include <cstdio>
#include <cstdlib>
#include <filesystem>

#include "tools/soak.h"

namespace flamerig {
namespace {

TEST(Soak, NothingReportedAsRecordedIsLostAndMemoryStaysBounded) {
  SoakOptions o;
  o.binary = FLAMERIG_BINARY;
  o.directory = (std::filesystem::temp_directory_path() /
                 ("flamerig_soak_test_" + std::to_string(::getpid())))
                    .string();
  o.seconds =
      std::getenv("FLAMERIG_SOAK_SECONDS") ? std::atof(std::getenv("FLAMERIG_SOAK_SECONDS")) : 15;
  o.seed = 42;
  o.segment_seconds = 5;  // the recording is closed and another started twice
  const SoakReport r = RunSoak(o);
  SCOPED_TRACE(r.Markdown() + "\n" + r.daemon_tail);
  EXPECT_GT(r.sets_reported, 0u);
  EXPECT_GE(r.segments, 3);
  EXPECT_EQ(r.lost, 0u);
  EXPECT_EQ(r.frames_wrong, 0u);
  EXPECT_GT(r.frames_checked, r.sets_readable);  // several cameras per set
  EXPECT_LE(r.peak_rss_mb, r.rss_bound_mb);
  // The faults happened.
  EXPECT_GE(r.outages, 2 * o.cameras);   // each camera went and came back at least twice
  EXPECT_GE(r.outages_seen, o.cameras);  // and the daemon noticed
  EXPECT_GE(r.stalls, 1);
  if (r.writer_stall_refused.empty()) {  // ptrace allowed here: the writers were stopped too
    EXPECT_GE(r.writer_stalls + r.disk_stalls, 2);
  } else {
    std::printf("soak: threads could not be stopped here (%s)\n", r.writer_stall_refused.c_str());
  }
  EXPECT_GE(r.preview_clients + r.vanishing_clients, 5);
}

}  // namespace
}  // namespace flamerig

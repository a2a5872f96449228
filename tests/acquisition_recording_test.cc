// The recording: frame sets written by the Recorder read back bit-exact; a recording killed with
// SIGKILL mid-write, truncated, or stopped by a full disk opens with every complete set; corruption
// gives an error naming the file; memory stays bounded when the disk falls behind.
#include <gtest/gtest.h>
#include <signal.h>
#include <sys/resource.h>
#include <sys/wait.h>
#include <unistd.h>

#include <zlib.h>

#include <chrono>
#include <cstring>
#include <filesystem>
#include <fstream>
#include <functional>
#include <iterator>
#include <thread>
#include <vector>

#include <yaml-cpp/yaml.h>

#include "acquisition/recording.h"
#include "core/error.h"

namespace flamerig {
namespace {

namespace fs = std::filesystem;

class TempDir {
 public:
  TempDir() {
    path_ = fs::temp_directory_path() /
            ("flamerig_rec_" + std::to_string(::getpid()) + "_" + std::to_string(counter_++));
    fs::remove_all(path_);
  }
  ~TempDir() { fs::remove_all(path_); }
  std::string str() const { return path_.string(); }
  fs::path path() const { return path_; }

 private:
  fs::path path_;
  static inline int counter_ = 0;
};

// Pixels that depend on every one of (camera, set, byte position): any misplaced byte shows.
std::uint8_t Pixel(int camera, std::uint64_t set, std::size_t i) {
  std::uint64_t x = (set * 0x9E3779B97F4A7C15ull) ^ (std::uint64_t(camera) << 56) ^ i;
  x ^= x >> 29;
  x *= 0xBF58476D1CE4E5B9ull;
  x ^= x >> 32;
  return static_cast<std::uint8_t>(x);
}

Frame MakeFrame(int camera, std::uint64_t set, int width, int height,
                PixelFormat format = PixelFormat::kMono8) {
  Frame f;
  f.info.camera = camera;
  f.info.frame_id = 1000 + set;
  f.info.device_frame_id = (1000 + set) % 65536;
  f.info.device_timestamp_ns = static_cast<std::int64_t>(set) * 33'333'333 + camera * 1000;
  f.info.host_monotonic_ns = f.info.device_timestamp_ns + 5'000'000;
  f.info.host_realtime_ns = 1'790'000'000'000'000'000 + f.info.host_monotonic_ns;
  f.info.trigger_id = static_cast<std::int64_t>(set);
  f.info.exposure_us = 1234.5;
  f.info.gain_db = 3.25;
  f.info.pixel_format = format;
  f.info.width = width;
  f.info.height = height;
  f.info.status = set % 7 == 3 ? FrameStatus::kIncomplete : FrameStatus::kOk;
  // What the camera sent: said by camera 1 (a wire format in odd sets), not by the others.
  if (camera == 1) f.info.sent_pfnc = set % 2 ? 0x010C0047u /* Mono12p */ : PfncOf(format);
  auto bytes = std::make_shared<std::vector<std::uint8_t>>(std::size_t(width) * height *
                                                           BytesPerPixel(format));
  for (std::size_t i = 0; i < bytes->size(); ++i) (*bytes)[i] = Pixel(camera, set, i);
  f.data = bytes;
  return f;
}

// Set `s` of a 3-camera rig; camera 2 misses every fifth set.
FrameSet MakeSet(std::uint64_t s, int width = 64, int height = 48) {
  FrameSet set;
  set.index = s;
  set.trigger_id = static_cast<std::int64_t>(s);
  set.reference_ns = static_cast<std::int64_t>(s) * 33'333'333;
  set.spread_ns = 2000;
  set.frames.resize(3);
  for (int c = 0; c < 3; ++c)
    if (!(c == 2 && s % 5 == 4)) set.frames[c] = MakeFrame(c, s, width, height);
  return set;
}

RecordingMetadata Metadata() {
  RecordingMetadata m;
  m.sync_mode = "software-trigger";
  m.config_yaml = "cameras: [a, b, c]\n";
  m.started_realtime_ns = 1'790'000'000'000'000'000;
  for (int c = 0; c < 3; ++c) {
    RecordingCamera rc;
    rc.name = "cam" + std::to_string(c);
    rc.description.driver = "sim";
    rc.description.id = "SIM" + std::to_string(c);
    rc.settings.width = 64;
    rc.settings.height = 48;
    rc.settings.exposure_us = 1234.5;
    rc.settings.trigger = TriggerMode::kSoftware;
    m.cameras.push_back(rc);
  }
  m.features["GevSCPSPacketSize"] = "1500";
  return m;
}

// Every byte and every field of set i as MakeSet made it.
void ExpectSetMatches(const FrameSet& got, std::uint64_t s) {
  const FrameSet want = MakeSet(s);
  ASSERT_EQ(got.frames.size(), 3u);
  EXPECT_EQ(got.index, want.index);
  EXPECT_EQ(got.trigger_id, want.trigger_id);
  EXPECT_EQ(got.reference_ns, want.reference_ns);
  EXPECT_EQ(got.spread_ns, want.spread_ns);
  for (int c = 0; c < 3; ++c) {
    ASSERT_EQ(got.frames[c].has_value(), want.frames[c].has_value()) << "set " << s << " cam " << c;
    if (!want.frames[c]) continue;
    const FrameInfo& g = got.frames[c]->info;
    const FrameInfo& w = want.frames[c]->info;
    EXPECT_EQ(g.camera, c);
    EXPECT_EQ(g.frame_id, w.frame_id);
    EXPECT_EQ(g.device_frame_id, w.device_frame_id);
    EXPECT_EQ(g.device_timestamp_ns, w.device_timestamp_ns);
    EXPECT_EQ(g.host_monotonic_ns, w.host_monotonic_ns);
    EXPECT_EQ(g.host_realtime_ns, w.host_realtime_ns);
    EXPECT_EQ(g.trigger_id, w.trigger_id);
    EXPECT_EQ(g.exposure_us, w.exposure_us);
    EXPECT_EQ(g.gain_db, w.gain_db);
    EXPECT_EQ(g.pixel_format, w.pixel_format);
    EXPECT_EQ(g.width, w.width);
    EXPECT_EQ(g.height, w.height);
    EXPECT_EQ(g.status, w.status);
    EXPECT_EQ(g.sent_pfnc, w.sent_pfnc);
    ASSERT_TRUE(*got.frames[c]->data == *want.frames[c]->data) << "set " << s << " cam " << c;
  }
}

TEST(Recording, FrameSetsReadBackBitExactWithTheirMetadata) {
  TempDir dir;
  {
    Recorder rec(dir.str(), Metadata());
    for (std::uint64_t s = 0; s < 40; ++s) ASSERT_TRUE(rec.Submit(MakeSet(s)));
    const RecorderStatus st = rec.Close();
    EXPECT_EQ(st.sets_recorded, 40u);
    EXPECT_EQ(st.frames_recorded, 40u * 3 - 8);  // camera 2 missed 8 sets
    EXPECT_FALSE(st.stopped) << st.error;
  }
  const Recording r = Recording::Open(dir.str());
  EXPECT_TRUE(r.recovery().closed_cleanly);
  EXPECT_EQ(r.recovery().ignored_bytes, 0u);
  ASSERT_EQ(r.num_sets(), 40u);
  for (std::size_t s = 0; s < r.num_sets(); ++s) ExpectSetMatches(r.ReadSet(s), s);
  // Metadata snapshot.
  ASSERT_EQ(r.num_cameras(), 3);
  EXPECT_EQ(r.metadata().sync_mode, "software-trigger");
  EXPECT_EQ(r.metadata().config_yaml, "cameras: [a, b, c]\n");
  EXPECT_EQ(r.metadata().cameras[1].description.id, "SIM1");
  EXPECT_EQ(r.metadata().cameras[1].settings.trigger, TriggerMode::kSoftware);
  EXPECT_EQ(r.metadata().cameras[1].settings.exposure_us, 1234.5);
  EXPECT_EQ(r.metadata().features.at("GevSCPSPacketSize"), "1500");
  EXPECT_EQ(r.final_counters().at("sets_recorded"), "40");
  // Camera 2's frame ids skip every fifth set: 7 gaps of one frame in 32 frames (set 39 is last).
  const auto missing = r.MissingByFrameId();
  EXPECT_EQ(missing[0], 0u);
  EXPECT_EQ(missing[2], 7u);
  EXPECT_THROW(r.ReadSet(40), std::out_of_range);
}

// The file format's CRC-32 is zlib's (the oracle: zlib's own crc32 over the bytes on disk),
// whatever library computes it: a record's CRC of itself and of its pixels in camNN.data.
TEST(Recording, ChecksumsOnDiskAreZlibsCrc32) {
  TempDir dir;
  {
    Recorder rec(dir.str(), Metadata());
    for (std::uint64_t s = 0; s < 3; ++s) ASSERT_TRUE(rec.Submit(MakeSet(s)));
    rec.Close();
  }
  std::ifstream data(dir.path() / "cam01.data", std::ios::binary);
  std::vector<char> bytes((std::istreambuf_iterator<char>(data)), std::istreambuf_iterator<char>());
  std::size_t at = 16;  // the file header
  int records = 0;
  while (at + sizeof(FrameRecord) <= bytes.size()) {
    FrameRecord r;
    std::memcpy(&r, bytes.data() + at, sizeof r);
    ASSERT_EQ(std::string(r.magic, 4), "FRM1") << "at byte " << at;
    const auto* p = reinterpret_cast<const Bytef*>(bytes.data() + at);
    EXPECT_EQ(r.record_crc, crc32_z(0, p + 8, sizeof(FrameRecord) - 8));
    ASSERT_LE(at + sizeof r + r.payload_bytes, bytes.size());
    EXPECT_GT(r.payload_bytes, 0u);
    EXPECT_EQ(r.payload_crc, crc32_z(0, p + sizeof r, r.payload_bytes));
    at += sizeof r + r.payload_bytes;
    ++records;
  }
  EXPECT_EQ(records, 3);
}

TEST(Recording, RefusesToOverwriteAndFramesOfTheWrongSize) {
  TempDir dir;
  fs::create_directories(dir.path());
  std::ofstream(dir.path() / "keep.txt") << "user data";
  try {
    Recorder rec(dir.str(), Metadata());
    FAIL() << "recorded into a non-empty directory";
  } catch (const RecordingError& e) {
    EXPECT_NE(std::string(e.what()).find("not empty"), std::string::npos);
  }
  EXPECT_TRUE(fs::exists(dir.path() / "keep.txt"));
  TempDir dir2;
  Recorder rec(dir2.str(), Metadata());
  FrameSet bad = MakeSet(0);
  auto shorter = std::make_shared<std::vector<std::uint8_t>>(*bad.frames[1]->data);
  shorter->pop_back();
  bad.frames[1]->data = shorter;
  try {
    rec.Submit(bad);
    FAIL() << "a frame of the wrong size was accepted";
  } catch (const InputError& e) {
    EXPECT_NE(std::string(e.what()).find("camera 1"), std::string::npos) << e.what();
    EXPECT_NE(std::string(e.what()).find("3071 bytes for 64x48 Mono8"), std::string::npos)
        << e.what();
  }
  FrameSet two = MakeSet(0);
  two.frames.pop_back();
  EXPECT_THROW(rec.Submit(two), InputError);
}

std::uint64_t FileSize(const fs::path& p) { return fs::file_size(p); }

// metadata.yaml as a recorder killed mid-recording leaves it: `closed: false`, no counters.
void AsIfKilled(const fs::path& dir) {
  std::ifstream in(dir / "metadata.yaml");
  const std::string text((std::istreambuf_iterator<char>(in)), {});
  ASSERT_NE(text.find("closed: true"), std::string::npos);
  std::ofstream(dir / "metadata.yaml", std::ios::trunc)
      << text.substr(0, text.find("closed: true")) << "closed: false\n";
}

TEST(Recording, TruncatedFilesOpenWithEveryCompleteSet) {
  TempDir dir;
  {
    Recorder rec(dir.str(), Metadata());
    for (std::uint64_t s = 0; s < 10; ++s) rec.Submit(MakeSet(s));
    rec.Close();
  }
  // As a kill mid-write leaves it: half a frame appended to a data file, a torn index entry and a
  // torn set record.
  AsIfKilled(dir.path());
  {
    std::ofstream(dir.path() / "cam00.data", std::ios::app | std::ios::binary)
        << std::string(1000, 'x');
    std::ofstream(dir.path() / "cam01.index", std::ios::app | std::ios::binary)
        << std::string(50, 'y');
    const auto sets = dir.path() / "sets.index";
    fs::resize_file(sets, FileSize(sets) - 10);
  }
  const Recording r = Recording::Open(dir.str());
  EXPECT_EQ(r.num_sets(), 9u);  // the tenth set's record was torn
  EXPECT_EQ(r.recovery().ignored_bytes, 1000u + 50u + (48u + 24u - 10u));
  EXPECT_GE(r.recovery().notes.size(), 3u);
  for (std::size_t s = 0; s < r.num_sets(); ++s) ExpectSetMatches(r.ReadSet(s), s);
}

void FlipByte(const fs::path& p, std::uint64_t at) {
  std::fstream f(p, std::ios::in | std::ios::out | std::ios::binary);
  f.seekg(static_cast<std::streamoff>(at));
  char c;
  f.read(&c, 1);
  c = static_cast<char>(c ^ 0x5a);
  f.seekp(static_cast<std::streamoff>(at));
  f.write(&c, 1);
}

std::string OpenError(const std::string& dir) {
  try {
    Recording::Open(dir);
  } catch (const RecordingError& e) {
    return e.what();
  }
  return "";
}

// Every frame of set s but the camera `except`, as MakeSet made them (the header not compared).
void ExpectFramesMatch(const Recording& r, std::uint64_t s, int except = -1) {
  const FrameSet want = MakeSet(s);
  for (int c = 0; c < 3; ++c) {
    if (c == except) continue;
    ASSERT_EQ(r.HasFrame(s, c), want.frames[c].has_value()) << "set " << s << " cam " << c;
    const std::optional<Frame> got = r.ReadFrame(s, c);
    ASSERT_EQ(got.has_value(), want.frames[c].has_value()) << "set " << s << " cam " << c;
    if (!got) continue;
    EXPECT_EQ(got->info.frame_id, want.frames[c]->info.frame_id);
    EXPECT_EQ(got->info.device_timestamp_ns, want.frames[c]->info.device_timestamp_ns);
    ASSERT_TRUE(*got->data == *want.frames[c]->data) << "set " << s << " cam " << c;
  }
}

std::string Notes(const Recording& r) {
  std::string all;
  for (const auto& n : r.recovery().notes) all += n + "\n";
  return all;
}

// The error ReadFrame gives, or "".
std::string ReadError(const Recording& r, std::size_t s, int c) {
  try {
    r.ReadFrame(s, c);
  } catch (const RecordingError& e) {
    return e.what();
  }
  return "";
}

// A pristine 10-set recording, copied afresh for each kind of damage.
class Damage : public ::testing::Test {
 protected:
  void SetUp() override {
    Recorder rec(pristine_.str(), Metadata());
    for (std::uint64_t s = 0; s < 10; ++s) ASSERT_TRUE(rec.Submit(MakeSet(s)));
    rec.Close();
    fs::copy(pristine_.path(), dir_.path());
    frames_ = Recording::Open(pristine_.str()).frames(1);
  }
  fs::path at(const std::string& name) const { return dir_.path() / name; }
  TempDir pristine_, dir_;
  std::vector<FrameRecord> frames_;  // camera 1's, undamaged
};

TEST_F(Damage, AFlippedPixelByteCostsThatFrameAlone) {
  FlipByte(at("cam01.data"), frames_[4].offset + sizeof(FrameRecord) + 100);
  const Recording r = Recording::Open(dir_.str());
  EXPECT_FALSE(r.recovery().damaged()) << Notes(r);
  const std::string m = ReadError(r, 4, 1);
  EXPECT_NE(m.find("cam01.data"), std::string::npos) << m;
  EXPECT_NE(m.find("pixel checksum"), std::string::npos) << m;
  EXPECT_NE(m.find("set 4"), std::string::npos) << m;
  ExpectFramesMatch(r, 4, /*except=*/1);
  for (std::uint64_t s = 0; s < 10; ++s)
    if (s != 4) ExpectSetMatches(r.ReadSet(s), s);
}

TEST_F(Damage, AFlippedIndexByteCostsNothing) {
  FlipByte(at("cam01.index"), 16 + 3 * sizeof(FrameRecord) + 40);
  const Recording r = Recording::Open(dir_.str());
  EXPECT_EQ(r.recovery().rebuilt_indexes, std::vector<int>{1});
  EXPECT_NE(Notes(r).find("cam01.index: entry 3 at byte 400 is corrupt"), std::string::npos)
      << Notes(r);
  ASSERT_EQ(r.num_sets(), 10u);
  for (std::uint64_t s = 0; s < 10; ++s) ExpectSetMatches(r.ReadSet(s), s);
}

TEST_F(Damage, AFlippedRecordHeaderInTheDataFileIsReadFromTheIndex) {
  FlipByte(at("cam01.data"), frames_[3].offset + 40);
  const Recording r = Recording::Open(dir_.str());
  for (std::uint64_t s = 0; s < 10; ++s) ExpectSetMatches(r.ReadSet(s), s);
  // Both copies of the header damaged: that frame alone is lost, and says where it was.
  FlipByte(at("cam01.index"), 16 + 3 * sizeof(FrameRecord) + 40);
  const Recording both = Recording::Open(dir_.str());
  EXPECT_EQ(both.recovery().lost_frames, 1u) << Notes(both);
  EXPECT_EQ(both.recovery().damaged_bytes, frames_[4].offset - frames_[3].offset) << Notes(both);
  EXPECT_TRUE(both.FrameLost(3, 1));
  EXPECT_FALSE(both.HasFrame(3, 1));
  EXPECT_NE(ReadError(both, 3, 1).find("is lost"), std::string::npos) << ReadError(both, 3, 1);
  ExpectFramesMatch(both, 3, /*except=*/1);
  for (std::uint64_t s = 0; s < 10; ++s)
    if (s != 3) ExpectSetMatches(both.ReadSet(s), s);
}

TEST_F(Damage, ACorruptSetRecordIsRebuiltFromItsFrames) {
  FlipByte(at("sets.index"), 16 + 2 * 72 + 20);
  const Recording r = Recording::Open(dir_.str());
  EXPECT_EQ(r.recovery().rebuilt_sets, 1u);
  EXPECT_NE(Notes(r).find("sets.index: set record 2 at byte 160 is corrupt"), std::string::npos)
      << Notes(r);
  // Its header from its frames: trigger id, earliest device time and their spread are exact here.
  for (std::uint64_t s = 0; s < 10; ++s) ExpectSetMatches(r.ReadSet(s), s);
}

TEST_F(Damage, ACutDataFileLosesOnlyTheFramesPastTheCut) {
  fs::resize_file(at("cam01.data"), frames_[6].offset + 500);
  const Recording r = Recording::Open(dir_.str());
  ASSERT_EQ(r.num_sets(), 10u) << Notes(r);
  EXPECT_EQ(r.recovery().lost_frames, 4u) << Notes(r);
  for (std::uint64_t s = 0; s < 6; ++s) ExpectSetMatches(r.ReadSet(s), s);
  for (std::uint64_t s = 6; s < 10; ++s) {
    EXPECT_TRUE(r.FrameLost(s, 1));
    const std::string m = ReadError(r, s, 1);
    EXPECT_NE(m.find("cam01.data ends at byte " + std::to_string(frames_[6].offset + 500)),
              std::string::npos)
        << m;
    ExpectFramesMatch(r, s, /*except=*/1);
  }
}

TEST_F(Damage, AMissingDataFileLosesOnlyItsCamera) {
  fs::remove(at("cam02.data"));
  const Recording r = Recording::Open(dir_.str());
  ASSERT_EQ(r.num_sets(), 10u) << Notes(r);
  EXPECT_EQ(r.recovery().lost_frames, 8u) << Notes(r);  // camera 2 missed sets 4 and 9
  EXPECT_NE(Notes(r).find("cam02.data (camera cam2) is missing"), std::string::npos) << Notes(r);
  for (std::uint64_t s = 0; s < 10; ++s) {
    EXPECT_EQ(r.FrameLost(s, 2), s % 5 != 4) << s;  // lost, not missed
    ExpectFramesMatch(r, s, /*except=*/2);
  }
}

TEST_F(Damage, ACutIndexIsReadFromTheDataFile) {
  fs::resize_file(at("cam01.index"), 16 + 4 * sizeof(FrameRecord) + 50);
  const Recording r = Recording::Open(dir_.str());
  EXPECT_NE(Notes(r).find("cam01.index: holds no entry for set 4"), std::string::npos) << Notes(r);
  ASSERT_EQ(r.num_sets(), 10u);
  for (std::uint64_t s = 0; s < 10; ++s) ExpectSetMatches(r.ReadSet(s), s);
  // A missing index and one with a bad header likewise.
  fs::remove(at("cam01.index"));
  FlipByte(at("cam02.index"), 2);
  const Recording again = Recording::Open(dir_.str());
  EXPECT_EQ(again.recovery().rebuilt_indexes, (std::vector<int>{1, 2})) << Notes(again);
  EXPECT_NE(Notes(again).find("cam02.index: is not a flamerig recording file"), std::string::npos)
      << Notes(again);
  for (std::uint64_t s = 0; s < 10; ++s) ExpectSetMatches(again.ReadSet(s), s);
}

TEST_F(Damage, AMissingSetIndexIsRebuiltFromTheFrames) {
  fs::remove(at("sets.index"));
  const Recording r = Recording::Open(dir_.str());
  ASSERT_EQ(r.num_sets(), 10u) << Notes(r);
  EXPECT_EQ(r.recovery().rebuilt_sets, 10u);
  for (std::uint64_t s = 0; s < 10; ++s) {
    ExpectFramesMatch(r, s);
    EXPECT_EQ(r.SetHeader(s).index, s);
    EXPECT_EQ(r.SetHeader(s).trigger_id, static_cast<std::int64_t>(s));
  }
  // Cut to 7 sets, where metadata.yaml says 10 were recorded: the 3 after are rebuilt.
  fs::copy_file(pristine_.path() / "sets.index", at("sets.index"));
  fs::resize_file(at("sets.index"), 16 + 7 * 72);
  const Recording cut = Recording::Open(dir_.str());
  ASSERT_EQ(cut.num_sets(), 10u) << Notes(cut);
  EXPECT_EQ(cut.recovery().rebuilt_sets, 3u);
  for (std::uint64_t s = 0; s < 10; ++s) ExpectFramesMatch(cut, s);
}

TEST_F(Damage, OnlyMetadataIsIndispensable) {
  std::ofstream(at("metadata.yaml")) << "flamerig_recording: [not, a, number";
  std::string m = OpenError(dir_.str());
  EXPECT_NE(m.find("metadata.yaml"), std::string::npos) << m;
  fs::remove(at("metadata.yaml"));
  m = OpenError(dir_.str());
  EXPECT_NE(m.find("has no metadata.yaml: not a flamerig recording"), std::string::npos) << m;
  EXPECT_NE(OpenError((dir_.path() / "nothing").string()).find("not a directory"),
            std::string::npos);
}

// A metadata.yaml cut short that still parses, listing fewer cameras than the take holds: an
// error naming the files of the camera it leaves out and sets.index's count. Read as it was, the
// take lost a whole camera with only a warning (2026-12-02).
TEST_F(Damage, AMetadataThatListsFewerCamerasThanTheTakeIsAnError) {
  YAML::Node meta = YAML::LoadFile(at("metadata.yaml").string());
  YAML::Node cameras = meta["cameras"];
  YAML::Node first_two(YAML::NodeType::Sequence);
  first_two.push_back(cameras[0]);
  first_two.push_back(cameras[1]);
  meta["cameras"] = first_two;
  std::ofstream(at("metadata.yaml"), std::ios::trunc) << meta << "\n";
  const std::string m = OpenError(dir_.str());
  for (const char* said : {"metadata.yaml lists 2 camera(s)", "cam02.data, cam02.index",
                           "sets.index records 3 cameras a set", "damaged or cut short"})
    EXPECT_NE(m.find(said), std::string::npos) << said << " not in: " << m;
  // Only sets.index to tell: the same.
  fs::remove(at("cam02.data"));
  fs::remove(at("cam02.index"));
  EXPECT_NE(OpenError(dir_.str()).find("sets.index records 3 cameras a set"), std::string::npos);
}

// `flamerig recover`: the damage salvaged, the sets an interrupted recorder left uncommitted taken
// in when their frames are whole, the pixels checked, and the result opens clean.
TEST_F(Damage, RebuildIndexesWritesACleanRecordingAndKeepsTheOldFiles) {
  FlipByte(at("cam01.index"), 16 + 3 * sizeof(FrameRecord) + 40);  // recovered from the data
  FlipByte(at("sets.index"), 16 + 2 * 72 + 20);                    // rebuilt from the frames
  FlipByte(at("cam00.data"), Recording::Open(pristine_.str()).frames(0)[7].offset + 300);
  // An interrupted recorder, the last two sets never committed.
  AsIfKilled(dir_.path());
  fs::resize_file(at("sets.index"), 16 + 8 * 72);
  const std::uintmax_t data_size = fs::file_size(at("cam01.data"));
  const RecoveryReport report = RebuildIndexes(dir_.str());
  // Set 8 is whole; set 9 is not taken in: camera 2 never wrote that far (it missed set 9, but
  // nothing on disk says so).
  EXPECT_EQ(report.added_sets, 1u);
  EXPECT_EQ(report.rebuilt_sets, 1u);
  EXPECT_EQ(report.corrupt_frames, 1u);
  EXPECT_EQ(report.sets, 9u);
  EXPECT_EQ(fs::file_size(at("cam01.data")), data_size);  // data untouched
  std::size_t aside = 0;
  for (const auto& e : fs::directory_iterator(dir_.path()))
    if (e.path().filename().string().rfind("replaced_indexes_", 0) == 0)
      aside += fs::exists(e.path() / "sets.index") && fs::exists(e.path() / "cam01.index");
  EXPECT_EQ(aside, 1u);
  const Recording r = Recording::Open(dir_.str());
  EXPECT_FALSE(r.recovery().damaged()) << Notes(r);
  EXPECT_TRUE(r.recovery().rebuilt_indexes.empty()) << Notes(r);
  ASSERT_EQ(r.num_sets(), 9u);
  for (std::uint64_t s = 0; s < 9; ++s)
    if (s != 7) ExpectSetMatches(r.ReadSet(s), s);
  ExpectFramesMatch(r, 7, /*except=*/0);
  EXPECT_NE(ReadError(r, 7, 0).find("pixel checksum"), std::string::npos);
}

TEST(Recording, AnUncommittedSetIsTakenInOnlyWhenEveryCameraWroteThatFar) {
  TempDir dir;
  {
    Recorder rec(dir.str(), Metadata());
    for (std::uint64_t s = 0; s < 6; ++s) ASSERT_TRUE(rec.Submit(MakeSet(s)));
    rec.Close();
  }
  // As if killed: sets.index stops after set 3, and camera 1's data file before set 5's frame.
  // Camera 2 missed set 4 (s % 5 == 4) and wrote set 5.
  const std::vector<FrameRecord> cam1 = Recording::Open(dir.str()).frames(1);
  AsIfKilled(dir.path());
  fs::resize_file(dir.path() / "sets.index", 16 + 4 * 72);
  fs::resize_file(dir.path() / "cam01.data", cam1[5].offset);
  fs::resize_file(dir.path() / "cam01.index", 16 + 5 * sizeof(FrameRecord));
  const Recording before = Recording::Open(dir.str());
  EXPECT_EQ(before.num_sets(), 4u) << Notes(before);  // uncommitted sets are not read
  const RecoveryReport report = RebuildIndexes(dir.str());
  EXPECT_EQ(report.added_sets, 1u);  // set 4 (camera 2 missed it: it wrote set 5); not set 5
  const Recording r = Recording::Open(dir.str());
  ASSERT_EQ(r.num_sets(), 5u);
  for (std::uint64_t s = 0; s < 5; ++s) ExpectFramesMatch(r, s);
  EXPECT_FALSE(r.HasFrame(4, 2));
}

// A child process records until it is killed with SIGKILL; the recording then opens with at least
// every set the child had committed when it was killed, all bit-exact.
TEST(Recording, SurvivesSigkillMidWrite) {
  TempDir dir;
  const fs::path sets = dir.path() / "sets.index";
  const pid_t child = ::fork();
  ASSERT_GE(child, 0);
  if (child == 0) {
    RecorderOptions o;
    o.sync_interval_s = 0.05;
    Recorder rec(dir.str(), Metadata(), o);
    for (std::uint64_t s = 0;; ++s) {
      while (!rec.Submit(MakeSet(s, 320, 240))) {
        // queue full: wait for the disk, keep every set (so set i is MakeSet(i))
        std::this_thread::sleep_for(std::chrono::milliseconds(1));
      }
    }
  }
  // Wait for 30 committed sets (72 bytes each after the 16-byte header), then kill.
  const auto deadline = std::chrono::steady_clock::now() + std::chrono::seconds(60);
  std::uint64_t committed = 0;
  while (std::chrono::steady_clock::now() < deadline) {
    std::error_code ec;
    const auto size = fs::file_size(sets, ec);
    if (!ec && size >= 16) committed = (size - 16) / 72;
    if (committed >= 30) break;
    std::this_thread::sleep_for(std::chrono::milliseconds(2));
  }
  ::kill(child, SIGKILL);
  int wstatus = 0;
  ::waitpid(child, &wstatus, 0);
  ASSERT_TRUE(WIFSIGNALED(wstatus));
  ASSERT_GE(committed, 30u);
  const Recording r = Recording::Open(dir.str());
  EXPECT_FALSE(r.recovery().closed_cleanly);
  EXPECT_GE(r.num_sets(), committed);
  for (std::size_t s = 0; s < r.num_sets(); ++s) {
    const FrameSet got = r.ReadSet(s);
    const FrameSet want = MakeSet(s, 320, 240);
    for (int c = 0; c < 3; ++c) {
      ASSERT_EQ(got.frames[c].has_value(), want.frames[c].has_value());
      if (want.frames[c]) {
        ASSERT_TRUE(*got.frames[c]->data == *want.frames[c]->data) << s;
      }
    }
  }
}

// A full disk, made real with RLIMIT_FSIZE in a child (writes fail with EFBIG): the recording stops
// cleanly with an error naming the file and the cause, and every committed set reads back.
// Runs `record` in a child process in which no file may grow past `max_file_bytes` (a full disk
// that comes at a known size) and returns what it reported.
std::string InChildWithFileLimit(rlim_t max_file_bytes,
                                 const std::function<std::string()>& record) {
  int pipe_fd[2];
  if (::pipe(pipe_fd) != 0) return "pipe failed";
  const pid_t child = ::fork();
  if (child < 0) return "fork failed";
  if (child == 0) {
    ::close(pipe_fd[0]);
    ::signal(SIGXFSZ, SIG_IGN);
    rlimit lim{max_file_bytes, max_file_bytes};
    ::setrlimit(RLIMIT_FSIZE, &lim);
    std::string report;
    try {
      report = record();
    } catch (const std::exception& e) {
      report = std::string("exception\n") + e.what();
    }
    (void)!::write(pipe_fd[1], report.data(), report.size());
    ::_exit(0);
  }
  ::close(pipe_fd[1]);
  std::string report;
  char buf[512];
  for (ssize_t n; (n = ::read(pipe_fd[0], buf, sizeof buf)) > 0;) report.append(buf, n);
  ::close(pipe_fd[0]);
  ::waitpid(child, nullptr, 0);
  return report;
}

TEST(Recording, AFullDiskStopsTheRecordingCleanly) {
  TempDir dir;
  const std::string report = InChildWithFileLimit(1 << 20, [&] {  // 1 MiB a file
    Recorder rec(dir.str(), Metadata());
    std::uint64_t s = 0;
    for (; s < 10000 && !rec.status().stopped; ++s) {
      while (!rec.Submit(MakeSet(s, 160, 120)) && !rec.status().stopped)
        std::this_thread::sleep_for(std::chrono::milliseconds(1));
    }
    const RecorderStatus st = rec.Close();
    return std::to_string(st.sets_recorded) + "\n" + st.error;
  });
  const std::size_t nl = report.find('\n');
  ASSERT_NE(nl, std::string::npos) << report;
  const std::string error = report.substr(nl + 1);
  EXPECT_NE(error.find("file size limit"), std::string::npos) << error;
  EXPECT_NE(error.find(".data"), std::string::npos) << error;
  const std::uint64_t recorded = std::stoull(report.substr(0, nl));
  // 1 MiB holds 54 frames of 19200 bytes per camera. The writers run independently, so when the
  // first file fails, a set is complete only if every camera had written its frame: under load a
  // slow writer may have written few (so no lower bound), but never a set beyond the limit.
  EXPECT_LE(recorded, 54u);
  const Recording r = Recording::Open(dir.str());
  EXPECT_EQ(r.num_sets(), recorded);
  for (std::size_t s = 0; s < r.num_sets(); ++s) {
    const FrameSet got = r.ReadSet(s);
    const FrameSet want = MakeSet(s, 160, 120);
    for (int c = 0; c < 3; ++c)
      if (want.frames[c]) {
        ASSERT_TRUE(*got.frames[c]->data == *want.frames[c]->data) << s;
      }
  }
}

TEST(Recording, SizeLimitStopsCleanly) {
  TempDir dir;
  RecorderOptions o;
  o.max_bytes = 100 * 3200;  // about 100 frames of 64x48 with their headers
  Recorder rec(dir.str(), Metadata(), o);
  std::uint64_t s = 0;
  while (!rec.status().stopped && s < 1000) {
    if (rec.Submit(MakeSet(s)))
      ++s;
    else
      std::this_thread::sleep_for(std::chrono::milliseconds(1));
  }
  const RecorderStatus st = rec.Close();
  EXPECT_TRUE(st.stopped);
  EXPECT_TRUE(st.limit_reached);  // configured, not a fault
  EXPECT_NE(st.error.find("size limit"), std::string::npos) << st.error;
  EXPECT_LE(st.bytes_written, o.max_bytes);
  const Recording r = Recording::Open(dir.str());
  EXPECT_EQ(r.num_sets(), st.sets_recorded);
  EXPECT_GT(r.num_sets(), 25u);
  // metadata.yaml keeps the limit apart from the faults.
  EXPECT_EQ(r.final_counters().at("error"), "");
  EXPECT_EQ(r.final_counters().at("limit_reached"), st.error);
  for (std::size_t i = 0; i < r.num_sets(); ++i) ExpectSetMatches(r.ReadSet(i), i);
}

// A set count: the recording holds exactly the first max_sets sets it was given, stops as the last
// is accepted, and what follows is neither recorded nor counted as dropped.
TEST(Recording, SetLimitHoldsExactlyThatManySets) {
  TempDir dir;
  RecorderOptions o;
  o.max_sets = 7;
  Recorder rec(dir.str(), Metadata(), o);
  int accepted = 0;
  for (std::uint64_t s = 0; s < 12; ++s) {
    const bool took = rec.Submit(MakeSet(s));
    accepted += took;
    EXPECT_EQ(took, s < 7) << "set " << s;
    EXPECT_EQ(rec.status().stopped, s >= 6) << "set " << s;
  }
  const RecorderStatus st = rec.Close();
  EXPECT_EQ(accepted, 7);
  EXPECT_EQ(st.sets_recorded, 7u);
  EXPECT_EQ(st.sets_dropped, 0u);
  EXPECT_TRUE(st.limit_reached);
  EXPECT_NE(st.error.find("reached its limit of 7 frame sets"), std::string::npos) << st.error;
  const Recording r = Recording::Open(dir.str());
  ASSERT_EQ(r.num_sets(), 7u);
  for (std::size_t i = 0; i < r.num_sets(); ++i) ExpectSetMatches(r.ReadSet(i), i);
}

// A write that fails after a set limit was reached is a fault, not the limit: the disk fills (a
// file limit of six and a half 640x480 frames) while the last of 7 sets is written, which is always
// after the limit stopped the recording (it stops as the 7th set is accepted, before any writer has
// it; the six before are on disk by then). The six stay readable and metadata.yaml names the fault.
TEST(Recording, AWriteFailingAfterTheSetLimitIsAFault) {
  TempDir dir;
  const rlim_t frame_record = sizeof(FrameRecord) + 640 * 480;
  const std::string report = InChildWithFileLimit(6 * frame_record + frame_record / 2, [&] {
    RecorderOptions o;
    o.max_sets = 7;
    o.min_free_bytes = 0;
    Recorder rec(dir.str(), Metadata(), o);
    std::string log;
    for (std::uint64_t s = 0; s < 7; ++s) {
      log += rec.Submit(MakeSet(s, 640, 480)) ? "" : "set " + std::to_string(s) + " refused; ";
      // The first six on disk before the seventh is given: its failure stops the writers, and a
      // writer still holding set 5 would then leave it out (the count must not depend on timing).
      const auto until = std::chrono::steady_clock::now() + std::chrono::seconds(30);
      while (s == 5 && rec.status().sets_recorded < 6 && std::chrono::steady_clock::now() < until)
        std::this_thread::sleep_for(std::chrono::milliseconds(1));
    }
    const RecorderStatus st = rec.Close();
    return std::to_string(st.sets_recorded) + " " + std::to_string(st.sets_dropped) + " " +
           std::to_string(st.limit_reached) + " " + std::to_string(st.stopped) + "\n" + log +
           st.error;
  });
  const std::size_t nl = report.find('\n');
  ASSERT_NE(nl, std::string::npos) << report;
  // Every set accepted (no "refused" in the log), 6 recorded, none dropped, no longer
  // `limit_reached`, stopped; the error says the limit came first, then the fault.
  EXPECT_EQ(report.substr(0, nl), "6 0 0 1") << report;
  const std::string error = report.substr(nl + 1);
  EXPECT_EQ(error.rfind("reached its limit of 7 frame sets; then", 0), 0u) << error;
  EXPECT_NE(error.find("file size limit"), std::string::npos) << error;
  const Recording r = Recording::Open(dir.str());
  ASSERT_EQ(r.num_sets(), 6u);
  for (std::size_t i = 0; i < r.num_sets(); ++i) {
    const FrameSet got = r.ReadSet(i);
    const FrameSet want = MakeSet(i, 640, 480);
    for (int c = 0; c < 3; ++c)
      if (want.frames[c]) {
        ASSERT_TRUE(got.frames[c]) << i;
        ASSERT_TRUE(*got.frames[c]->data == *want.frames[c]->data) << i;
      }
  }
  EXPECT_EQ(r.final_counters().at("error"), error);
  EXPECT_EQ(r.final_counters().at("limit_reached"), "");
}

// A producer much faster than the disk: whole sets are dropped and counted, the queue never holds
// more than its bound, and what was recorded is exactly the sets that were accepted.
TEST(Recording, MemoryStaysBoundedWhenTheDiskFallsBehind) {
  TempDir dir;
  RecorderOptions o;
  o.max_queued_bytes = 3 * 640 * 480;  // about one set of 640x480
  Recorder rec(dir.str(), Metadata(), o);
  // One set's pixels shared by every submission, so the producer costs nothing.
  const FrameSet big = MakeSet(0, 640, 480);
  std::vector<std::uint64_t> accepted;
  for (std::uint64_t s = 0; s < 2000; ++s) {
    FrameSet set = big;
    set.index = s;
    if (rec.Submit(set)) accepted.push_back(s);
  }
  const RecorderStatus st = rec.Close();
  EXPECT_EQ(st.sets_submitted, 2000u);
  EXPECT_EQ(st.sets_recorded + st.sets_dropped, 2000u);
  EXPECT_EQ(st.sets_recorded, accepted.size());
  // Writing 0.9 MB per set takes far longer than submitting one (shared pixels, no copy).
  EXPECT_GT(st.sets_dropped, 0u);
  EXPECT_LE(st.peak_queued_bytes, o.max_queued_bytes);
  const Recording r = Recording::Open(dir.str());
  ASSERT_EQ(r.num_sets(), accepted.size());
  for (std::size_t i = 0; i < r.num_sets(); i += 97) EXPECT_EQ(r.ReadSet(i).index, accepted[i]);
}

}  // namespace
}  // namespace flamerig

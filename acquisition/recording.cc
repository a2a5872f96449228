#include "acquisition/recording.h"

#include <fcntl.h>
#include <libdeflate.h>
#include <sys/statvfs.h>
#include <unistd.h>
#include <yaml-cpp/yaml.h>

#include <algorithm>
#include <cerrno>
#include <chrono>
#include <cstring>
#include <ctime>
#include <filesystem>
#include <fstream>
#include <set>
#include <sstream>

#include "acquisition/thread_name.h"
#include "core/atomic_file.h"
#include "core/error.h"

namespace flamerig {

static_assert(__BYTE_ORDER__ == __ORDER_LITTLE_ENDIAN__, "the recording format is little-endian");

namespace fs = std::filesystem;

namespace {

constexpr char kDataMagic[8] = {'F', 'L', 'M', 'R', 'D', 'A', 'T', '1'};
constexpr char kIndexMagic[8] = {'F', 'L', 'M', 'R', 'I', 'D', 'X', '1'};
constexpr char kSetsMagic[8] = {'F', 'L', 'M', 'R', 'S', 'E', 'T', '1'};
constexpr std::size_t kFileHeader = 16;  // magic, u32 version, u32 camera (or camera count)
constexpr std::size_t kSetFixed = 48;    // "SET1", crc, seq, index, trigger, reference, spread
constexpr const char* kReserveFile = "closing.reserve";  // removed when the recording closes
constexpr off_t kReserveBytes = 256 << 10;

// CRC-32 (the polynomial of zlib and gzip: the file format's), by libdeflate, which folds with
// carry-less multiplies where the CPU has them: 11 GB/s against zlib's 3 here, so 8 x 640x480 x
// 100 fps costs 0.02 of a core instead of 0.08 (issue 24). Its values are zlib's (a test checks).
std::uint32_t Crc(const void* p, std::size_t n) {
  return static_cast<std::uint32_t>(libdeflate_crc32(0, p, n));
}

std::string Errno(int e) {
  std::string s = std::strerror(e);
  if (e == ENOSPC || e == EDQUOT) s += " (disk full)";
  if (e == EFBIG) s += " (the file size limit: `ulimit -f`, or the file system's largest file)";
  return s;
}

// Writes all of [p, p+n) or returns the errno.
int WriteAll(int fd, const void* p, std::size_t n) {
  const auto* b = static_cast<const char*>(p);
  while (n > 0) {
    const ssize_t w = ::write(fd, b, n);
    if (w < 0) {
      if (errno == EINTR) continue;
      return errno;
    }
    b += w;
    n -= static_cast<std::size_t>(w);
  }
  return 0;
}

std::vector<char> FileHeader(const char (&magic)[8], std::uint32_t value) {
  std::vector<char> h(kFileHeader, 0);
  std::memcpy(h.data(), magic, 8);
  const std::uint32_t version = 1;
  std::memcpy(h.data() + 8, &version, 4);
  std::memcpy(h.data() + 12, &value, 4);
  return h;
}

int CreateFile(const fs::path& path, const std::vector<char>& header) {
  const int fd = ::open(path.c_str(), O_WRONLY | O_CREAT | O_EXCL | O_APPEND | O_CLOEXEC, 0644);
  if (fd < 0)
    throw RecordingError("recording: cannot create " + path.string() + ": " + Errno(errno));
  if (const int e = WriteAll(fd, header.data(), header.size())) {
    ::close(fd);
    throw RecordingError("recording: cannot write " + path.string() + ": " + Errno(e));
  }
  return fd;
}

void FillRecordCrc(FrameRecord* r) {
  r->record_crc = Crc(reinterpret_cast<const char*>(r) + 8, sizeof(FrameRecord) - 8);
}
bool RecordCrcOk(const FrameRecord& r) {
  return std::memcmp(r.magic, "FRM1", 4) == 0 &&
         r.record_crc == Crc(reinterpret_cast<const char*>(&r) + 8, sizeof(FrameRecord) - 8);
}

YAML::Node SettingsNode(const CameraSettings& s) {
  YAML::Node n;
  n["width"] = s.width;
  n["height"] = s.height;
  n["pixel_format"] = ToString(s.pixel_format);
  if (!s.wire_format.empty()) n["wire_format"] = s.wire_format;  // what the camera sent
  n["frame_rate_hz"] = s.frame_rate_hz;
  n["exposure_us"] = s.exposure_us;
  n["gain_db"] = s.gain_db;
  n["trigger"] = ToString(s.trigger);
  n["trigger_source"] = s.trigger_source;
  n["packet_size"] = s.packet_size;
  n["offset_x"] = s.offset_x;
  n["offset_y"] = s.offset_y;
  for (const auto& [name, value] : s.features) n["features"][name] = value;
  return n;
}

CameraSettings SettingsFrom(const YAML::Node& n) {
  CameraSettings s;
  s.width = n["width"].as<int>();
  s.height = n["height"].as<int>();
  s.pixel_format = PixelFormatFromName(n["pixel_format"].as<std::string>());
  if (n["wire_format"]) s.wire_format = n["wire_format"].as<std::string>();
  s.frame_rate_hz = n["frame_rate_hz"].as<double>();
  s.exposure_us = n["exposure_us"].as<double>();
  s.gain_db = n["gain_db"].as<double>();
  s.trigger = TriggerModeFromName(n["trigger"].as<std::string>());
  s.trigger_source = n["trigger_source"].as<std::string>();
  s.packet_size = n["packet_size"].as<int>();
  s.offset_x = n["offset_x"].as<int>(0);
  s.offset_y = n["offset_y"].as<int>(0);
  if (n["features"])
    for (const auto& kv : n["features"])
      s.features.emplace_back(kv.first.as<std::string>(), kv.second.as<std::string>());
  return s;
}

std::string MetadataYaml(const RecordingMetadata& m, bool closed,
                         const std::map<std::string, std::string>& counters) {
  YAML::Node root;
  root["flamerig_recording"] = 1;
  root["sync_mode"] = m.sync_mode;
  root["started_realtime_ns"] = m.started_realtime_ns;
  root["trigger_rate_hz"] = m.trigger_rate_hz;
  if (!m.event_name.empty()) {
    root["event"]["name"] = m.event_name;
    root["event"]["realtime_ns"] = m.event_realtime_ns;
    root["event"]["last_pretrigger_set"] = m.event_last_ring_set;
  }
  for (const auto& c : m.cameras) {
    YAML::Node n;
    n["name"] = c.name;
    n["driver"] = c.description.driver;
    n["id"] = c.description.id;
    n["vendor"] = c.description.vendor;
    n["model"] = c.description.model;
    n["address"] = c.description.address;
    n["serial"] = c.description.serial;
    n["settings"] = SettingsNode(c.settings);
    root["cameras"].push_back(n);
  }
  for (const auto& [k, v] : m.features) root["features"][k] = v;
  root["config"] = m.config_yaml;
  root["closed"] = closed;
  for (const auto& [k, v] : counters) root["counters"][k] = v;
  YAML::Emitter out;
  out << root;
  return std::string(out.c_str()) + "\n";
}

// Writes `text` to dir/name through a temporary file, fsync and rename: never half a file.
void WriteAtomically(const fs::path& dir, const std::string& name, const std::string& text) {
  try {
    WriteFileAtomically((dir / name).string(), text);
  } catch (const IoError& e) {
    throw RecordingError(std::string("recording: ") + e.what());
  }
}

std::vector<char> SetRecordBytes(const FrameSet& h, std::uint64_t seq,
                                 const std::vector<std::int64_t>& entries) {
  std::vector<char> b(kSetFixed + 8 * entries.size(), 0);
  std::memcpy(b.data(), "SET1", 4);
  std::memcpy(b.data() + 8, &seq, 8);
  std::memcpy(b.data() + 16, &h.index, 8);
  std::memcpy(b.data() + 24, &h.trigger_id, 8);
  std::memcpy(b.data() + 32, &h.reference_ns, 8);
  std::memcpy(b.data() + 40, &h.spread_ns, 8);
  std::memcpy(b.data() + kSetFixed, entries.data(), 8 * entries.size());
  const std::uint32_t crc = Crc(b.data() + 8, b.size() - 8);
  std::memcpy(b.data() + 4, &crc, 4);
  return b;
}

// The whole file, or nullopt when it cannot be opened.
std::optional<std::vector<char>> ReadWholeFile(const fs::path& path) {
  std::ifstream in(path, std::ios::binary);
  if (!in) return std::nullopt;
  return std::vector<char>(std::istreambuf_iterator<char>(in), {});
}

// What is wrong with a file's header, or "" when it is right.
std::string HeaderProblem(const std::vector<char>& bytes, const char (&magic)[8],
                          std::uint32_t expect_value) {
  if (bytes.size() < kFileHeader || std::memcmp(bytes.data(), magic, 8) != 0)
    return "is not a flamerig recording file (bad header)";
  std::uint32_t version, value;
  std::memcpy(&version, bytes.data() + 8, 4);
  std::memcpy(&value, bytes.data() + 12, 4);
  if (version != 1)
    return "has format version " + std::to_string(version) + "; this flamerig reads version 1";
  if (value != expect_value)
    return "header says " + std::to_string(value) + ", metadata.yaml says " +
           std::to_string(expect_value);
  return "";
}

// A frame record whose fields agree with each other and with its camera.
bool RecordSane(const FrameRecord& r, int camera) {
  if (r.camera != static_cast<std::uint32_t>(camera) ||
      r.pixel_format > static_cast<std::uint32_t>(PixelFormat::kBayerBg16) ||
      r.status > static_cast<std::uint32_t>(FrameStatus::kError))
    return false;
  return r.payload_bytes == 0 ||
         r.payload_bytes ==
             std::uint64_t(r.width) * r.height *
                 BytesPerPixel(static_cast<PixelFormat>(std::min<std::uint32_t>(
                     r.pixel_format, static_cast<std::uint32_t>(PixelFormat::kBayerBg16))));
}

// The record and its pixels lie inside a data file of `data_size` bytes.
bool RecordFits(const FrameRecord& r, std::uint64_t data_size) {
  return r.offset >= kFileHeader && r.payload_bytes <= data_size &&
         r.offset <= data_size - r.payload_bytes &&
         r.offset + r.payload_bytes + sizeof(FrameRecord) <= data_size;
}

std::uint64_t RecordEnd(const FrameRecord& r) {
  return r.offset + sizeof(FrameRecord) + r.payload_bytes;
}

// Reads n bytes at `at`; false when the file is shorter.
bool ReadAt(int fd, void* p, std::size_t n, std::uint64_t at) {
  auto* b = static_cast<char*>(p);
  while (n > 0) {
    const ssize_t r = ::pread(fd, b, n, static_cast<off_t>(at));
    if (r < 0 && errno == EINTR) continue;
    if (r <= 0) return false;
    b += r;
    n -= static_cast<std::size_t>(r);
    at += static_cast<std::uint64_t>(r);
  }
  return true;
}

// The first offset in [from, limit) where an intact record of `camera` starts (its own offset
// field says so), or `limit`.
std::uint64_t NextIntactRecord(int fd, int camera, std::uint64_t from, std::uint64_t limit,
                               std::uint64_t data_size) {
  constexpr std::size_t kChunk = 1 << 20;
  std::vector<char> buf(kChunk + 3);
  for (std::uint64_t at = from; at < limit; at += kChunk) {
    const std::size_t n =
        static_cast<std::size_t>(std::min<std::uint64_t>(kChunk + 3, data_size - at));
    if (n < 4 || !ReadAt(fd, buf.data(), n, at)) break;
    for (std::size_t i = 0; i + 4 <= n && at + i < limit; ++i) {
      if (std::memcmp(buf.data() + i, "FRM1", 4) != 0) continue;
      FrameRecord r;
      if (ReadAt(fd, &r, sizeof r, at + i) && RecordCrcOk(r) && RecordSane(r, camera) &&
          r.offset == at + i && RecordFits(r, data_size))
        return at + i;
    }
  }
  return limit;
}

// A camera's frames found again by walking its data file record by record. A record header that
// is damaged is taken from `copies` (the index's entries whose checksum holds) when one starts at
// that offset; a damaged stretch is skipped up to the next intact record.
std::vector<FrameRecord> WalkDataFile(const fs::path& path, int camera, std::uint64_t data_size,
                                      const std::vector<FrameRecord>& copies,
                                      RecoveryReport* report) {
  std::map<std::uint64_t, FrameRecord> by_offset;
  for (const FrameRecord& r : copies)
    if (RecordFits(r, data_size)) by_offset.emplace(r.offset, r);
  std::vector<FrameRecord> frames;
  const int fd = ::open(path.c_str(), O_RDONLY | O_CLOEXEC);
  if (fd < 0) return frames;
  const std::string file = path.filename().string();
  std::uint64_t pos = kFileHeader, from_copies = 0;
  while (pos + sizeof(FrameRecord) <= data_size) {
    FrameRecord r;
    if (ReadAt(fd, &r, sizeof r, pos) && RecordCrcOk(r) && RecordSane(r, camera) &&
        r.offset == pos && RecordFits(r, data_size)) {
      frames.push_back(r);
      pos = RecordEnd(r);
      continue;
    }
    if (const auto it = by_offset.find(pos); it != by_offset.end()) {
      frames.push_back(it->second);
      ++from_copies;
      pos = RecordEnd(it->second);
      continue;
    }
    const auto later = by_offset.upper_bound(pos);
    const std::uint64_t limit = later == by_offset.end() ? data_size : later->first;
    const std::uint64_t next = NextIntactRecord(fd, camera, pos + 1, limit, data_size);
    report->notes.push_back(file + ": bytes " + std::to_string(pos) + " to " +
                            std::to_string(next) + " hold no intact frame record, skipped");
    report->damaged_bytes += next - pos;
    pos = next;
  }
  ::close(fd);
  if (from_copies > 0)
    report->notes.push_back(file + ": " + std::to_string(from_copies) +
                            " damaged record header(s) read from the index's copy");
  return frames;
}

// The position in `frames` (increasing sequence numbers) of the frame of set `seq`, or -1.
std::int64_t FindBySeq(const std::vector<FrameRecord>& frames, std::uint64_t seq,
                       std::int64_t hint) {
  if (hint >= 0 && static_cast<std::size_t>(hint) < frames.size() &&
      frames[static_cast<std::size_t>(hint)].set == seq)
    return hint;
  const auto it = std::lower_bound(frames.begin(), frames.end(), seq,
                                   [](const FrameRecord& r, std::uint64_t q) { return r.set < q; });
  return it != frames.end() && it->set == seq ? it - frames.begin() : -1;
}

}  // namespace

std::string CameraDataFile(int camera) {
  char b[32];
  std::snprintf(b, sizeof b, "cam%02d.data", camera);
  return b;
}
std::string CameraIndexFile(int camera) {
  char b[32];
  std::snprintf(b, sizeof b, "cam%02d.index", camera);
  return b;
}

void RecorderOptions::Validate() const {
  if (max_queued_bytes == 0) throw InputError("recorder: max_queued_bytes must be > 0");
  if (!(sync_interval_s >= 0)) throw InputError("recorder: sync_interval_s must be >= 0");
}

// ---------------------------------------------------------------------------------------------
// Recorder

struct Recorder::CameraFiles {
  int data_fd = -1, index_fd = -1;
  fs::path data_path, index_path;
  std::uint64_t data_size = kFileHeader;
  std::int64_t next_entry = 0;
  std::int64_t last_sync_ns = 0;
};

Recorder::Recorder(const std::string& directory, const RecordingMetadata& metadata,
                   const RecorderOptions& options)
    : directory_(directory), metadata_(metadata), options_(options) {
  options_.Validate();
  if (metadata_.cameras.empty()) throw InputError("recorder: no cameras");
  const fs::path dir(directory_);
  std::error_code ec;
  if (fs::exists(dir, ec) && !fs::is_empty(dir, ec)) {
    throw RecordingError("recording: " + directory_ +
                         " already exists and is not empty; choose a new name (nothing was "
                         "overwritten)");
  }
  // Below min_free_bytes a recording would stop at once: refuse it before creating anything.
  if (options_.min_free_bytes > 0) {
    fs::path probe = dir;
    while (!probe.empty() && !fs::exists(probe, ec)) probe = probe.parent_path();
    struct statvfs v;
    if (::statvfs(probe.empty() ? "." : probe.c_str(), &v) == 0) {
      const std::uint64_t free = static_cast<std::uint64_t>(v.f_bavail) * v.f_frsize;
      if (free < options_.min_free_bytes)
        throw RecordingError("recording: " + directory_ + ": only " + std::to_string(free >> 20) +
                             " MiB free on its disk, below " +
                             std::to_string(options_.min_free_bytes >> 20) +
                             " MiB (min_free_mb); nothing was recorded");
    }
  }
  const bool existed = fs::exists(dir, ec);
  fs::create_directories(dir, ec);
  if (ec) throw RecordingError("recording: cannot create " + directory_ + ": " + ec.message());
  // Room kept for the closing metadata: released by Close() just before it writes it, so a disk
  // that fills while recording still gets a metadata.yaml with `closed: true` and the counters.
  reserve_path_ = (dir / kReserveFile).string();
  const int reserve = ::open(reserve_path_.c_str(), O_WRONLY | O_CREAT | O_EXCL | O_CLOEXEC, 0600);
  // Twice the metadata as it starts (the closing one adds counters), at least 256 KiB.
  const off_t reserve_bytes = std::max<off_t>(
      kReserveBytes, 2 * static_cast<off_t>(MetadataYaml(metadata_, false, {}).size()) + 65536);
  const int reserved = reserve < 0 ? errno : ::posix_fallocate(reserve, 0, reserve_bytes);
  if (reserve >= 0) ::close(reserve);
  if (reserved != 0) {
    ::unlink(reserve_path_.c_str());
    if (!existed) fs::remove(dir, ec);
    throw RecordingError(
        "recording: " + directory_ + ": cannot reserve " + std::to_string(reserve_bytes >> 10) +
        " KiB for its closing metadata: " + Errno(reserved) + "; nothing was recorded");
  }
  WriteAtomically(dir, "metadata.yaml", MetadataYaml(metadata_, false, {}));
  const std::uint32_t n = static_cast<std::uint32_t>(metadata_.cameras.size());
  for (std::uint32_t c = 0; c < n; ++c) {
    auto files = std::make_unique<CameraFiles>();
    files->data_path = dir / CameraDataFile(c);
    files->index_path = dir / CameraIndexFile(c);
    files->data_fd = CreateFile(files->data_path, FileHeader(kDataMagic, c));
    files->index_fd = CreateFile(files->index_path, FileHeader(kIndexMagic, c));
    files->last_sync_ns = SystemClock().MonotonicNs();
    cameras_.push_back(std::move(files));
  }
  sets_fd_ = CreateFile(dir / "sets.index", FileHeader(kSetsMagic, n));
  queues_.resize(n);
  status_.max_queued_bytes = options_.max_queued_bytes;
  last_sync_ns_ = SystemClock().MonotonicNs();
  for (std::uint32_t c = 0; c < n; ++c)
    writers_.emplace_back([this, c] {
      NameThisThread("fr-write" + std::to_string(c));
      WriterLoop(c);
    });
  committer_ = std::thread([this] {
    NameThisThread("fr-commit");
    CommitterLoop();
  });
}

Recorder::~Recorder() {
  try {
    Close();
  } catch (...) {
  }
}

bool Recorder::Submit(const FrameSet& set) {
  std::lock_guard<std::mutex> lock(mutex_);
  ++status_.sets_submitted;
  if (set.frames.size() != cameras_.size()) {
    throw InputError("recorder: a frame set with " + std::to_string(set.frames.size()) +
                     " camera slots for a recording of " + std::to_string(cameras_.size()) +
                     " cameras");
  }
  // A recording of max_sets frame sets is complete: the sets that follow are not dropped, only
  // not part of it.
  if (complete_) return false;
  if (closing_ || status_.stopped) {
    ++status_.sets_dropped;
    return false;
  }
  std::uint64_t bytes = 0;
  for (std::size_t c = 0; c < set.frames.size(); ++c) {
    const auto& f = set.frames[c];
    if (!f) continue;
    const std::uint64_t expect =
        std::uint64_t(f->info.width) * f->info.height * BytesPerPixel(f->info.pixel_format);
    if (f->bytes() != 0 && f->bytes() != expect) {
      throw InputError("recorder: camera " + std::to_string(c) + " frame " +
                       std::to_string(f->info.frame_id) + ": " + std::to_string(f->bytes()) +
                       " bytes for " + std::to_string(f->info.width) + "x" +
                       std::to_string(f->info.height) + " " + ToString(f->info.pixel_format) +
                       " (expected " + std::to_string(expect) + ")");
    }
    bytes += f->bytes();
  }
  // Limits, per whole set so that everything accepted is written complete: the recording's size,
  // and the free space left on its filesystem (checked every 8 MiB). Reaching one stops accepting
  // sets; what is queued is still written.
  const std::uint64_t on_disk = bytes + sizeof(FrameRecord) * set.present();
  std::string limit;
  bool configured = true;
  if (options_.max_bytes > 0 && accepted_bytes_ + on_disk > options_.max_bytes) {
    limit = "recording " + directory_ + ": reached its size limit of " +
            std::to_string(options_.max_bytes) + " bytes";
  } else if (options_.min_free_bytes > 0 && accepted_bytes_ >= next_space_check_) {
    // Checked again after at most half the reserve has been written, so the reserve itself
    // cannot be used up between two checks (a fixed 8 MiB filled a disk with 2 MiB kept free).
    next_space_check_ =
        accepted_bytes_ + std::clamp<std::uint64_t>(options_.min_free_bytes / 2, 64 << 10, 8 << 20);
    struct statvfs v;
    if (::statvfs(directory_.c_str(), &v) == 0 &&
        static_cast<std::uint64_t>(v.f_bavail) * v.f_frsize <
            options_.min_free_bytes + status_.queued_bytes + on_disk) {
      configured = false;
      limit = "recording " + directory_ + ": the disk is nearly full (less than " +
              std::to_string(options_.min_free_bytes >> 20) + " MiB free, min_free_mb)";
    }
  }
  if (!limit.empty()) {
    status_.stopped = true;
    status_.limit_reached = configured;
    status_.error = limit + "; recording stopped (every frame set before it is readable)";
    // A limit the operator set ends the recording: the sets past it are not part of it, not
    // dropped. A nearly full disk drops them.
    if (configured)
      complete_ = true;
    else
      ++status_.sets_dropped;
    return false;
  }
  // Bounded memory: a set that does not fit is dropped whole (one set always fits an empty queue).
  if (status_.queued_bytes > 0 && status_.queued_bytes + bytes > options_.max_queued_bytes) {
    ++status_.sets_dropped;
    return false;
  }
  accepted_bytes_ += on_disk;
  const std::uint64_t seq = next_seq_++;
  Pending p;
  p.header.index = set.index;
  p.header.trigger_id = set.trigger_id;
  p.header.reference_ns = set.reference_ns;
  p.header.spread_ns = set.spread_ns;
  p.entries.assign(cameras_.size(), -1);
  for (std::size_t c = 0; c < set.frames.size(); ++c) {
    if (!set.frames[c]) continue;
    queues_[c].push_back(Job{seq, *set.frames[c]});
    ++p.remaining;
  }
  pending_.emplace(seq, std::move(p));
  status_.queued_bytes += bytes;
  status_.peak_queued_bytes = std::max(status_.peak_queued_bytes, status_.queued_bytes);
  if (options_.max_sets > 0 && next_seq_ >= options_.max_sets) {  // the last set it takes
    complete_ = true;
    status_.stopped = true;
    status_.limit_reached = true;
    status_.error = "reached its limit of " + std::to_string(options_.max_sets) + " frame sets";
  }
  CommitReady();
  work_.notify_all();
  return true;
}

void Recorder::Fail(const std::string& message) {
  const std::string stop =
      message + "; recording stopped (every frame set committed before is readable)";
  status_.error = status_.error.empty() ? stop : status_.error + "; then " + stop;
  status_.limit_reached = false;  // a write that fails is a fault, whatever limit came before
  failed_ = true;
  status_.stopped = true;
  work_.notify_all();
  idle_.notify_all();
  commit_.notify_all();
}

void Recorder::CommitReady() {
  bool any = false;
  for (;;) {
    auto it = pending_.find(next_commit_);
    if (it == pending_.end() || it->second.remaining > 0) break;
    to_commit_.push_back(SetRecordBytes(it->second.header, it->first, it->second.entries));
    pending_.erase(it);
    ++next_commit_;
    any = true;
  }
  if (any) commit_.notify_one();
}

void Recorder::CommitterLoop() {
  for (;;) {
    std::vector<std::vector<char>> batch;
    {
      std::unique_lock<std::mutex> lock(mutex_);
      commit_.wait(lock, [&] { return !to_commit_.empty() || writers_done_ || failed_; });
      // Sets whose frames are all written are committed even after a failure elsewhere.
      if (to_commit_.empty()) return;  // writers done or stopped, and nothing left
      batch.swap(to_commit_);
    }
    // Small appends to the set index; the frames they point to are already written.
    std::string failure;
    std::uint64_t written = 0;
    for (const auto& b : batch) {
      if (const int e = WriteAll(sets_fd_, b.data(), b.size())) {
        failure = "recording " + directory_ + ": writing sets.index: " + Errno(e);
        break;
      }
      ++written;
    }
    if (failure.empty() && options_.sync_interval_s > 0) {
      const std::int64_t now = SystemClock().MonotonicNs();
      if (now - last_sync_ns_ > static_cast<std::int64_t>(options_.sync_interval_s * 1e9)) {
        ::fdatasync(sets_fd_);
        last_sync_ns_ = now;
      }
    }
    std::lock_guard<std::mutex> lock(mutex_);
    status_.sets_recorded += written;
    if (!failure.empty()) Fail(failure);
    idle_.notify_all();
  }
}

void Recorder::WriterLoop(int camera) {
  CameraFiles& files = *cameras_[camera];
  for (;;) {
    std::unique_lock<std::mutex> lock(mutex_);
    work_.wait(lock, [&] { return !queues_[camera].empty() || closing_ || failed_; });
    if (failed_) {  // release what waits: it will not be written
      for (const Job& j : queues_[camera]) status_.queued_bytes -= j.frame.bytes();
      queues_[camera].clear();
      idle_.notify_all();
      return;
    }
    if (queues_[camera].empty()) {
      if (closing_) return;
      continue;
    }
    Job job = std::move(queues_[camera].front());
    queues_[camera].pop_front();
    const std::uint64_t payload = job.frame.bytes();
    const std::uint64_t record_bytes = sizeof(FrameRecord) + payload;
    std::string failure;
    lock.unlock();

    FrameRecord r{};
    std::int64_t entry = -1;
    if (failure.empty()) {
      const FrameInfo& in = job.frame.info;
      std::memcpy(r.magic, "FRM1", 4);
      r.offset = files.data_size;
      r.set = job.seq;
      r.frame_id = in.frame_id;
      r.device_frame_id = in.device_frame_id;
      r.device_timestamp_ns = in.device_timestamp_ns;
      r.host_monotonic_ns = in.host_monotonic_ns;
      r.host_realtime_ns = in.host_realtime_ns;
      r.trigger_id = in.trigger_id;
      r.exposure_us = in.exposure_us;
      r.gain_db = in.gain_db;
      r.pixel_format = static_cast<std::uint32_t>(in.pixel_format);
      r.width = static_cast<std::uint32_t>(in.width);
      r.height = static_cast<std::uint32_t>(in.height);
      r.status = static_cast<std::uint32_t>(in.status);
      r.payload_bytes = payload;
      r.payload_crc = payload ? Crc(job.frame.data->data(), payload) : 0;
      r.camera = static_cast<std::uint32_t>(camera);
      r.sent_pfnc = in.sent_pfnc;
      FillRecordCrc(&r);
      const void* pixels = payload ? job.frame.data->data() : nullptr;
      int e = WriteAll(files.data_fd, &r, sizeof r);
      if (!e && payload) e = WriteAll(files.data_fd, pixels, payload);
      if (e) {
        failure = "recording " + directory_ + ": writing " + files.data_path.filename().string() +
                  ": " + Errno(e);
      } else if (const int e2 = WriteAll(files.index_fd, &r, sizeof r)) {
        failure = "recording " + directory_ + ": writing " + files.index_path.filename().string() +
                  ": " + Errno(e2);
      } else {
        files.data_size += record_bytes;
        entry = files.next_entry++;
      }
    }
    job.frame.data.reset();  // the pixels are on disk (or will never be): release them
    if (failure.empty() && options_.sync_interval_s > 0) {
      const std::int64_t now = SystemClock().MonotonicNs();
      if (now - files.last_sync_ns > static_cast<std::int64_t>(options_.sync_interval_s * 1e9)) {
        ::fdatasync(files.data_fd);
        ::fdatasync(files.index_fd);
        files.last_sync_ns = now;
      }
    }

    lock.lock();
    status_.queued_bytes -= payload;
    if (!failure.empty()) {
      Fail(failure);
    } else {
      ++status_.frames_recorded;
      status_.bytes_written += record_bytes;
      Pending& p = pending_.at(job.seq);
      p.entries[camera] = entry;
      --p.remaining;
      CommitReady();
    }
    idle_.notify_all();
  }
}

void Recorder::SyncAll() {
  for (auto& f : cameras_) {
    ::fdatasync(f->data_fd);
    ::fdatasync(f->index_fd);
  }
  ::fdatasync(sets_fd_);
}

RecorderStatus Recorder::status() const {
  std::lock_guard<std::mutex> lock(mutex_);
  return status_;
}

RecorderStatus Recorder::Close(const std::map<std::string, std::string>& extra) {
  {
    std::unique_lock<std::mutex> lock(mutex_);
    if (closed_) return status_;
    closing_ = true;
    work_.notify_all();
  }
  for (auto& t : writers_) t.join();
  writers_.clear();
  {
    std::lock_guard<std::mutex> lock(mutex_);
    writers_done_ = true;
    commit_.notify_all();
  }
  if (committer_.joinable()) committer_.join();
  std::unique_lock<std::mutex> lock(mutex_);
  SyncAll();
  for (auto& f : cameras_) {
    ::close(f->data_fd);
    ::close(f->index_fd);
  }
  ::close(sets_fd_);
  closed_ = true;
  ::unlink(reserve_path_.c_str());  // the room kept for what follows
  std::map<std::string, std::string> counters = {
      {"sets_submitted", std::to_string(status_.sets_submitted)},
      {"sets_recorded", std::to_string(status_.sets_recorded)},
      {"sets_dropped", std::to_string(status_.sets_dropped)},
      {"frames_recorded", std::to_string(status_.frames_recorded)},
      {"bytes_written", std::to_string(status_.bytes_written)},
      {"peak_queued_bytes", std::to_string(status_.peak_queued_bytes)},
      // A fault and a configured limit apart: `error` is empty when a limit ended the recording.
      {"error", status_.limit_reached ? "" : status_.error},
      {"limit_reached", status_.limit_reached ? status_.error : ""}};
  counters.insert(extra.begin(), extra.end());
  try {
    WriteAtomically(directory_, "metadata.yaml", MetadataYaml(metadata_, true, counters));
  } catch (const RecordingError& e) {
    // The frames are safe; only the closing note could not be written (a full disk, most often).
    // A fault, even after a limit the operator set.
    if (status_.error.empty() || status_.limit_reached) {
      status_.error = status_.error.empty() ? e.what() : status_.error + "; then " + e.what();
      status_.limit_reached = false;
    }
  }
  return status_;
}

// ---------------------------------------------------------------------------------------------
// Recording

Recording Recording::Open(const std::string& directory) {
  Recording rec;
  rec.directory_ = directory;
  const fs::path dir(directory);
  if (!fs::is_directory(dir))
    throw RecordingError("recording: " + directory + " is not a directory");
  const fs::path meta_path = dir / "metadata.yaml";
  if (!fs::exists(meta_path))
    throw RecordingError("recording: " + directory +
                         " has no metadata.yaml: not a flamerig recording");
  try {
    const YAML::Node root = YAML::LoadFile(meta_path.string());
    if (!root["flamerig_recording"] || root["flamerig_recording"].as<int>() != 1)
      throw RecordingError("recording: " + meta_path.string() + " is not a version 1 recording");
    RecordingMetadata& m = rec.metadata_;
    m.sync_mode = root["sync_mode"].as<std::string>("");
    m.started_realtime_ns = root["started_realtime_ns"].as<std::int64_t>(0);
    m.trigger_rate_hz = root["trigger_rate_hz"].as<double>(0);
    if (const YAML::Node e = root["event"]) {
      m.event_name = e["name"].as<std::string>("");
      m.event_realtime_ns = e["realtime_ns"].as<std::int64_t>(0);
      m.event_last_ring_set = e["last_pretrigger_set"].as<std::int64_t>(-1);
    }
    m.config_yaml = root["config"].as<std::string>("");
    if (!root["cameras"] || !root["cameras"].IsSequence() || root["cameras"].size() == 0)
      throw RecordingError("recording: " + meta_path.string() + " lists no cameras");
    for (const auto& n : root["cameras"]) {
      RecordingCamera c;
      c.name = n["name"].as<std::string>();
      c.description.driver = n["driver"].as<std::string>("");
      c.description.id = n["id"].as<std::string>("");
      c.description.vendor = n["vendor"].as<std::string>("");
      c.description.model = n["model"].as<std::string>("");
      c.description.address = n["address"].as<std::string>("");
      c.description.serial = n["serial"].as<std::string>("");
      c.settings = SettingsFrom(n["settings"]);
      m.cameras.push_back(c);
    }
    if (root["features"])
      for (const auto& kv : root["features"])
        m.features[kv.first.as<std::string>()] = kv.second.as<std::string>();
    rec.recovery_.closed_cleanly = root["closed"].as<bool>(false);
    if (root["counters"])
      for (const auto& kv : root["counters"])
        rec.final_counters_[kv.first.as<std::string>()] = kv.second.as<std::string>();
  } catch (const YAML::Exception& e) {
    throw RecordingError("recording: " + meta_path.string() + ": " + e.what());
  } catch (const InputError& e) {
    throw RecordingError("recording: " + meta_path.string() + ": " + e.what());
  }
  const int n = rec.num_cameras();
  // metadata.yaml lists every camera the take holds. One cut short (or edited) may list fewer
  // and still parse: the files of a camera it does not list, or a sets.index that records more
  // cameras a set, say so. Read as it is, that take lost a whole camera with only a warning
  // (2026-12-02); its frames are intact, and it is metadata.yaml that must be restored.
  {
    std::vector<std::string> unlisted;
    for (int c = n; c < n + 64; ++c)
      for (const std::string& file : {CameraDataFile(c), CameraIndexFile(c)})
        if (fs::exists(dir / file)) unlisted.push_back(file);
    std::uint32_t per_set = 0;
    char header[kFileHeader] = {};
    std::ifstream sets(dir / "sets.index", std::ios::binary);
    if (sets.read(header, kFileHeader) && std::memcmp(header, kSetsMagic, 8) == 0)
      std::memcpy(&per_set, header + 12, 4);
    if (!unlisted.empty() || per_set > static_cast<std::uint32_t>(n)) {
      std::string what;
      if (!unlisted.empty()) {
        what = "the take holds ";
        for (std::size_t i = 0; i < unlisted.size(); ++i) what += (i ? ", " : "") + unlisted[i];
        what += " of a camera it does not list";
      }
      if (per_set > static_cast<std::uint32_t>(n))
        what += std::string(what.empty() ? "" : ", and ") + "sets.index records " +
                std::to_string(per_set) + " cameras a set";
      throw RecordingError("recording: " + meta_path.string() + " lists " + std::to_string(n) +
                           " camera(s), but " + what +
                           ": metadata.yaml is damaged or cut short (the frames are "
                           "untouched; restore it from a copy of the take)");
    }
  }
  RecoveryReport& report = rec.recovery_;
  rec.frames_.resize(n);
  // ---- Each camera's frames: from its index, or found again in its data file.
  std::vector<bool> have_data(n, false), walked(n, false);
  std::vector<std::uint64_t> data_sizes(n, 0);
  std::vector<std::vector<FrameRecord>> copies(n);  // index entries whose checksum holds
  auto walk = [&](int c, const std::string& why) {
    const fs::path data_path = dir / CameraDataFile(c);
    report.notes.push_back(CameraIndexFile(c) + ": " + why + "; its frames found again in " +
                           CameraDataFile(c));
    rec.frames_[c] = WalkDataFile(data_path, c, data_sizes[c], copies[c], &report);
    walked[c] = true;
    report.rebuilt_indexes.push_back(c);
  };
  for (int c = 0; c < n; ++c) {
    const fs::path index_path = dir / CameraIndexFile(c), data_path = dir / CameraDataFile(c);
    const std::string& name = rec.metadata_.cameras[c].name;
    std::error_code ec;
    data_sizes[c] = fs::file_size(data_path, ec);
    have_data[c] = !ec;
    if (!have_data[c]) {
      data_sizes[c] = 0;
      report.notes.push_back(CameraDataFile(c) + " (camera " + name +
                             ") is missing or unreadable: its frames are lost");
      continue;
    }
    const std::optional<std::vector<char>> index = ReadWholeFile(index_path);
    std::string problem = index ? HeaderProblem(*index, kIndexMagic, static_cast<std::uint32_t>(c))
                                : std::string("is missing or unreadable");
    std::vector<FrameRecord> entries;
    std::string torn;
    std::size_t tail = 0;
    if (problem.empty()) {
      const std::size_t count = (index->size() - kFileHeader) / sizeof(FrameRecord);
      tail = (index->size() - kFileHeader) % sizeof(FrameRecord);
      for (std::size_t e = 0; e < count; ++e) {
        FrameRecord r;
        const std::size_t at = kFileHeader + e * sizeof(FrameRecord);
        std::memcpy(&r, index->data() + at, sizeof r);
        const bool intact = RecordCrcOk(r) && RecordSane(r, c);
        const bool fits = RecordFits(r, data_sizes[c]);
        if (intact) copies[c].push_back(r);
        if (intact && fits && (entries.empty() || r.set > entries.back().set)) {
          if (problem.empty() && torn.empty()) entries.push_back(r);
          continue;
        }
        const std::string what = !intact ? std::string("checksum mismatch")
                                 : !fits
                                     ? "its frame lies past the end of " + CameraDataFile(c)
                                     : std::string("out of order (its set number does not rise)");
        if (e + 1 == count && problem.empty()) {
          torn = what;  // torn by an interrupted write: ignored
        } else if (problem.empty()) {
          problem = "entry " + std::to_string(e) + " at byte " + std::to_string(at) +
                    " is corrupt (" + what + ")";
        }
      }
    }
    if (!problem.empty()) {
      walk(c, problem);
      continue;
    }
    rec.frames_[c] = std::move(entries);
    if (!torn.empty()) {
      report.notes.push_back(CameraIndexFile(c) + ": last entry incomplete (" +
                             (torn == "checksum mismatch" ? "checksum" : "its frame is cut short") +
                             "), ignored");
      report.ignored_bytes += sizeof(FrameRecord);
    }
    if (tail) {
      report.notes.push_back(CameraIndexFile(c) + ": " + std::to_string(tail) +
                             " bytes of a torn entry at the end, ignored");
      report.ignored_bytes += tail;
    }
  }
  // ---- The sets: their records, and those rebuilt from their frames.
  const fs::path sets_path = dir / "sets.index";
  const std::optional<std::vector<char>> sets = ReadWholeFile(sets_path);
  std::string sets_problem = sets ? HeaderProblem(*sets, kSetsMagic, static_cast<std::uint32_t>(n))
                                  : std::string("is missing or unreadable");
  const std::size_t record = kSetFixed + 8 * static_cast<std::size_t>(n);
  struct Parsed {
    SetEntry entry;
    bool rebuild = false;  // its record is damaged: made again from its frames
  };
  std::vector<Parsed> parsed;
  if (sets_problem.empty()) {
    const std::size_t count = (sets->size() - kFileHeader) / record;
    for (std::size_t s = 0; s < count; ++s) {
      const std::size_t at = kFileHeader + s * record;
      const char* b = sets->data() + at;
      std::uint32_t crc;
      std::memcpy(&crc, b + 4, 4);
      Parsed p;
      p.entry.entries.resize(n);
      std::memcpy(&p.entry.seq, b + 8, 8);
      std::memcpy(p.entry.entries.data(), b + kSetFixed, 8 * n);
      bool ok = std::memcmp(b, "SET1", 4) == 0 && crc == Crc(b + 8, record - 8);
      for (int c = 0; ok && c < n; ++c) ok = p.entry.entries[c] >= -1;
      if (ok && !parsed.empty()) ok = p.entry.seq > parsed.back().entry.seq;
      if (!ok) {
        if (s + 1 == count) {
          report.notes.push_back("sets.index: last set record incomplete, ignored");
          report.ignored_bytes += record;
          break;
        }
        report.notes.push_back("sets.index: set record " + std::to_string(s) + " at byte " +
                               std::to_string(at) + " is corrupt; rebuilt from its frames");
        p.rebuild = true;
        p.entry.seq = parsed.empty() ? 0 : parsed.back().entry.seq + 1;
        parsed.push_back(std::move(p));
        continue;
      }
      std::memcpy(&p.entry.header.index, b + 16, 8);
      std::memcpy(&p.entry.header.trigger_id, b + 24, 8);
      std::memcpy(&p.entry.header.reference_ns, b + 32, 8);
      std::memcpy(&p.entry.header.spread_ns, b + 40, 8);
      parsed.push_back(std::move(p));
    }
    if (const std::size_t sets_tail = (sets->size() - kFileHeader) % record) {
      report.notes.push_back("sets.index: " + std::to_string(sets_tail) +
                             " bytes of a torn record at the end, ignored");
      report.ignored_bytes += sets_tail;
    }
  }
  // A frame a set record names but the index does not hold: that camera's index stops short
  // (truncated) or lost it; walk its data file once before calling the frame lost.
  for (const Parsed& p : parsed) {
    if (p.rebuild) continue;
    for (int c = 0; c < n; ++c) {
      const std::int64_t e = p.entry.entries[c];
      if (e < 0 || walked[c] || !have_data[c] || FindBySeq(rec.frames_[c], p.entry.seq, e) >= 0)
        continue;
      walk(c, "holds no entry for set " + std::to_string(p.entry.seq) +
                  " that sets.index names (entry " + std::to_string(e) + ")");
    }
  }
  // Sets the recording had but whose records are gone: metadata.yaml's count says how many when
  // the recorder closed it; otherwise every set whose frames are all on disk.
  std::uint64_t next_seq = parsed.empty() ? 0 : parsed.back().entry.seq + 1;
  std::uint64_t recorded = 0;
  if (const auto it = rec.final_counters_.find("sets_recorded"); it != rec.final_counters_.end())
    recorded = std::strtoull(it->second.c_str(), nullptr, 10);
  if (!parsed.empty() && next_seq == 0) {  // the last set's number is the largest there is
    recorded = 0;
    next_seq = ~std::uint64_t(0);
  }
  const bool rebuild_tail = !sets_problem.empty() || next_seq < recorded;
  if (!sets_problem.empty())
    report.notes.push_back("sets.index " + sets_problem + "; the sets rebuilt from their frames");
  else if (next_seq < recorded)
    report.notes.push_back("sets.index holds " + std::to_string(next_seq) +
                           " sets where metadata.yaml says " + std::to_string(recorded) +
                           " were recorded; the rest rebuilt from their frames");
  if (rebuild_tail) {
    for (int c = 0; c < n; ++c)
      if (!walked[c] && have_data[c]) walk(c, "may stop short, as sets.index does");
    std::set<std::uint64_t> seqs;  // of the sets to rebuild
    if (recorded > 0) {            // the committed ones: each of which a frame survives
      for (const auto& frames : rec.frames_)
        for (const FrameRecord& r : frames)
          if (r.set >= next_seq && r.set < recorded) seqs.insert(r.set);
      if (seqs.size() < recorded - next_seq)
        report.notes.push_back(std::to_string(recorded - next_seq - seqs.size()) +
                               " set(s) metadata.yaml counts have no frame left on disk");
    } else {
      for (std::uint64_t q = next_seq; rec.WholeSet(q); ++q) seqs.insert(q);
    }
    for (const std::uint64_t q : seqs) {
      Parsed p;
      p.rebuild = true;
      p.entry.seq = q;
      p.entry.entries.assign(n, -1);
      parsed.push_back(std::move(p));
    }
  }
  // The index's intact copies by set (a lost frame's reason says where it was).
  std::vector<std::map<std::uint64_t, const FrameRecord*>> copy_by_set(n);
  for (int c = 0; c < n; ++c)
    for (const FrameRecord& r : copies[c]) copy_by_set[c].emplace(r.set, &r);
  // ---- Each set's frames, by the sequence number every frame record carries.
  std::uint64_t previous_index = 0;
  bool any = false;
  for (Parsed& p : parsed) {
    SetEntry& entry = p.entry;
    const std::size_t i = rec.sets_.size();
    for (int c = 0; c < n; ++c) {
      const std::int64_t e = entry.entries[c];
      if (!p.rebuild && e < 0) continue;  // the camera missed the set
      const std::int64_t at = FindBySeq(rec.frames_[c], entry.seq, e);
      if (at >= 0 || p.rebuild) {
        entry.entries[c] = at;
        continue;
      }
      entry.entries[c] = kLost;
      ++report.lost_frames;
      std::string why = have_data[c] ? CameraDataFile(c) + " holds no intact record of it"
                                     : CameraDataFile(c) + " is missing";
      if (const auto it = copy_by_set[c].find(entry.seq);
          it != copy_by_set[c].end() && have_data[c] && !RecordFits(*it->second, data_sizes[c]))
        why = CameraDataFile(c) + " ends at byte " + std::to_string(data_sizes[c]) +
              ", before this frame (bytes " + std::to_string(it->second->offset) + " to " +
              std::to_string(RecordEnd(*it->second)) + ")";
      rec.lost_[{i, c}] = why;
    }
    if (p.rebuild) {
      entry.header = rec.HeaderFromFrames(entry, any ? previous_index + 1 : entry.seq);
      ++report.rebuilt_sets;
    }
    previous_index = entry.header.index;
    any = true;
    rec.sets_.push_back(std::move(entry));
  }
  if (report.lost_frames > 0)
    report.notes.push_back(std::to_string(report.lost_frames) +
                           " frame(s) named by the sets are lost; their sets' other frames read");
  const std::uint64_t last_seq = rec.sets_.empty() ? 0 : rec.sets_.back().seq;
  for (int c = 0; c < n; ++c) {
    std::size_t uncommitted = 0;
    std::uint64_t end = kFileHeader;
    for (const FrameRecord& r : rec.frames_[c]) {
      if (rec.sets_.empty() || r.set > last_seq) ++uncommitted;
      end = std::max(end, RecordEnd(r));
    }
    if (uncommitted > 0)
      report.notes.push_back(CameraIndexFile(c) + ": " + std::to_string(uncommitted) +
                             " frames of sets that were never committed, ignored");
    if (have_data[c] && !walked[c] && data_sizes[c] > end) {
      report.notes.push_back(CameraDataFile(c) + ": " + std::to_string(data_sizes[c] - end) +
                             " bytes after the last indexed frame, ignored");
      report.ignored_bytes += data_sizes[c] - end;
    }
  }
  report.sets = rec.sets_.size();
  return rec;
}

bool Recording::WholeSet(std::uint64_t seq) const {
  if (seq == ~std::uint64_t(0)) return false;  // the numbering's end: nothing follows it
  bool any = false;
  for (const auto& frames : frames_) {
    if (frames.empty() || frames.back().set < seq) return false;  // not written that far
    any = any || FindBySeq(frames, seq, -1) >= 0;
  }
  return any;
}

FrameSet Recording::HeaderFromFrames(const SetEntry& entry, std::uint64_t index) const {
  FrameSet h;
  h.index = index;
  bool first = true;
  std::int64_t lo = 0, hi = 0;
  for (std::size_t c = 0; c < frames_.size(); ++c) {
    if (entry.entries[c] < 0) continue;
    const FrameRecord& r = frames_[c][static_cast<std::size_t>(entry.entries[c])];
    if (first) {
      h.trigger_id = r.trigger_id;
      lo = hi = r.device_timestamp_ns;
    } else if (h.trigger_id != r.trigger_id) {
      h.trigger_id = -1;
    }
    lo = std::min(lo, r.device_timestamp_ns);
    hi = std::max(hi, r.device_timestamp_ns);
    first = false;
  }
  h.reference_ns = lo;
  h.spread_ns = hi - lo;
  return h;
}

FrameSet Recording::ReadSet(std::size_t i) const {
  FrameSet set = SetHeader(i);
  set.frames.resize(num_cameras());
  for (int c = 0; c < num_cameras(); ++c) set.frames[c] = ReadFrame(i, c);
  return set;
}

FrameSet Recording::SetHeader(std::size_t i) const {
  if (i >= sets_.size()) {
    throw std::out_of_range("recording " + directory_ + ": frame set " + std::to_string(i) +
                            " of " + std::to_string(sets_.size()));
  }
  return sets_[i].header;
}

std::optional<Frame> Recording::ReadFrame(std::size_t i, int c) const {
  if (i >= sets_.size() || c < 0 || c >= num_cameras()) {
    throw std::out_of_range("recording " + directory_ + ": frame set " + std::to_string(i) +
                            " camera " + std::to_string(c) + " is not in the recording");
  }
  const SetEntry& e = sets_[i];
  const fs::path path = fs::path(directory_) / CameraDataFile(c);
  if (e.entries[c] == kLost) {
    throw RecordingError("recording: " + path.string() + ": the frame of set " + std::to_string(i) +
                         " (camera " + metadata_.cameras[c].name +
                         ") is lost: " + lost_.at({i, c}));
  }
  if (e.entries[c] < 0) return std::nullopt;
  const FrameRecord& r = frames_[c][static_cast<std::size_t>(e.entries[c])];
  std::ifstream in(path, std::ios::binary);
  FrameRecord on_disk;
  auto pixels = std::make_shared<std::vector<std::uint8_t>>(r.payload_bytes);
  in.seekg(static_cast<std::streamoff>(r.offset));
  in.read(reinterpret_cast<char*>(&on_disk), sizeof on_disk);
  in.read(reinterpret_cast<char*>(pixels->data()), static_cast<std::streamsize>(r.payload_bytes));
  const std::string where = path.string() + ": frame " + std::to_string(r.frame_id) + " (set " +
                            std::to_string(i) + ") at byte " + std::to_string(r.offset);
  if (!in) throw RecordingError("recording: " + where + ": cut short");
  // A damaged copy of the header in the data file is no reason to lose the frame: the index's
  // copy describes it. An intact one that differs means the two files disagree.
  if (RecordCrcOk(on_disk) && std::memcmp(&on_disk, &r, sizeof r) != 0)
    throw RecordingError("recording: " + where + ": record header differs from the index");
  if (Crc(pixels->data(), pixels->size()) != r.payload_crc)
    throw RecordingError("recording: " + where + ": pixel checksum mismatch");
  Frame f;
  f.info.camera = c;
  f.info.frame_id = r.frame_id;
  f.info.device_frame_id = r.device_frame_id;
  f.info.device_timestamp_ns = r.device_timestamp_ns;
  f.info.host_monotonic_ns = r.host_monotonic_ns;
  f.info.host_realtime_ns = r.host_realtime_ns;
  f.info.trigger_id = r.trigger_id;
  f.info.exposure_us = r.exposure_us;
  f.info.gain_db = r.gain_db;
  f.info.pixel_format = static_cast<PixelFormat>(r.pixel_format);
  f.info.width = static_cast<int>(r.width);
  f.info.height = static_cast<int>(r.height);
  f.info.status = static_cast<FrameStatus>(r.status);
  f.info.sent_pfnc = r.sent_pfnc;
  f.data = std::move(pixels);
  return f;
}

bool Recording::HasFrame(std::size_t i, int c) const {
  return i < sets_.size() && c >= 0 && c < num_cameras() && sets_[i].entries[c] >= 0;
}

bool Recording::FrameLost(std::size_t i, int c) const {
  return i < sets_.size() && c >= 0 && c < num_cameras() && sets_[i].entries[c] == kLost;
}

std::vector<std::uint64_t> Recording::MissingByFrameId() const {
  std::vector<std::uint64_t> missing(num_cameras(), 0);
  for (int c = 0; c < num_cameras(); ++c) {
    const auto& f = frames_[c];
    for (std::size_t k = 1; k < f.size(); ++k)
      if (f[k].frame_id > f[k - 1].frame_id + 1)
        missing[c] += f[k].frame_id - f[k - 1].frame_id - 1;
  }
  return missing;
}

RecoveryReport RebuildIndexes(const std::string& directory) {
  Recording rec = Recording::Open(directory);
  RecoveryReport report = rec.recovery_;
  const int n = rec.num_cameras();
  // Sets the recorder never committed whose frames all reached the disk.
  const bool at_end = !rec.sets_.empty() && rec.sets_.back().seq == ~std::uint64_t(0);
  for (std::uint64_t seq = rec.sets_.empty() ? 0 : rec.sets_.back().seq + 1;
       !at_end && rec.WholeSet(seq); ++seq) {
    Recording::SetEntry entry;
    entry.seq = seq;
    entry.entries.resize(n);
    for (int c = 0; c < n; ++c) entry.entries[c] = FindBySeq(rec.frames_[c], seq, -1);
    entry.header =
        rec.HeaderFromFrames(entry, rec.sets_.empty() ? seq : rec.sets_.back().header.index + 1);
    rec.sets_.push_back(std::move(entry));
    ++report.added_sets;
  }
  if (report.added_sets > 0)
    report.notes.push_back(std::to_string(report.added_sets) +
                           " set(s) never committed but whole on disk, taken in");
  // Every frame's pixels against their checksum: what the rebuilt recording holds is readable.
  for (std::size_t i = 0; i < rec.sets_.size(); ++i) {
    for (int c = 0; c < n; ++c) {
      if (!rec.HasFrame(i, c)) continue;
      try {
        rec.ReadFrame(i, c);
      } catch (const RecordingError& e) {
        ++report.corrupt_frames;
        report.notes.push_back(std::string(e.what()).substr(std::strlen("recording: ")));
      }
    }
  }
  // The new indexes: every intact frame of each data file, in data order.
  std::vector<std::string> index_bytes(n);
  for (int c = 0; c < n; ++c) {
    const std::vector<char> header = FileHeader(kIndexMagic, static_cast<std::uint32_t>(c));
    index_bytes[c].assign(header.begin(), header.end());
    for (const FrameRecord& r : rec.frames_[c])
      index_bytes[c].append(reinterpret_cast<const char*>(&r), sizeof r);
  }
  const std::vector<char> sets_header = FileHeader(kSetsMagic, static_cast<std::uint32_t>(n));
  std::string sets_bytes(sets_header.begin(), sets_header.end());
  for (const auto& s : rec.sets_) {
    std::vector<std::int64_t> entries(n);
    for (int c = 0; c < n; ++c) entries[c] = std::max<std::int64_t>(s.entries[c], -1);
    const std::vector<char> b = SetRecordBytes(s.header, s.seq, entries);
    sets_bytes.append(b.data(), b.size());
  }
  // The old indexes kept aside, then the new ones in place (each replaced atomically).
  const fs::path dir(directory);
  char stamp[32];
  const std::time_t now = std::time(nullptr);
  std::tm tm{};
  ::gmtime_r(&now, &tm);
  std::strftime(stamp, sizeof stamp, "%Y%m%dT%H%M%SZ", &tm);
  fs::path aside = dir / ("replaced_indexes_" + std::string(stamp));
  try {
    // A folder of its own, never one an earlier recover filled (twice in one second: _2, _3...).
    for (int k = 2; !fs::create_directory(aside); ++k)
      aside = dir / ("replaced_indexes_" + std::string(stamp) + "_" + std::to_string(k));
    std::vector<std::string> names = {"sets.index"};
    for (int c = 0; c < n; ++c) names.push_back(CameraIndexFile(c));
    for (const auto& name : names)
      if (fs::exists(dir / name))
        CopyFileAtomically((dir / name).string(), (aside / name).string());
    for (int c = 0; c < n; ++c)
      WriteFileAtomically((dir / CameraIndexFile(c)).string(), index_bytes[c]);
    WriteFileAtomically((dir / "sets.index").string(), sets_bytes);
    // The new indexes cannot mark a lost frame (its set reads as without that camera): they are
    // listed here, as the damaged ones are in the notes.
    if (!rec.lost_.empty()) {
      std::string csv = "set,camera,reason\n";
      for (const auto& [where, why] : rec.lost_)
        csv += std::to_string(where.first) + "," + rec.metadata_.cameras[where.second].name +
               ",\"" + why + "\"\n";
      WriteFileAtomically((dir / "lost_frames.csv").string(), csv);
      report.notes.push_back(std::to_string(rec.lost_.size()) +
                             " lost frame(s) listed in lost_frames.csv; after this recover their "
                             "sets read as without those cameras");
    }
  } catch (const std::exception& e) {
    throw RecordingError("recording: " + directory + ": writing the rebuilt indexes: " + e.what());
  }
  report.notes.push_back("the replaced index files are in " + aside.string());
  report.sets = rec.sets_.size();
  return report;
}

}  // namespace flamerig

#include "acquisition/recording.h"

#include <fcntl.h>
#include <sys/statvfs.h>
#include <unistd.h>
#include <yaml-cpp/yaml.h>
#include <zlib.h>

#include <algorithm>
#include <cerrno>
#include <chrono>
#include <cstring>
#include <filesystem>
#include <fstream>
#include <sstream>

#include "core/atomic_file.h"
#include "core/error.h"
#include "acquisition/thread_name.h"

namespace flamerig {

static_assert(__BYTE_ORDER__ == __ORDER_LITTLE_ENDIAN__, "the recording format is little-endian");

namespace fs = std::filesystem;

namespace {

constexpr char kDataMagic[8] = {'F', 'L', 'M', 'R', 'D', 'A', 'T', '1'};
constexpr char kIndexMagic[8] = {'F', 'L', 'M', 'R', 'I', 'D', 'X', '1'};
constexpr char kSetsMagic[8] = {'F', 'L', 'M', 'R', 'S', 'E', 'T', '1'};
constexpr std::size_t kFileHeader = 16;  // magic, u32 version, u32 camera (or camera count)
constexpr std::size_t kSetFixed = 48;    // "SET1", crc, seq, index, trigger, reference, spread

std::uint32_t Crc(const void* p, std::size_t n) {
  return static_cast<std::uint32_t>(crc32_z(0, static_cast<const Bytef*>(p), n));
}

std::string Errno(int e) {
  std::string s = std::strerror(e);
  if (e == ENOSPC || e == EDQUOT || e == EFBIG) s += " (disk full)";
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
  n["frame_rate_hz"] = s.frame_rate_hz;
  n["exposure_us"] = s.exposure_us;
  n["gain_db"] = s.gain_db;
  n["trigger"] = ToString(s.trigger);
  n["trigger_source"] = s.trigger_source;
  n["packet_size"] = s.packet_size;
  return n;
}

CameraSettings SettingsFrom(const YAML::Node& n) {
  CameraSettings s;
  s.width = n["width"].as<int>();
  s.height = n["height"].as<int>();
  s.pixel_format = PixelFormatFromName(n["pixel_format"].as<std::string>());
  s.frame_rate_hz = n["frame_rate_hz"].as<double>();
  s.exposure_us = n["exposure_us"].as<double>();
  s.gain_db = n["gain_db"].as<double>();
  s.trigger = TriggerModeFromName(n["trigger"].as<std::string>());
  s.trigger_source = n["trigger_source"].as<std::string>();
  s.packet_size = n["packet_size"].as<int>();
  return s;
}

std::string MetadataYaml(const RecordingMetadata& m, bool closed,
                         const std::map<std::string, std::string>& counters) {
  YAML::Node root;
  root["flamerig_recording"] = 1;
  root["sync_mode"] = m.sync_mode;
  root["started_realtime_ns"] = m.started_realtime_ns;
  for (const auto& c : m.cameras) {
    YAML::Node n;
    n["name"] = c.name;
    n["driver"] = c.description.driver;
    n["id"] = c.description.id;
    n["vendor"] = c.description.vendor;
    n["model"] = c.description.model;
    n["address"] = c.description.address;
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

std::vector<char> ReadWholeFile(const fs::path& path) {
  std::ifstream in(path, std::ios::binary);
  if (!in) throw RecordingError("recording: cannot open " + path.string());
  return std::vector<char>(std::istreambuf_iterator<char>(in), {});
}

void CheckFileHeader(const std::vector<char>& bytes, const char (&magic)[8],
                     std::uint32_t expect_value, const fs::path& path) {
  if (bytes.size() < kFileHeader || std::memcmp(bytes.data(), magic, 8) != 0) {
    throw RecordingError("recording: " + path.string() +
                         " is not a flamerig recording file (bad header)");
  }
  std::uint32_t version, value;
  std::memcpy(&version, bytes.data() + 8, 4);
  std::memcpy(&value, bytes.data() + 12, 4);
  if (version != 1) {
    throw RecordingError("recording: " + path.string() + " has format version " +
                         std::to_string(version) + "; this flamerig reads version 1");
  }
  if (value != expect_value) {
    throw RecordingError("recording: " + path.string() + " header says " + std::to_string(value) +
                         ", metadata.yaml says " + std::to_string(expect_value));
  }
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
  if (!(sync_interval_s >= 0))
    throw InputError("recorder: sync_interval_s must be >= 0");
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
  fs::create_directories(dir, ec);
  if (ec) throw RecordingError("recording: cannot create " + directory_ + ": " + ec.message());
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
                                " camera slots for a recording of " +
                                std::to_string(cameras_.size()) + " cameras");
  }
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
      throw InputError(
          "recorder: camera " + std::to_string(c) + " frame " + std::to_string(f->info.frame_id) +
          ": " + std::to_string(f->bytes()) + " bytes for " + std::to_string(f->info.width) + "x" +
          std::to_string(f->info.height) + " " + ToString(f->info.pixel_format) + " (expected " +
          std::to_string(expect) + ")");
    }
    bytes += f->bytes();
  }
  // Limits, per whole set so that everything accepted is written complete: the recording's size,
  // and the free space left on its filesystem (checked every 8 MiB). Reaching one stops accepting
  // sets; what is queued is still written.
  const std::uint64_t on_disk = bytes + sizeof(FrameRecord) * set.present();
  std::string limit;
  if (options_.max_bytes > 0 && accepted_bytes_ + on_disk > options_.max_bytes) {
    limit = "recording " + directory_ + ": reached its size limit of " +
            std::to_string(options_.max_bytes) + " bytes";
  } else if (options_.min_free_bytes > 0 && accepted_bytes_ >= next_space_check_) {
    next_space_check_ = accepted_bytes_ + (8ull << 20);
    struct statvfs v;
    if (::statvfs(directory_.c_str(), &v) == 0 &&
        static_cast<std::uint64_t>(v.f_bavail) * v.f_frsize <
            options_.min_free_bytes + status_.queued_bytes + on_disk) {
      limit = "recording " + directory_ + ": the disk is nearly full (less than " +
              std::to_string(options_.min_free_bytes >> 20) + " MiB free, min_free_bytes)";
    }
  }
  if (!limit.empty()) {
    status_.stopped = true;
    status_.error = limit + "; recording stopped (every frame set before it is readable)";
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
  CommitReady();
  work_.notify_all();
  return true;
}

void Recorder::Fail(const std::string& message) {
  const std::string stop =
      message + "; recording stopped (every frame set committed before is readable)";
  status_.error = status_.error.empty() ? stop : status_.error + "; then " + stop;
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

RecorderStatus Recorder::Close() {
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
  std::map<std::string, std::string> counters = {
      {"sets_submitted", std::to_string(status_.sets_submitted)},
      {"sets_recorded", std::to_string(status_.sets_recorded)},
      {"sets_dropped", std::to_string(status_.sets_dropped)},
      {"frames_recorded", std::to_string(status_.frames_recorded)},
      {"bytes_written", std::to_string(status_.bytes_written)},
      {"peak_queued_bytes", std::to_string(status_.peak_queued_bytes)},
      {"error", status_.error}};
  try {
    WriteAtomically(directory_, "metadata.yaml", MetadataYaml(metadata_, true, counters));
  } catch (const RecordingError& e) {
    // The frames are safe; only the closing note could not be written (a full disk, most often).
    if (status_.error.empty()) status_.error = e.what();
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
  try {
    const YAML::Node root = YAML::LoadFile(meta_path.string());
    if (!root["flamerig_recording"] || root["flamerig_recording"].as<int>() != 1)
      throw RecordingError("recording: " + meta_path.string() + " is not a version 1 recording");
    RecordingMetadata& m = rec.metadata_;
    m.sync_mode = root["sync_mode"].as<std::string>("");
    m.started_realtime_ns = root["started_realtime_ns"].as<std::int64_t>(0);
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
  RecoveryReport& report = rec.recovery_;
  rec.frames_.resize(n);
  for (int c = 0; c < n; ++c) {
    const fs::path index_path = dir / CameraIndexFile(c), data_path = dir / CameraDataFile(c);
    const std::vector<char> index = ReadWholeFile(index_path);
    CheckFileHeader(index, kIndexMagic, c, index_path);
    std::error_code ec;
    const std::uint64_t data_size = fs::file_size(data_path, ec);
    if (ec) throw RecordingError("recording: cannot open " + data_path.string());
    const std::size_t entries = (index.size() - kFileHeader) / sizeof(FrameRecord);
    const std::size_t tail = (index.size() - kFileHeader) % sizeof(FrameRecord);
    std::uint64_t data_end = kFileHeader;
    for (std::size_t e = 0; e < entries; ++e) {
      FrameRecord r;
      const std::size_t at = kFileHeader + e * sizeof(FrameRecord);
      std::memcpy(&r, index.data() + at, sizeof r);
      const bool last = e + 1 == entries;
      const bool fits = r.offset >= kFileHeader && r.payload_bytes <= data_size &&
                        r.offset + sizeof(FrameRecord) + r.payload_bytes <= data_size;
      const bool sane = r.camera == static_cast<std::uint32_t>(c) &&
                        r.pixel_format <= static_cast<std::uint32_t>(PixelFormat::kBayerBg8) &&
                        r.status <= static_cast<std::uint32_t>(FrameStatus::kError) &&
                        (r.payload_bytes == 0 ||
                         r.payload_bytes == std::uint64_t(r.width) * r.height *
                                                BytesPerPixel(static_cast<PixelFormat>(
                                                    std::min<std::uint32_t>(r.pixel_format, 6))));
      if (!RecordCrcOk(r) || !fits || !sane) {
        if (last) {  // torn by an interrupted write: ignored
          report.notes.push_back(index_path.filename().string() + ": last entry incomplete (" +
                                 (fits ? "checksum" : "its frame is cut short") + "), ignored");
          report.ignored_bytes += sizeof(FrameRecord);
          break;
        }
        throw RecordingError(
            "recording: " + index_path.string() + ": entry " + std::to_string(e) + " at byte " +
            std::to_string(at) + " is corrupt (" +
            (fits ? "checksum mismatch" : "points outside " + data_path.filename().string()) + ")");
      }
      rec.frames_[c].push_back(r);
      data_end = r.offset + sizeof(FrameRecord) + r.payload_bytes;
    }
    if (tail) {
      report.notes.push_back(index_path.filename().string() + ": " + std::to_string(tail) +
                             " bytes of a torn entry at the end, ignored");
      report.ignored_bytes += tail;
    }
    if (data_size > data_end) {
      report.notes.push_back(data_path.filename().string() + ": " +
                             std::to_string(data_size - data_end) +
                             " bytes after the last indexed frame, ignored");
      report.ignored_bytes += data_size - data_end;
    }
  }
  const fs::path sets_path = dir / "sets.index";
  const std::vector<char> sets = ReadWholeFile(sets_path);
  CheckFileHeader(sets, kSetsMagic, static_cast<std::uint32_t>(n), sets_path);
  const std::size_t record = kSetFixed + 8 * static_cast<std::size_t>(n);
  const std::size_t count = (sets.size() - kFileHeader) / record;
  std::vector<std::size_t> used(n, 0);  // frames referenced by committed sets
  for (std::size_t s = 0; s < count; ++s) {
    const std::size_t at = kFileHeader + s * record;
    const char* b = sets.data() + at;
    std::uint32_t crc;
    std::memcpy(&crc, b + 4, 4);
    SetEntry entry;
    entry.entries.resize(n);
    std::memcpy(entry.entries.data(), b + kSetFixed, 8 * n);
    bool ok = std::memcmp(b, "SET1", 4) == 0 && crc == Crc(b + 8, record - 8);
    for (int c = 0; ok && c < n; ++c)
      ok = entry.entries[c] >= -1 &&
           entry.entries[c] < static_cast<std::int64_t>(rec.frames_[c].size());
    if (!ok) {
      if (s + 1 == count) {
        report.notes.push_back("sets.index: last set record incomplete, ignored");
        report.ignored_bytes += record;
        break;
      }
      throw RecordingError("recording: " + sets_path.string() + ": set record " +
                           std::to_string(s) + " at byte " + std::to_string(at) + " is corrupt");
    }
    std::memcpy(&entry.header.index, b + 16, 8);
    std::memcpy(&entry.header.trigger_id, b + 24, 8);
    std::memcpy(&entry.header.reference_ns, b + 32, 8);
    std::memcpy(&entry.header.spread_ns, b + 40, 8);
    for (int c = 0; c < n; ++c)
      if (entry.entries[c] >= 0)
        used[c] = std::max<std::size_t>(used[c], static_cast<std::size_t>(entry.entries[c]) + 1);
    rec.sets_.push_back(std::move(entry));
  }
  const std::size_t sets_tail = (sets.size() - kFileHeader) % record;
  if (sets_tail) {
    report.notes.push_back("sets.index: " + std::to_string(sets_tail) +
                           " bytes of a torn record at the end, ignored");
    report.ignored_bytes += sets_tail;
  }
  for (int c = 0; c < n; ++c) {
    if (rec.frames_[c].size() > used[c]) {
      report.notes.push_back(CameraIndexFile(c) + ": " +
                             std::to_string(rec.frames_[c].size() - used[c]) +
                             " frames of sets that were never committed, ignored");
    }
  }
  report.sets = rec.sets_.size();
  return rec;
}

FrameSet Recording::ReadSet(std::size_t i) const {
  if (i >= sets_.size()) {
    throw std::out_of_range("recording " + directory_ + ": frame set " + std::to_string(i) +
                            " of " + std::to_string(sets_.size()));
  }
  FrameSet set = sets_[i].header;
  set.frames.resize(num_cameras());
  for (int c = 0; c < num_cameras(); ++c) set.frames[c] = ReadFrame(i, c);
  return set;
}

std::optional<Frame> Recording::ReadFrame(std::size_t i, int c) const {
  if (i >= sets_.size() || c < 0 || c >= num_cameras()) {
    throw std::out_of_range("recording " + directory_ + ": frame set " + std::to_string(i) +
                            " camera " + std::to_string(c) + " is not in the recording");
  }
  const SetEntry& e = sets_[i];
  if (e.entries[c] < 0) return std::nullopt;
  const FrameRecord& r = frames_[c][static_cast<std::size_t>(e.entries[c])];
  const fs::path path = fs::path(directory_) / CameraDataFile(c);
  std::ifstream in(path, std::ios::binary);
  FrameRecord on_disk;
  auto pixels = std::make_shared<std::vector<std::uint8_t>>(r.payload_bytes);
  in.seekg(static_cast<std::streamoff>(r.offset));
  in.read(reinterpret_cast<char*>(&on_disk), sizeof on_disk);
  in.read(reinterpret_cast<char*>(pixels->data()), static_cast<std::streamsize>(r.payload_bytes));
  const std::string where = path.string() + ": frame " + std::to_string(r.frame_id) + " (set " +
                            std::to_string(i) + ") at byte " + std::to_string(r.offset);
  if (!in) throw RecordingError("recording: " + where + ": cut short");
  if (std::memcmp(&on_disk, &r, sizeof r) != 0)
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
  f.data = std::move(pixels);
  return f;
}

bool Recording::HasFrame(std::size_t i, int c) const {
  return i < sets_.size() && c >= 0 && c < num_cameras() && sets_[i].entries[c] >= 0;
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

}  // namespace flamerig

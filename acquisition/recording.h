// Lossless recording of frame sets (DESIGN section 3), and reading recordings back.
//
// A recording is a directory:
//   metadata.yaml   the snapshot taken when recording started (capture config, sync mode, each
//                   camera's name, driver, serial and settings in force); rewritten atomically when
//                   the recording closes, with its counters and `closed: true`.
//   camNN.data      per camera, append-only: a file header, then for every frame a record header
//                   (FrameRecord, with a CRC-32 of itself and of the pixels) followed by the pixels.
//   camNN.index     per camera, append-only: a file header, then the same FrameRecord per frame
//                   (its `offset` says where the record starts in camNN.data).
//   sets.index      append-only: a file header, then one SetRecord per frame set: its number, trigger
//                   id, reference time, timestamp spread, and for every camera the entry of its frame
//                   in camNN.index (or -1 when the camera missed the set), with a CRC-32.
// All integers little-endian; the layouts are below and are the file format (version 1).
//
// Order of writes: a frame's data record, then its index entry; a set's record only after every one
// of its frames has been written. So a recording killed at any instant (SIGKILL) holds, in
// sets.index, only sets whose frames are all on disk; what follows the last complete set (a torn
// record, frames of sets never committed) is ignored when the recording is opened, and the open
// reports how much was ignored. The files are fdatasync'ed every `sync_interval_s` and at close,
// which bounds what a power cut can take.
//
// Writing: Submit() queues a set and returns at once; one writer thread per camera appends its
// frames. The queue is bounded in bytes: when the disk cannot keep up, whole sets are dropped and
// counted (never half a set), and memory stays bounded. A set that would take the recording past
// `max_bytes` or past `max_sets` frame sets, or its filesystem below `min_free_bytes`, stops it
// cleanly: no more sets are accepted, those already accepted are written. A write that fails
// (disk full, I/O error) stops it at once: everything up to the last committed set stays
// readable. status() names the file and the reason either way. A recording is refused (RecordingError, nothing created) when its disk
// has less than `min_free_bytes` free; while it records, a small file (closing.reserve) holds room
// for the closing metadata.yaml, so a disk that fills still gets `closed: true` and the counters.
//
// Reading: Recording::Open() checks the headers and checksums of the indices, recovers an
// interrupted recording as above, and ReadSet() returns the frames with their pixels checked against
// their CRC.
//
// Salvage: damage costs only the frames it touches. The data files are self-describing (every
// frame's record header is also in camNN.data, with its set's sequence number), so Open() rebuilds
// what a damaged file hid:
//   - a camNN.index that is missing, has a bad header, a corrupt entry, or stops before the sets
//     that name its frames: its frames are found again by walking camNN.data record by record (a
//     damaged record header is read from the index's copy; a damaged stretch is skipped up to the
//     next intact record);
//   - a camNN.data that is missing or cut short: that camera's frames in it are lost, every other
//     camera's frame of those sets reads;
//   - a corrupt set record in sets.index: the set is rebuilt from its frames (which carry its
//     sequence number), its header approximated from their timestamps; a sets.index missing or cut
//     short while metadata.yaml says more sets were recorded: the missing sets are rebuilt likewise;
//   - a flipped byte in a frame's pixels: ReadFrame() of that frame fails, naming it.
// Each of these is a note in recovery(). A lost frame is still listed in its set (FrameLost()) and
// ReadFrame() of it throws RecordingError saying why. Only a missing or unreadable metadata.yaml
// makes a recording unreadable. RebuildIndexes() (`flamerig recover`) writes the salvaged indexes
// back, so later reads are fast and clean.
#ifndef FLAMERIG_ACQUISITION_RECORDING_H_
#define FLAMERIG_ACQUISITION_RECORDING_H_

#include <condition_variable>
#include <cstdint>
#include <deque>
#include <map>
#include <memory>
#include <mutex>
#include <optional>
#include <stdexcept>
#include <string>
#include <thread>
#include <utility>
#include <vector>

#include "acquisition/camera.h"
#include "acquisition/clock.h"
#include "acquisition/frame.h"
#include "acquisition/frame_set.h"
#include "core/error.h"

namespace flamerig {

// A recording that cannot be read: names the file and, where it applies, the byte offset.
class RecordingError : public DataError {
 public:
  using DataError::DataError;
};

struct RecordingCamera {
  std::string name;  // the rig's name for it ("cam0")
  CameraDescription description;
  CameraSettings settings;  // in force when recording started
};

struct RecordingMetadata {
  std::string sync_mode;    // "hardware-trigger", "software-trigger", "free-run", "ptp", ...
  std::string config_yaml;  // the capture configuration as the daemon read it
  std::vector<RecordingCamera> cameras;
  std::map<std::string, std::string> features;  // other device feature values worth keeping
  std::int64_t started_realtime_ns = 0;
  double trigger_rate_hz = 0;  // the trigger's rate (0: free-run); cameras may allow more
  // An event recording (`ctl event NAME`): the trigger's moment, and the FrameSet::index of the
  // last set from the pre-trigger ring (sets after it are live); empty name: not an event.
  std::string event_name;
  std::int64_t event_realtime_ns = 0;
  std::int64_t event_last_ring_set = -1;  // -1: the ring was empty
};

// On-disk records (version 1). FrameRecord is 128 bytes, SetRecord 48 + 8 * cameras bytes.
#pragma pack(push, 1)
struct FrameRecord {
  char magic[4];             // "FRM1"
  std::uint32_t record_crc;  // CRC-32 of the 124 bytes that follow it
  std::uint64_t offset;      // of this record in camNN.data
  std::uint64_t set;         // the frame set it belongs to
  std::uint64_t frame_id, device_frame_id;
  std::int64_t device_timestamp_ns, host_monotonic_ns, host_realtime_ns, trigger_id;
  double exposure_us, gain_db;
  std::uint32_t pixel_format, width, height, status;
  std::uint64_t payload_bytes;
  std::uint32_t payload_crc;  // CRC-32 of the pixels
  std::uint32_t camera;
  // FrameInfo::sent_pfnc: the format the camera sent the frame in, 0 where not known. Zero in
  // recordings made before it was kept (the bytes were reserved and written as zeros), which
  // read as frames that do not say.
  std::uint32_t sent_pfnc;
  std::uint8_t reserved[4];
};
#pragma pack(pop)
static_assert(sizeof(FrameRecord) == 128, "FrameRecord is part of the file format");

struct RecorderOptions {
  std::uint64_t max_queued_bytes = 512ull << 20;  // pixels waiting for the disk, all cameras
  double sync_interval_s = 1.0;                   // fdatasync cadence; 0 = only at close
  std::uint64_t min_free_bytes = 64ull << 20;     // stop cleanly below this much free space
  std::uint64_t max_bytes = 0;                    // stop cleanly past this size; 0 = no limit
  std::uint64_t max_sets = 0;  // stop cleanly after this many frame sets; 0 = no limit
  void Validate() const;       // throws InputError naming the field
};

struct RecorderStatus {
  std::uint64_t sets_submitted = 0;
  std::uint64_t sets_recorded = 0;  // committed to sets.index
  std::uint64_t sets_dropped = 0;   // refused: queue full, or the recording had stopped
  std::uint64_t frames_recorded = 0;
  std::uint64_t bytes_written = 0;  // data files, pixels and record headers
  std::uint64_t queued_bytes = 0, peak_queued_bytes = 0, max_queued_bytes = 0;
  bool stopped = false;  // no longer accepting sets: an error or a limit; `error` says which
  // Stopped by max_bytes or max_sets, as configured (not a fault; the sets it refused after are not
  // counted as dropped). False again when a write fails after it.
  bool limit_reached = false;
  std::string error;
};

class Recorder {
 public:
  // Creates the recording directory (it must not exist, or be empty) and its files, writes
  // metadata.yaml and starts one writer thread per camera. Throws RecordingError naming the path.
  Recorder(const std::string& directory, const RecordingMetadata& metadata,
           const RecorderOptions& options = {});
  ~Recorder();  // Close()
  Recorder(const Recorder&) = delete;
  Recorder& operator=(const Recorder&) = delete;

  // Queues a frame set (its frames' bytes are shared, not copied); never waits for the disk. False
  // when the set was dropped: the queue was full, or the recording has stopped (status()).
  bool Submit(const FrameSet& set);
  // Writes what is queued, syncs, rewrites metadata.yaml with the counters (and `extra`, the
  // caller's own: missed triggers, ...) and `closed: true`, and stops the writers. Idempotent.
  RecorderStatus Close(const std::map<std::string, std::string>& extra = {});
  RecorderStatus status() const;
  const std::string& directory() const { return directory_; }

 private:
  struct Job {
    std::uint64_t seq;  // submission order
    Frame frame;
  };
  struct Pending {
    FrameSet header;                    // the set without pixels
    int remaining = 0;                  // frames not yet written
    std::vector<std::int64_t> entries;  // index entry per camera, -1 = missing
  };
  struct CameraFiles;
  void WriterLoop(int camera);
  void CommitterLoop();  // appends set records to sets.index, outside the lock, in order
  void Fail(const std::string& message);  // holds mutex_
  void CommitReady();                     // holds mutex_: queues finished sets' records
  void SyncAll();

  std::string directory_;
  std::string reserve_path_;  // space held for the closing metadata.yaml
  RecordingMetadata metadata_;
  RecorderOptions options_;
  std::vector<std::unique_ptr<CameraFiles>> cameras_;
  int sets_fd_ = -1;
  mutable std::mutex mutex_;
  std::condition_variable work_;  // writers wait for jobs
  std::condition_variable idle_;  // Close waits for the queues to drain
  std::vector<std::deque<Job>> queues_;
  std::map<std::uint64_t, Pending> pending_;  // by seq, until committed in order
  std::uint64_t next_seq_ = 0, next_commit_ = 0;
  std::uint64_t accepted_bytes_ = 0;    // on disk once every accepted set is written
  std::uint64_t next_space_check_ = 0;  // accepted_bytes_ at which to look at free space again
  bool failed_ = false;                 // a write failed: the writers stop
  RecorderStatus status_;
  bool closing_ = false, closed_ = false;
  bool complete_ = false;  // a configured limit reached (max_sets, max_bytes): sets past it refused
  std::int64_t last_sync_ns_ = 0;
  std::vector<std::vector<char>> to_commit_;  // set records ready for sets.index, in order
  std::condition_variable commit_;
  bool writers_done_ = false;
  std::vector<std::thread> writers_;
  std::thread committer_;
};

struct RecoveryReport {
  bool closed_cleanly = false;      // metadata.yaml says the recorder closed it
  std::uint64_t sets = 0;           // readable frame sets
  std::uint64_t ignored_bytes = 0;  // past the last complete set (torn records, uncommitted frames)
  std::uint64_t damaged_bytes = 0;  // stretches of a data file skipped as unreadable
  std::uint64_t lost_frames = 0;    // frames named by a set but gone (a data file missing or cut)
  std::uint64_t rebuilt_sets = 0;   // sets rebuilt from their frames (set records damaged or gone)
  std::uint64_t added_sets = 0;     // RebuildIndexes: uncommitted sets whose frames are all there
  std::uint64_t corrupt_frames = 0;  // RebuildIndexes: frames whose pixels fail their CRC
  std::vector<int> rebuilt_indexes;  // cameras whose frames were found by walking camNN.data
  std::vector<std::string> notes;    // what was ignored, damaged or rebuilt, file by file
  bool damaged() const {
    return damaged_bytes > 0 || lost_frames > 0 || rebuilt_sets > 0 || corrupt_frames > 0 ||
           !rebuilt_indexes.empty();
  }
};

class Recording {
 public:
  // Opens and checks a recording; throws RecordingError naming the file (and offset) that is
  // missing, malformed or corrupt.
  static Recording Open(const std::string& directory);

  const RecordingMetadata& metadata() const { return metadata_; }
  const RecoveryReport& recovery() const { return recovery_; }
  std::size_t num_sets() const { return sets_.size(); }
  int num_cameras() const { return static_cast<int>(metadata_.cameras.size()); }
  // The set's header (index, trigger, reference time, spread) and its frames with their pixels,
  // checked against their CRC (RecordingError on a mismatch, naming the file, frame and offset).
  FrameSet ReadSet(std::size_t i) const;
  // One camera's frame of set i (nullopt when the camera missed the set); same checks and errors.
  std::optional<Frame> ReadFrame(std::size_t i, int camera) const;
  // The set holds a readable frame of the camera (false when it missed the set or the frame is
  // lost). Pixels are checked only when read.
  bool HasFrame(std::size_t i, int camera) const;
  // The set held a frame of the camera that damage took (ReadFrame() throws saying why).
  bool FrameLost(std::size_t i, int camera) const;
  // The set's header (index, trigger, reference time, spread) without its frames.
  FrameSet SetHeader(std::size_t i) const;
  // The frame records of one camera (no pixels): what the per-frame index says.
  const std::vector<FrameRecord>& frames(int camera) const { return frames_[camera]; }
  // Drops counted in the recording: frame-id gaps per camera (wrap-aware unwrapped ids).
  std::vector<std::uint64_t> MissingByFrameId() const;
  // Counters the recorder wrote at close (sets_dropped, ...; `error` the fault that stopped it,
  // `limit_reached` the configured limit that did, each empty otherwise); empty when it did not
  // close.
  const std::map<std::string, std::string>& final_counters() const { return final_counters_; }

 private:
  static constexpr std::int64_t kLost = -2;  // an entry whose frame damage took
  struct SetEntry {
    FrameSet header;
    std::uint64_t seq = 0;              // the recorder's sequence number (FrameRecord::set)
    std::vector<std::int64_t> entries;  // position in frames_[camera], -1 missed, kLost
  };
  friend RecoveryReport RebuildIndexes(const std::string& directory);
  // Every camera has written a frame of set `seq` or of a later one (so a camera without one
  // missed it), and one at least has its frame.
  bool WholeSet(std::uint64_t seq) const;
  // A rebuilt set's header: the frames' common trigger id (else -1), their earliest device time
  // and its spread.
  FrameSet HeaderFromFrames(const SetEntry& entry, std::uint64_t index) const;
  std::string directory_;
  std::map<std::pair<std::size_t, int>, std::string> lost_;  // (set, camera): why it is lost
  RecordingMetadata metadata_;
  RecoveryReport recovery_;
  std::vector<std::vector<FrameRecord>> frames_;
  std::vector<SetEntry> sets_;
  std::map<std::string, std::string> final_counters_;
};

// `flamerig recover`: opens the recording with every salvage above, then also takes in the sets the
// recorder never committed whose frames are all on disk (a set is whole when every camera has its
// frame, or has written a later one, so it missed this set), checks every frame's pixels against
// their CRC, and writes the rebuilt camNN.index and sets.index in place. The data files and
// metadata.yaml are never modified; the replaced index files are copied first to a folder of
// their own, DIRECTORY/replaced_indexes_<UTC time>[_N]/ (nothing is deleted). The new indexes
// cannot mark a lost frame (its set then reads as without that camera): lost frames are listed in
// DIRECTORY/lost_frames.csv. The report counts what was found; its notes list each damaged frame.
// Throws RecordingError when metadata.yaml cannot be read or a new file cannot be written (each
// file is replaced atomically, and the copies of the old ones are already in their folder).
RecoveryReport RebuildIndexes(const std::string& directory);

// File names inside a recording.
std::string CameraDataFile(int camera);   // "cam00.data"
std::string CameraIndexFile(int camera);  // "cam00.index"

}  // namespace flamerig

#endif  // FLAMERIG_ACQUISITION_RECORDING_H_

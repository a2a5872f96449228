// Files that are either whole or absent under their final name: written under a temporary name
// beside the target ("<name>.tmp-<pid>-<n>", unique to the writer), flushed to disk, then renamed
// (rename is atomic within a file system), and the folder flushed so that the rename survives a
// power cut. A process killed at any moment leaves at most a stale temporary file behind, never
// half a file under the final name.
//
// Every writer of results in flamerig (volumes, summaries, caches, recordings' metadata, pictures)
// goes through these.
//
// Errors: IoError (core/error.h) naming the final path and what the system said. The temporary
// file is removed on failure.
//
// Thread safety: any calls may run concurrently; two writers of one path (two processes, two
// threads) each write their own temporary file, the last rename wins, and neither leaves a
// partial file.
#ifndef FLAMERIG_CORE_ATOMIC_FILE_H_
#define FLAMERIG_CORE_ATOMIC_FILE_H_

#include <string>
#include <string_view>

namespace flamerig {

// Writes `bytes` to `path` atomically and durably.
void WriteFileAtomically(const std::string& path, std::string_view bytes);

// Copies `from` to `to` atomically and durably.
void CopyFileAtomically(const std::string& from, const std::string& to);

// Flushes a whole file (written by another library) and its folder to disk; errors are ignored.
void SyncFile(const std::string& path);

// For writers that need a file name (OpenVDB, OpenCV): write to temp_path(), then Commit(), which
// flushes and renames it to the final path. Destroyed without Commit(), it removes the temporary
// file. The temporary name keeps the final name's extension ("a.vdb" -> "a.tmp-<pid>-<n>.vdb"),
// because some writers choose the format by it.
class AtomicFile {
 public:
  explicit AtomicFile(std::string path);
  ~AtomicFile();
  AtomicFile(const AtomicFile&) = delete;
  AtomicFile& operator=(const AtomicFile&) = delete;

  const std::string& temp_path() const { return temp_; }
  const std::string& path() const { return path_; }
  void Commit();  // throws IoError naming path() when the rename fails

 private:
  std::string path_, temp_;
  bool committed_ = false;
};

}  // namespace flamerig

#endif  // FLAMERIG_CORE_ATOMIC_FILE_H_

// One job per folder: an exclusive lock that a second process asking for the same folder gets as
// a clear error, never as two writers mixing their files.
//
// The lock is the file FOLDER/.flamerig.lock held with flock(2). The kernel releases it when the
// holder's process ends, however it ends (SIGKILL, a crash, a power cut), so there are no stale
// locks to clean up; the file itself stays and says who held it last. The holder writes its pid,
// its host name, the time and what it is doing into the file; a refused process reads them into
// its error message.
//
// flock locks belong to the open file, not the process: two FolderLocks on one folder conflict
// within one process too (which is how the tests check them). Locks over NFS follow the server's
// flock support.
//
// Thread safety: a FolderLock is owned by one thread; distinct objects are independent.
#ifndef FLAMERIG_CORE_FOLDER_LOCK_H_
#define FLAMERIG_CORE_FOLDER_LOCK_H_

#include <string>

namespace flamerig {

class FolderLock {
 public:
  // Creates the folder if needed and takes its lock for `what` ("flamerig capture", "flamerig
  // run"). Throws InputError "FOLDER is in use by another flamerig: WHAT, pid N on HOST since
  // TIME" when another holder has it, IoError naming the lock file when it cannot be created.
  FolderLock(const std::string& folder, const std::string& what);
  ~FolderLock();  // releases the lock (the file stays)
  FolderLock(const FolderLock&) = delete;
  FolderLock& operator=(const FolderLock&) = delete;

  const std::string& path() const { return path_; }  // the lock file

 private:
  std::string path_;
  int fd_ = -1;
};

}  // namespace flamerig

#endif  // FLAMERIG_CORE_FOLDER_LOCK_H_

// `flamerig run` over several processes (DESIGN section 9): the orchestration, testable in
// process, and MPI (Open MPI) as one way to run it.
//
// `mpirun -n N flamerig run ...` gives each rank one contiguous run of the frames (RankFrames), so
// warm starts still chain inside a rank; rank 0 prepares the rig (calibrating first if asked)
// while the others wait, every rank writes its own frames' outputs into the shared OUT, and the
// summaries are gathered on rank 0, which writes the one report (RunDistributed). The ranks talk
// through a Communicator: MpiSession under mpirun, a session of one rank without it, and
// ThreadRanks in the tests (ranks as threads of one process).
//
// Threads: each rank uses the machine's cores divided by the ranks on its node (MPI's shared-memory
// split, MPI_Comm_split_type), unless DistributedOptions::threads says otherwise.
//
// Thread safety: a Communicator is used by its rank's thread only.
#ifndef FLAMERIG_PIPELINE_DISTRIBUTED_H_
#define FLAMERIG_PIPELINE_DISTRIBUTED_H_

#include <condition_variable>
#include <cstddef>
#include <memory>
#include <mutex>
#include <string>
#include <vector>

#include "core/progress.h"
#include "pipeline/run.h"

namespace flamerig {

// What the orchestration needs of a group of ranks.
class Communicator {
 public:
  virtual ~Communicator() = default;
  virtual int rank() const = 0;
  virtual int size() const = 0;
  virtual int ranks_on_this_node() const = 0;
  virtual void Barrier() = 0;
  // Every rank's text, in rank order, on rank 0; an empty vector on the others.
  virtual std::vector<std::string> Gather(const std::string& text) = 0;
};

class MpiSession : public Communicator {
 public:
  // Initialises MPI when this process was started by mpirun or mpiexec (their environment says
  // so); otherwise a session of one rank. Throws InputError when started by mpirun with more than
  // one rank but built without MPI (it would compute every frame N times).
  MpiSession(int* argc, char*** argv);
  ~MpiSession() override;  // finalises MPI if it was initialised
  MpiSession(const MpiSession&) = delete;
  MpiSession& operator=(const MpiSession&) = delete;

  bool active() const { return active_; }  // MPI initialised
  int rank() const override { return rank_; }
  int size() const override { return size_; }
  // The ranks that share this node's memory (MPI_Comm_split_type MPI_COMM_TYPE_SHARED).
  int ranks_on_this_node() const override { return local_size_; }
  void Barrier() override;
  std::vector<std::string> Gather(const std::string& text) override;
  // A rank that failed stops them all (the others would otherwise wait at the next barrier).
  [[noreturn]] void Abort(int code);

  static bool BuiltWithMpi();

 private:
  bool active_ = false;
  int rank_ = 0, size_ = 1, local_size_ = 1;
};

// `size` ranks as threads of one process, for tests of the orchestration: rank(r) is the
// communicator the thread of rank r uses.
class ThreadRanks {
 public:
  explicit ThreadRanks(int size);
  ~ThreadRanks();
  Communicator& rank(int r);

 private:
  class Rank;
  friend class Rank;
  void Barrier();
  int size_;
  std::mutex mutex_;
  std::condition_variable cv_;
  int arrived_ = 0;
  long long generation_ = 0;
  std::vector<std::string> texts_;
  std::vector<std::unique_ptr<Rank>> ranks_;
};

// Rank `rank` of `size`'s contiguous share of frames [begin, end): as equal as can be, the first
// ranks taking one more when they do not divide evenly.
void RankFrames(std::size_t begin, std::size_t end, int rank, int size, std::size_t* rank_begin,
                std::size_t* rank_end);

struct DistributedOptions {
  std::size_t threads = 0;  // per rank; 0 = the machine's cores / the ranks on this node
};

struct DistributedRun {
  std::string rig_path;
  RunSummary mine;                   // this rank's frames
  std::vector<FrameSummary> frames;  // rank 0: every rank's, in frame order
  std::string report;                // rank 0: the report's index.html
  std::size_t failed = 0;            // rank 0: failed frames of the whole run
  bool cancelled = false;            // this rank stopped early
};

// The whole run on this rank: the rig (rank 0 first), this rank's frames (RunFrames), then the
// summaries gathered and the report written on rank 0. Progress: the calibration's (rank 0), then
// RunFrames'; the source's notes and this rank's range are logged (core/log.h). Throws what
// PrepareRig and RunFrames throw.
DistributedRun RunDistributed(const RunOptions& options, const DistributedOptions& distributed,
                              Communicator& ranks, const ProgressCallback& progress = nullptr);

}  // namespace flamerig

#endif  // FLAMERIG_PIPELINE_DISTRIBUTED_H_

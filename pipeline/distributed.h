// `flamerig run` over several processes with MPI (Open MPI), DESIGN section 9.
//
// `mpirun -n N flamerig run ...` gives each rank one contiguous run of the frames (RankFrames), so
// warm starts still chain inside a rank; rank 0 prepares the rig (calibrating first if asked)
// before the others start, every rank writes its own frames' outputs into the shared OUT, and the
// summaries are gathered on rank 0, which writes the one report. The same binary runs without
// mpirun as a single rank and never initialises MPI then; a binary built without MPI refuses to run
// under mpirun with more than one rank instead of computing every frame N times.
//
// Threads: under mpirun each rank uses the machine's cores divided by the ranks on its node
// (OMPI_COMM_WORLD_LOCAL_SIZE), unless --threads says otherwise.
//
// Thread safety: one MpiSession per process, used from the main thread.
#ifndef FLAMERIG_PIPELINE_DISTRIBUTED_H_
#define FLAMERIG_PIPELINE_DISTRIBUTED_H_

#include <cstddef>
#include <string>
#include <vector>

namespace flamerig {

class MpiSession {
 public:
  // Initialises MPI when this process was started by mpirun or mpiexec (their environment says
  // so); otherwise a session of one rank. Throws std::runtime_error when started by mpirun with
  // more than one rank but built without MPI.
  MpiSession(int* argc, char*** argv);
  ~MpiSession();  // finalises MPI if it was initialised
  MpiSession(const MpiSession&) = delete;
  MpiSession& operator=(const MpiSession&) = delete;

  bool active() const { return active_; }  // MPI initialised
  int rank() const { return rank_; }
  int size() const { return size_; }
  int ranks_on_this_node() const { return local_size_; }

  void Barrier();
  // Every rank's text, in rank order, on rank 0; an empty vector on the others.
  std::vector<std::string> Gather(const std::string& text);
  // A rank that failed stops them all (the others would otherwise wait at the next barrier).
  [[noreturn]] void Abort(int code);

  static bool BuiltWithMpi();

 private:
  bool active_ = false;
  int rank_ = 0, size_ = 1, local_size_ = 1;
};

// Rank `rank` of `size`'s contiguous share of frames [begin, end): as equal as can be, the first
// ranks taking one more when they do not divide evenly.
void RankFrames(std::size_t begin, std::size_t end, int rank, int size, std::size_t* rank_begin,
                std::size_t* rank_end);

}  // namespace flamerig

#endif  // FLAMERIG_PIPELINE_DISTRIBUTED_H_

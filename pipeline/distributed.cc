#include "pipeline/distributed.h"

#include <tbb/global_control.h>

#include <algorithm>
#include <chrono>
#include <cstdlib>
#include <filesystem>
#include <optional>
#include <thread>

#include "core/error.h"
#include "core/folder_lock.h"
#include "core/log.h"
#include "pipeline/run_report.h"

#ifdef FLAMERIG_HAVE_MPI
#include <mpi.h>
#endif

namespace flamerig {

namespace {

[[maybe_unused]] int EnvInt(const char* name, int fallback) {
  const char* v = std::getenv(name);
  return v && *v ? std::atoi(v) : fallback;
}

// Started by mpirun/mpiexec (Open MPI, or a PMI launcher such as srun or MPICH's hydra)?
bool LaunchedByMpirun() {
  return std::getenv("OMPI_COMM_WORLD_SIZE") || std::getenv("PMIX_RANK") || std::getenv("PMI_RANK");
}

}  // namespace

bool MpiSession::BuiltWithMpi() {
#ifdef FLAMERIG_HAVE_MPI
  return true;
#else
  return false;
#endif
}

MpiSession::MpiSession(int* argc, char*** argv) {
  if (!LaunchedByMpirun()) return;
#ifdef FLAMERIG_HAVE_MPI
  MPI_Init(argc, argv);
  active_ = true;
  MPI_Comm_rank(MPI_COMM_WORLD, &rank_);
  MPI_Comm_size(MPI_COMM_WORLD, &size_);
  // The ranks on this node: those that can share memory with this one.
  MPI_Comm node;
  MPI_Comm_split_type(MPI_COMM_WORLD, MPI_COMM_TYPE_SHARED, rank_, MPI_INFO_NULL, &node);
  MPI_Comm_size(node, &local_size_);
  MPI_Comm_free(&node);
#else
  const int size = EnvInt("OMPI_COMM_WORLD_SIZE", EnvInt("PMI_SIZE", 1));
  if (size > 1)
    throw InputError("started by mpirun with " + std::to_string(size) +
                     " ranks, but this flamerig was built without MPI (install "
                     "libopenmpi-dev and rebuild)");
#endif
}

MpiSession::~MpiSession() {
#ifdef FLAMERIG_HAVE_MPI
  if (active_) MPI_Finalize();
#endif
}

void MpiSession::Barrier() {
#ifdef FLAMERIG_HAVE_MPI
  if (active_) MPI_Barrier(MPI_COMM_WORLD);
#endif
}

std::vector<std::string> MpiSession::Gather(const std::string& text) {
  if (!active_) return {text};
#ifdef FLAMERIG_HAVE_MPI
  const int length = static_cast<int>(text.size());
  std::vector<int> lengths(rank_ == 0 ? size_ : 0);
  MPI_Gather(&length, 1, MPI_INT, lengths.data(), 1, MPI_INT, 0, MPI_COMM_WORLD);
  std::vector<int> offsets(lengths.size(), 0);
  int total = 0;
  for (std::size_t r = 0; r < lengths.size(); ++r) {
    offsets[r] = total;
    total += lengths[r];
  }
  std::string all(static_cast<std::size_t>(total), '\0');
  MPI_Gatherv(text.data(), length, MPI_CHAR, all.data(), lengths.data(), offsets.data(), MPI_CHAR,
              0, MPI_COMM_WORLD);
  std::vector<std::string> out;
  for (std::size_t r = 0; r < lengths.size(); ++r)
    out.push_back(
        all.substr(static_cast<std::size_t>(offsets[r]), static_cast<std::size_t>(lengths[r])));
  return out;
#else
  return {text};
#endif
}

void MpiSession::Abort(int code) {
#ifdef FLAMERIG_HAVE_MPI
  if (active_) MPI_Abort(MPI_COMM_WORLD, code);
#endif
  std::exit(code);
}

void RankFrames(std::size_t begin, std::size_t end, int rank, int size, std::size_t* rank_begin,
                std::size_t* rank_end) {
  if (size < 1 || rank < 0 || rank >= size || end < begin)
    throw InputError("RankFrames: need 0 <= rank < size and begin <= end");
  const std::size_t n = end - begin, r = static_cast<std::size_t>(rank);
  const std::size_t base = n / size, extra = n % size;
  *rank_begin = begin + r * base + std::min(r, extra);
  *rank_end = *rank_begin + base + (r < extra ? 1 : 0);
}

// ---- Ranks as threads

class ThreadRanks::Rank : public Communicator {
 public:
  Rank(ThreadRanks* group, int rank) : group_(group), rank_(rank) {}
  int rank() const override { return rank_; }
  int size() const override { return group_->size_; }
  int ranks_on_this_node() const override { return group_->size_; }
  void Barrier() override { group_->Barrier(); }
  std::vector<std::string> Gather(const std::string& text) override {
    {
      std::lock_guard<std::mutex> lock(group_->mutex_);
      group_->texts_[rank_] = text;
    }
    group_->Barrier();  // every text is in
    std::vector<std::string> out;
    if (rank_ == 0) {
      std::lock_guard<std::mutex> lock(group_->mutex_);
      out = group_->texts_;
    }
    group_->Barrier();  // rank 0 has read them before anyone writes again
    return out;
  }

 private:
  ThreadRanks* group_;
  int rank_;
};

ThreadRanks::ThreadRanks(int size) : size_(size), texts_(static_cast<std::size_t>(size)) {
  if (size < 1) throw InputError("ThreadRanks: size must be >= 1");
  for (int r = 0; r < size; ++r) ranks_.push_back(std::make_unique<Rank>(this, r));
}

ThreadRanks::~ThreadRanks() = default;

Communicator& ThreadRanks::rank(int r) { return *ranks_.at(static_cast<std::size_t>(r)); }

void ThreadRanks::Barrier() {
  std::unique_lock<std::mutex> lock(mutex_);
  const long long generation = generation_;
  if (++arrived_ == size_) {
    arrived_ = 0;
    ++generation_;
    cv_.notify_all();
  } else {
    cv_.wait(lock, [&] { return generation_ != generation; });
  }
}

// ---- The run over ranks

DistributedRun RunDistributed(const RunOptions& options, const DistributedOptions& distributed,
                              Communicator& ranks, const ProgressCallback& progress) {
  namespace fs = std::filesystem;
  const auto start = std::chrono::steady_clock::now();
  options.Validate();
  std::size_t threads = distributed.threads;
  if (threads == 0 && ranks.ranks_on_this_node() > 1)
    threads = std::max<std::size_t>(
        1, std::thread::hardware_concurrency() / static_cast<unsigned>(ranks.ranks_on_this_node()));
  std::unique_ptr<tbb::global_control> limit;
  if (threads)
    limit = std::make_unique<tbb::global_control>(tbb::global_control::max_allowed_parallelism,
                                                  threads);
  const std::string who = ranks.size() > 1 ? "[rank " + std::to_string(ranks.rank()) + "] " : "";
  DistributedRun out;
  // One job per output folder (its rank 0 holds the lock): two runs would overwrite each other's
  // frames and state. Rank 0 prepares the rig (it may calibrate) while the others wait.
  std::optional<FolderLock> lock;
  if (ranks.rank() == 0) {
    lock.emplace(
        options.out_dir,
        "flamerig run" + (ranks.size() > 1 ? " (" + std::to_string(ranks.size()) + " MPI ranks)"
                                           : std::string()));
    out.rig_path = PrepareRig(options, progress);
  }
  ranks.Barrier();
  if (ranks.rank() != 0) out.rig_path = PrepareRig(options);
  std::size_t begin, end;
  {
    const FrameSource source(options.source, Rig::Load(out.rig_path));
    if (ranks.rank() == 0)
      for (const auto& note : source.notes()) Log().warn("run: {}", note);
    RunRange(options, source, &begin, &end);
  }
  std::size_t mine_begin, mine_end;
  RankFrames(begin, end, ranks.rank(), ranks.size(), &mine_begin, &mine_end);
  Log().info("{}run: frames {}..{} of {} through {} into {}", who, mine_begin, mine_end - 1,
             options.source.Describe(), out.rig_path, options.out_dir);
  if (mine_begin < mine_end)
    out.mine = RunFrames(options, out.rig_path, mine_begin, mine_end, progress);
  out.cancelled = out.mine.cancelled;
  // Every rank's summaries to rank 0, which writes the one report.
  std::string text;
  for (const auto& f : out.mine.frames) text += f.ToYaml() + '\0';
  const std::vector<std::string> all = ranks.Gather(text);
  if (ranks.rank() != 0) return out;
  for (const auto& t : all) {
    std::size_t at = 0;
    while (at < t.size()) {
      const std::size_t stop = t.find('\0', at);
      out.frames.push_back(FrameSummary::FromYaml(t.substr(at, stop - at), "a rank's summary"));
      at = stop + 1;
    }
  }
  std::sort(out.frames.begin(), out.frames.end(),
            [](const FrameSummary& a, const FrameSummary& b) { return a.frame < b.frame; });
  RunReportInfo info;
  info.source = options.source.Describe();
  info.rig_path = out.rig_path;
  info.truth_dir = options.truth_dir;
  info.truth_rig = options.truth_rig;
  info.ranks = ranks.size();
  info.wall_seconds =
      std::chrono::duration<double>(std::chrono::steady_clock::now() - start).count();
  out.report = WriteRunReport(options.out_dir, out.frames, info);
  for (const auto& f : out.frames) out.failed += f.status.rfind("failed", 0) == 0;
  return out;
}

}  // namespace flamerig

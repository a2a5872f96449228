#include "pipeline/distributed.h"

#include <cstdlib>
#include <stdexcept>

#ifdef FLAMERIG_HAVE_MPI
#include <mpi.h>

#include "core/error.h"
#endif

namespace flamerig {

namespace {

int EnvInt(const char* name, int fallback) {
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
  local_size_ = std::max(1, EnvInt("OMPI_COMM_WORLD_LOCAL_SIZE", 1));
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

}  // namespace flamerig

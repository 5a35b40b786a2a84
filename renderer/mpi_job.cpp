// The MPI job (MpiJob) and the messaging the image- and data-parallel renders share
// (renderer/mpi_messages.h).
#include <mpi.h>

#include <cstdio>
#include <cstdlib>
#include <limits>
#include <string>
#include <type_traits>

#include "renderer/distributed.h"
#include "renderer/mpi_messages.h"

namespace iso {
namespace mpi {

void Outbox::send(std::vector<char> bytes, int to, int tag) {
  m_pending.push_back({MPI_REQUEST_NULL, std::move(bytes)});
  Pending& p = m_pending.back();
  MPI_Isend(p.bytes.data(), int(p.bytes.size()), MPI_BYTE, to, tag, MPI_COMM_WORLD, &p.request);
}

void Outbox::progress() {
  for (size_t i = 0; i < m_pending.size();) {
    int done = 0;
    MPI_Test(&m_pending[i].request, &done, MPI_STATUS_IGNORE);
    if (done) {
      m_pending[i] = std::move(m_pending.back());
      m_pending.pop_back();
    } else {
      ++i;
    }
  }
}

void Outbox::drain() {
  for (Pending& p : m_pending) MPI_Wait(&p.request, MPI_STATUS_IGNORE);
  m_pending.clear();
}

void receive(const MPI_Status& status, std::vector<char>& buffer) {
  int bytes = 0;
  MPI_Get_count(&status, MPI_BYTE, &bytes);
  buffer.resize(size_t(std::max(bytes, 0)));
  MPI_Recv(buffer.data(), bytes, MPI_BYTE, status.MPI_SOURCE, status.MPI_TAG, MPI_COMM_WORLD, MPI_STATUS_IGNORE);
}

std::vector<char> receive(const MPI_Status& status) {
  std::vector<char> buffer;
  receive(status, buffer);
  return buffer;
}

void sendCounters(const RayCounters& mine, RayCounters& total, int root) {
  constexpr int n = 3 + TraversalStats::kFields;
  uint64_t v[n] = {mine.camera, mine.shadow, mine.indirect};
  int i = 3;
  TraversalStats traversal = mine.traversal;
  traversal.forEach([&](uint64_t& value) { v[i++] = value; });
  uint64_t s[n] = {};
  MPI_Reduce(v, s, n, MPI_UINT64_T, MPI_SUM, root, MPI_COMM_WORLD);
  total.camera = s[0];
  total.shadow = s[1];
  total.indirect = s[2];
  i = 3;
  total.traversal.forEach([&](uint64_t& value) { value = s[i++]; });
}

}  // namespace mpi

namespace {

int environmentInt(const char* name, int fallback) {
  const char* v = std::getenv(name);
  if (!v) return fallback;
  char* end = nullptr;
  const long n = std::strtol(v, &end, 10);
  return end != v && *end == '\0' && n >= 0 && n <= (1 << 24) ? int(n) : fallback;
}

}  // namespace

LaunchedRanks launchedRanks() {
  LaunchedRanks r;
  for (const char* name : {"OMPI_COMM_WORLD_SIZE", "PMI_SIZE", "PMIX_RANK"}) r.launched = r.launched || std::getenv(name);
  r.size = environmentInt("OMPI_COMM_WORLD_SIZE", environmentInt("PMI_SIZE", 1));
  r.rank = environmentInt("OMPI_COMM_WORLD_RANK", environmentInt("PMI_RANK", 0));
  return r;
}

MpiJob::MpiJob() {
  if (!launchedRanks().launched) return;
  int provided = 0;
  MPI_Init_thread(nullptr, nullptr, MPI_THREAD_FUNNELED, &provided);
  m_initialised = true;
  MPI_Comm_rank(MPI_COMM_WORLD, &m_rank);
  MPI_Comm_size(MPI_COMM_WORLD, &m_size);
}

MpiJob::~MpiJob() {
  if (!m_initialised) return;
  if (m_abandoned) MPI_Abort(MPI_COMM_WORLD, 130);
  MPI_Finalize();
}

std::string MpiJob::where() const {
  return distributed() ? "rank " + std::to_string(m_rank) + " of " + std::to_string(m_size) + ": " : "";
}

std::string MpiJob::firstError(const std::string& mine) const {
  if (!distributed()) return mine;
  int failing = mine.empty() ? m_size : m_rank, first = m_size;
  MPI_Allreduce(&failing, &first, 1, MPI_INT, MPI_MIN, MPI_COMM_WORLD);
  if (first == m_size) return "";
  int length = first == m_rank ? int(mine.size()) : 0;
  MPI_Bcast(&length, 1, MPI_INT, first, MPI_COMM_WORLD);
  std::string message(size_t(length), '\0');
  if (first == m_rank) message = mine;
  MPI_Bcast(message.data(), length, MPI_CHAR, first, MPI_COMM_WORLD);
  return first == 0 ? message : "rank " + std::to_string(first) + " of " + std::to_string(m_size) + ": " + message;
}

RankExchange MpiJob::rankExchange() const {
  static_assert(std::is_trivially_copyable_v<RankAnswer>, "answers go between ranks as bytes");
  RankExchange x;
  x.rank = m_rank;
  x.ranks = m_size;
  x.combine = [size = m_size](std::vector<RankAnswer>& answers) {
    // One all-gather of every lane's answer; each rank combines them alike, rank by rank.
    const size_t lanes = answers.size();
    std::vector<RankAnswer> all(lanes * size_t(size));
    const int bytes = int(lanes * sizeof(RankAnswer));
    MPI_Allgather(answers.data(), bytes, MPI_BYTE, all.data(), bytes, MPI_BYTE, MPI_COMM_WORLD);
    for (size_t l = 0; l < lanes; ++l) {
      RankAnswer& a = answers[l];
      a.found = 0;
      for (int r = 0; r < size; ++r) {
        const RankAnswer& theirs = all[size_t(r) * lanes + l];
        if (!theirs.found) continue;
        if (a.query == RankAnswer::kBlocked) {
          a.found = 1;
        } else if (!a.found || theirs.hit.t < a.hit.t) {  // the closest; of equal ones the lowest rank's
          a.hit = theirs.hit;
          a.found = 1;
        }
      }
    }
  };
  x.firstError = [this](const std::string& mine) { return firstError(mine); };
  return x;
}

int MpiJob::sum(int v) const {
  if (!distributed()) return v;
  int total = 0;
  MPI_Allreduce(&v, &total, 1, MPI_INT, MPI_SUM, MPI_COMM_WORLD);
  return total;
}

bool MpiJob::sameOnEveryRank(uint64_t v) const {
  if (!distributed()) return true;
  uint64_t lowest = v, highest = v;
  MPI_Allreduce(MPI_IN_PLACE, &lowest, 1, MPI_UINT64_T, MPI_MIN, MPI_COMM_WORLD);
  MPI_Allreduce(MPI_IN_PLACE, &highest, 1, MPI_UINT64_T, MPI_MAX, MPI_COMM_WORLD);
  return lowest == highest;
}

void MpiJob::unionOfBounds(Vec3d& lower, Vec3d& upper) const {
  double lo[3] = {lower.x, lower.y, lower.z}, hi[3] = {-upper.x, -upper.y, -upper.z}, v[6];
  double mine[6] = {lo[0], lo[1], lo[2], hi[0], hi[1], hi[2]};
  MPI_Allreduce(mine, v, 6, MPI_DOUBLE, MPI_MIN, MPI_COMM_WORLD);  // (max as the min of negatives)
  lower = {v[0], v[1], v[2]};
  upper = {-v[3], -v[4], -v[5]};
}

RenderResult MpiJob::combine(const RenderResult& mine, int framesMine, int framesAll) const {
  if (!distributed()) return mine;
  RenderResult total;
  mpi::sendCounters(mine.counters, total.counters, 0);
  // Ranks without a frame count as having every sample (they hold back nothing).
  int minMax[2] = {framesMine ? -mine.minSamples : std::numeric_limits<int>::min(), mine.maxSamples};
  int reduced[2] = {};
  MPI_Reduce(minMax, reduced, 2, MPI_INT, MPI_MAX, 0, MPI_COMM_WORLD);
  double sums[2] = {mine.meanSamples * framesMine, mine.interrupted ? 1.0 : 0.0}, summed[2] = {};
  MPI_Reduce(sums, summed, 2, MPI_DOUBLE, MPI_SUM, 0, MPI_COMM_WORLD);
  double seconds = 0;
  MPI_Reduce(&mine.seconds, &seconds, 1, MPI_DOUBLE, MPI_MAX, 0, MPI_COMM_WORLD);
  total.minSamples = -reduced[0];
  total.maxSamples = reduced[1];
  total.meanSamples = framesAll > 0 ? summed[0] / framesAll : 0;
  total.interrupted = summed[1] > 0;
  total.seconds = seconds;
  return total;
}

void RankFigures::add(const RankFigures& frame) {
  auto sum = [](auto& into, const auto& from) {
    if (into.size() < from.size()) into.resize(from.size());
    for (size_t i = 0; i < from.size(); ++i) into[i] += from[i];
  };
  sum(tiles, frame.tiles);
  sum(busySeconds, frame.busySeconds);
  sum(raysAsked, frame.raysAsked);
  sum(raysSent, frame.raysSent);
  sum(raysReceived, frame.raysReceived);
  sum(bytesSent, frame.bytesSent);
  sum(waitSeconds, frame.waitSeconds);
  sum(tilesMoved, frame.tilesMoved);
}

void MpiJob::abort(int status) const {
  std::fflush(stdout);
  std::fflush(stderr);
  if (m_initialised) MPI_Abort(MPI_COMM_WORLD, status);
  std::_Exit(status);
}

}  // namespace iso

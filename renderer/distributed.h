#pragma once
// Rendering on many processes with MPI: `mpirun -np N isotrace render ...` runs the same
// binary on every rank. Each rank loads the scene itself (volumes are read-only; every rank
// holds a whole copy). One frame: every rank renders a fixed share of the tiles (all passes of a
// tile, so a pixel's sums are the single-process sums, in the same order) and rank 0 gathers
// them; only rank 0 writes the image. A sequence (--frames): frame f
// goes to rank f mod N, which writes it. Started without an MPI launcher, nothing here touches
// MPI and the render is the single-process one. The scene and the integrators know nothing
// of this layer.
#include <string>
#include <vector>

#include "accuracy/watertight.h"
#include "renderer/render.h"

namespace iso {

// Whether an MPI launcher started this process, the ranks it started and this process's rank
// among them, from the launcher's environment (Open MPI's OMPI_COMM_WORLD_SIZE / _RANK, or
// PMI_SIZE / PMI_RANK, PMIX_RANK), without touching MPI: {false, 1, 0} when none did.
struct LaunchedRanks {
  bool launched = false;
  int size = 1, rank = 0;
};
LaunchedRanks launchedRanks();

// This process's place in an MPI job, or a job of one.
class MpiJob {
 public:
  // Joins the job when an MPI launcher started this process (Open MPI's OMPI_COMM_WORLD_SIZE,
  // or PMI_SIZE / PMIX_RANK of other launchers); otherwise MPI is never initialised.
  MpiJob();
  ~MpiJob();
  MpiJob(const MpiJob&) = delete;
  MpiJob& operator=(const MpiJob&) = delete;

  int rank() const { return m_rank; }
  int size() const { return m_size; }
  bool distributed() const { return m_size > 1; }
  // "rank R of N: " under MPI, "" otherwise: the prefix of a message only some ranks may see.
  std::string where() const;

  // Collective: every rank says what went wrong on it ("" if nothing); every rank gets the
  // message of the lowest rank that failed, prefixed with where() when that is not rank 0.
  std::string firstError(const std::string& mine) const;
  // Collective: the sum of `v` over all ranks, on every rank.
  int sum(int v) const;
  // Collective: whether every rank passed the same `v`, on every rank.
  bool sameOnEveryRank(uint64_t v) const;
  // The collectives `isotrace watertight --data-parallel` combines its ranks' answers with.
  RankExchange rankExchange() const;
  // Collective: the union of every rank's box [lower, upper] (an empty one: lower > upper), on
  // every rank.
  void unionOfBounds(Vec3d& lower, Vec3d& upper) const;
  // Collective: the frames' figures of all ranks summed (counters, samples) on rank 0.
  RenderResult combine(const RenderResult& mine, int framesMine, int framesAll) const;
  // Ends the whole job now (a rank that cannot go on; the others would wait for it forever).
  [[noreturn]] void abort(int status) const;
  // Set by a rank 0 that stopped waiting for the others (after a stop request): the job is
  // aborted instead of finalised when this object goes.
  void abandon() { m_abandoned = true; }

 private:
  int m_rank = 0, m_size = 1;
  bool m_initialised = false, m_abandoned = false;
};

// Per rank: tiles rendered and seconds its threads spent rendering them (rank 0's figures).
struct RankFigures {
  std::vector<int> tiles;
  std::vector<double> busySeconds;
  // Data-parallel: per rank, the rays of its paths, their copies it sent to other ranks (those
  // whose volume part a ray passes through), the rays other ranks sent it, the bytes it sent
  // (rays, and hits back), and the seconds it waited for other ranks' messages (busySeconds: the
  // rest of the frame's).
  std::vector<double> raysAsked, raysSent, raysReceived, bytesSent, waitSeconds;
  // Per rank, the tiles it handed to other ranks: image-parallel, to ranks that ran out; data-
  // parallel, between passes (dealTilesByCost) and during a pass to ranks that ran out.
  std::vector<int> tilesMoved;
  // Adds another frame's figures, rank by rank (a sequence's stats are its frames' sums).
  void add(const RankFigures& frame);
};

// One frame over all ranks; every rank calls it. Tile (x, y) is rank (x + y) mod N's (the
// tiles dealt along the diagonals, so each rank gets its share of any region of the image); a
// rank renders its tiles as renderFrame renders all of them (renderTiles: pass by pass, its
// threads sharing the tiles) with no message until its tiles are done, then sends their sums to
// rank 0. On rank 0 `film` (and `direct`) get the image and the result has the ray counters of
// all ranks; other ranks' films stay empty. `figures`: per rank its tiles and its render seconds.
// Bit for bit the image of renderFrame, whatever the ranks and threads.
RenderResult renderFrameDistributed(MpiJob& job, const Camera& camera, const Integrator& integrator,
                                    const RenderOptions& options, Film& film, Film* direct, RankFigures* figures);

// The test hook ISOTRACE_TEST_DEAL=first: every tile starts on rank 0, which answers each other
// rank's first request for tiles before it renders one, so that the others take all their work
// from it whatever the machine's speed (image- and data-parallel; tests/mpi_test.cpp).
bool dealAllToFirstForTest();

// Between two passes of a data-parallel frame, the tiles dealt again by what the last pass cost:
// `owner[t]` is tile t's rank, `cost[t]` the seconds its owner spent on the tile's own paths in
// that pass (camera rays, tracing them through its part, shading; not the answers it gave other
// ranks), `busy[r]` rank r's busy seconds in the pass (all of its work, answers included),
// `first[t]` the rank whose volume box the tile's centre ray enters first (-1: none). Tiles move
// from ranks busier than the mean to ranks idler than it, each while its cost fits in the gap
// between both ranks and the mean: first the receiver's own tiles (their rays find their hits in
// its part), then tiles that see no volume. A tile whose rays enter another rank's box first
// never moves there (every stage of its paths would wait for that rank's walk: measured 5-25%
// slower, docs/BENCHMARKS.md). Nothing moves when no rank is more than 3% busier than the mean.
// The same inputs give the same owners on every rank.
std::vector<int> dealTilesByCost(std::vector<int> owner, const std::vector<int>& first, const std::vector<double>& cost,
                                 const std::vector<double>& busy);

// One frame of a data-parallel render ("distribution": "data"): each rank's World holds only its
// part of each volume (SceneDesc::dataPart). Tiles go to the rank whose volume box their centre
// ray enters first, in equal shares, and are dealt again between passes by what they cost
// (dealTilesByCost); a rank renders its tiles pass by pass with the wavefront flow's stages, in
// rounds of paths of which several are in flight, and a rank with no round left to start takes
// unstarted tiles (with their sums) from another during the pass. At each stage a rank traces its own rays whole
// and sends each to the ranks whose volume part it reaches (past its own hit: no further than two
// cell diagonals), which answer against their iso-surfaces (a closest hit, or whether a shadow
// segment is blocked) whenever they look, between steps of their own; the asker keeps the
// closest hit (the lower rank on a tie) or "blocked" if any rank is. Every brick is one rank's
// and a brick's answer is the single process's (tests/data_parallel_test.cpp), and a tile's sums
// move with it, so the image is bit for bit renderFrame's. Rank 0 gathers the tiles' sums.
// Collective; `figures` gets per rank its tiles, the rays it asked and sent, the bytes it sent,
// the seconds it waited for messages and the tiles it handed over (docs/distributed.md).
RenderResult renderFrameDataParallel(MpiJob& job, const Camera& camera, const Integrator& integrator,
                                     const RenderOptions& options, Film& film, Film* direct, RankFigures* figures);

}  // namespace iso

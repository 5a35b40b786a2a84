#pragma once
// What the MPI parts of the renderer share (renderer/mpi_job.cpp, image_parallel.cpp,
// data_parallel.cpp): the messages' tags, sends that never block, whole receives, the ray
// counters summed on one rank. Internal to renderer/; the API is renderer/distributed.h.
#include <mpi.h>

#include <chrono>
#include <vector>

#include "integrators/integrator.h"
#include "renderer/distributed.h"
#include "renderer/render.h"

namespace iso::mpi {

// The tags of every message between ranks (one list, so that no two parts use one tag).
enum Tag : int {
  // Image-parallel (renderFrameDistributed), while the ranks render:
  kTakeRequest = 1,  // rank -> rank: it has rendered its tiles, may it take some of yours? (no payload)
  kHanded = 2,       // the answer: a count of tiles (0: none), then each tile's place and sums
  // At the end of a frame (image-parallel and data-parallel, gatherTiles):
  kTiles = 5,    // rank -> 0: how many tiles it rendered, then their indices
  kSums = 6,     // rank -> 0: those tiles' sums, a tile a message, in the same order
  // Data-parallel, between passes: a tile dealt to another rank, its index and sums (one message
  // a tile, in tile order).
  kMoved = 7,
  // Data-parallel, during a pass: a stage's rays asked of a rank (a flight of the asking rank,
  // named in the message), and what that rank found (an answer to one ask).
  kAsk = 16,
  kAnswer = 17,
  // Data-parallel, during a pass: a rank with no round left to start asks another for tiles
  // (the pass's index), which answers with a count of tiles (0: none), their indices and sums.
  kTakeTiles = 18,
  kGivenTiles = 19,
};

using Clock = std::chrono::steady_clock;

inline double since(Clock::time_point t) { return std::chrono::duration<double>(Clock::now() - t).count(); }

// Sends that never block: two ranks each in a blocking send of a large message to the other
// would wait for each other forever. A message's bytes live here until MPI is done with them.
class Outbox {
 public:
  void send(std::vector<char> bytes, int to, int tag);
  // Forgets the messages that are sent.
  void progress();
  // Waits until every message is sent (the receivers are still receiving).
  void drain();

 private:
  struct Pending {
    MPI_Request request;
    std::vector<char> bytes;  // moving the vector keeps its buffer where MPI has it
  };
  std::vector<Pending> m_pending;
};

// Handles every message of the two tags that has come (`handle(tag, status)`, which receives it),
// looking again until none has; whether any came.
template <typename Handle>
bool handleWhatCame(int tagA, int tagB, Handle&& handle) {
  bool any = false;
  for (bool came = true; came;) {
    came = false;
    for (int tag : {tagA, tagB}) {
      int flag = 0;
      MPI_Status status;
      MPI_Iprobe(MPI_ANY_SOURCE, tag, MPI_COMM_WORLD, &flag, &status);
      if (!flag) continue;
      came = any = true;
      handle(tag, status);
    }
  }
  return any;
}

// Receives the message `status` announced, whole.
std::vector<char> receive(const MPI_Status& status);
// The same into `buffer` (resized to the message; a buffer reused for every message of a kind
// is zeroed only where it grows).
void receive(const MPI_Status& status, std::vector<char>& buffer);

// Collective, at the end of a frame: rank 0 gathers the tiles every other rank rendered. Each
// other rank sends how many tiles it has (`mine`), their indices, then each tile's sums
// (`blockOf(i)` for the tile mine[i]: its pixels, as many as the tile has, in the order `place`
// reads them), a tile a message; rank 0 calls place(tile, block) for each, rank by rank (its own
// tiles are its caller's). A count or index out of range ends the job.
template <class BlockOf, class Place>
void gatherTiles(const MpiJob& job, const TileRenderer& tiles, const std::vector<int>& mine, BlockOf&& blockOf,
                 Place&& place) {
  if (job.rank() == 0) {
    std::vector<PixelSums> block(size_t(TileRenderer::kTile) * size_t(TileRenderer::kTile));
    for (int q = 1; q < job.size(); ++q) {
      int count = 0;
      MPI_Recv(&count, 1, MPI_INT, q, kTiles, MPI_COMM_WORLD, MPI_STATUS_IGNORE);
      if (count < 0 || count > tiles.tiles()) job.abort(1);  // (a rank of this job sent it: cannot happen)
      std::vector<int> ids(static_cast<size_t>(count));
      MPI_Recv(ids.data(), count, MPI_INT, q, kTiles, MPI_COMM_WORLD, MPI_STATUS_IGNORE);
      for (int tile : ids) {
        if (tile < 0 || tile >= tiles.tiles()) job.abort(1);
        const int n = tiles.rect(tile).pixels();
        MPI_Recv(block.data(), int(size_t(n) * sizeof(PixelSums)), MPI_BYTE, q, kSums, MPI_COMM_WORLD,
                 MPI_STATUS_IGNORE);
        place(tile, static_cast<const PixelSums*>(block.data()));
      }
    }
    return;
  }
  const int count = int(mine.size());
  MPI_Send(&count, 1, MPI_INT, 0, kTiles, MPI_COMM_WORLD);
  MPI_Send(mine.data(), count, MPI_INT, 0, kTiles, MPI_COMM_WORLD);
  for (size_t i = 0; i < mine.size(); ++i)
    MPI_Send(blockOf(i), int(size_t(tiles.rect(mine[i]).pixels()) * sizeof(PixelSums)), MPI_BYTE, 0, kSums,
             MPI_COMM_WORLD);
}

// Collective: every rank's counters summed into `total` on rank `root`.
void sendCounters(const RayCounters& mine, RayCounters& total, int root);

}  // namespace iso::mpi

#pragma once
// What the MPI parts of the renderer share (renderer/mpi_job.cpp, image_parallel.cpp,
// data_parallel.cpp): the messages' tags, sends that never block, whole receives, the ray
// counters summed on one rank. Internal to renderer/; the API is renderer/distributed.h.
#include <mpi.h>

#include <chrono>
#include <vector>

#include "integrators/integrator.h"

namespace iso::mpi {

// The tags of every message between ranks (one list, so that no two parts use one tag).
enum Tag : int {
  // Image-parallel (renderFrameDistributed). The work is a piece: the next passes of one tile,
  // at least kPieceSamples samples. Rank 0 sends the tile's sums with it and gets them back with
  // the samples added, so a pixel's sums grow in sample order whichever rank takes which passes.
  kRequest = 1,  // rank -> 0: one more piece, please (no payload)
  kPiece = 2,    // 0 -> rank: PieceHeader + the tile's sums so far; tile -1: no more
  kResult = 3,   // rank -> 0: PieceHeader + the tile's sums with the piece's samples
  kDone = 4,     // rank -> 0: every result sent, nothing more will come
  // Data-parallel (renderFrameDataParallel), at the end of the frame:
  kTiles = 5,    // rank -> 0: how many tiles it rendered, then their indices
  kSums = 6,     // rank -> 0: those tiles' sums, a tile a message, in the same order
  // Data-parallel, between passes: a tile dealt to another rank, its index and sums (one message
  // a tile, in tile order).
  kMoved = 7,
  // Data-parallel, during a pass: a stage's rays asked of a rank (a flight of the asking rank,
  // named in the message), and what that rank found (an answer to one ask).
  kAsk = 16,
  kAnswer = 17,
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

// Receives the message `status` announced, whole.
std::vector<char> receive(const MPI_Status& status);
// The same into `buffer` (resized to the message; a buffer reused for every message of a kind
// is zeroed only where it grows).
void receive(const MPI_Status& status, std::vector<char>& buffer);

// Collective: every rank's counters summed into `total` on rank `root`.
void sendCounters(const RayCounters& mine, RayCounters& total, int root);

}  // namespace iso::mpi

// Image-parallel rendering under MPI (renderFrameDistributed): rank 0 hands out pieces of tiles
// to every rank, itself included, and gathers their sums.
#include <mpi.h>
#include <tbb/concurrent_queue.h>
#include <tbb/task_arena.h>

#include <algorithm>
#include <condition_variable>
#include <cstdio>
#include <cstring>
#include <deque>
#include <mutex>
#include <thread>

#include "renderer/distributed.h"
#include "renderer/mpi_messages.h"

namespace iso {

using namespace mpi;

namespace {

constexpr int kPieceSamples = 8;  // passes of 1, 1, 2 and 4 samples are too short alone to be worth a message

struct PieceHeader {
  int32_t tile = -1;
  int32_t pass = 0, s0 = 0;  // the first pass of the piece (on return: the next one)
  int32_t open = 1;          // on return: whether the tile needs more passes
  double busySeconds = 0;
};


// A piece with its tile's sums (row-major over the tile), before and after rendering.
struct Piece {
  PieceHeader header;
  std::vector<PixelSums> sums;
};

// This rank's render threads: each takes pieces from `todo` (tile -1 ends it), renders them
// and puts them on `done`. The rank's main thread alone talks MPI (MPI_THREAD_FUNNELED).
class PieceWorkers {
 public:
  PieceWorkers(const TileRenderer& tiles, int threads) : m_tiles(tiles), m_counters(size_t(threads)) {
    for (int i = 0; i < threads; ++i) m_threads.emplace_back([this, i] { run(m_counters[size_t(i)]); });
  }
  ~PieceWorkers() { join(); }
  void push(Piece piece) { m_todo.push(std::move(piece)); }
  bool pop(Piece& piece) { return m_done.try_pop(piece); }
  // Sleeps until a piece is done or `timeout` has passed (the main thread's wait between
  // looks at MPI: it must not take the core a render thread needs).
  void waitForDone(std::chrono::microseconds timeout) {
    std::unique_lock<std::mutex> lock(m_mutex);
    m_doneChanged.wait_for(lock, timeout, [&] { return m_doneCount != m_seenCount; });
    m_seenCount = m_doneCount;
  }
  // Ends the threads once the pieces pushed so far are done; the counters of all of them.
  RayCounters join() {
    for (size_t i = 0; i < m_threads.size(); ++i) m_todo.push(Piece{});
    for (std::thread& t : m_threads) t.join();
    m_threads.clear();
    RayCounters total;
    for (const RayCounters& c : m_counters) total.add(c);
    return total;
  }

 private:
  void run(RayCounters& counters) {
    for (;;) {
      Piece piece;
      m_todo.pop(piece);
      if (piece.header.tile < 0) return;
      const auto start = Clock::now();
      PieceHeader& h = piece.header;
      h.open = m_tiles.renderPasses(h.tile, h.pass, h.s0, kPieceSamples, piece.sums.data(), counters);
      h.busySeconds = since(start);
      m_done.push(std::move(piece));
      {
        std::lock_guard<std::mutex> lock(m_mutex);
        ++m_doneCount;
      }
      m_doneChanged.notify_one();
    }
  }

  const TileRenderer& m_tiles;
  std::vector<RayCounters> m_counters;
  std::vector<std::thread> m_threads;
  tbb::concurrent_bounded_queue<Piece> m_todo;
  tbb::concurrent_queue<Piece> m_done;
  std::mutex m_mutex;
  std::condition_variable m_doneChanged;
  uint64_t m_doneCount = 0, m_seenCount = 0;
};

// A piece as bytes (header, then the sums) and back; false if the bytes are no piece of this frame.
void pack(const Piece& piece, std::vector<char>& bytes) {
  bytes.resize(sizeof(PieceHeader) + piece.sums.size() * sizeof(PixelSums));
  std::memcpy(bytes.data(), &piece.header, sizeof(PieceHeader));
  if (!piece.sums.empty())
    std::memcpy(bytes.data() + sizeof(PieceHeader), static_cast<const void*>(piece.sums.data()),
                piece.sums.size() * sizeof(PixelSums));
}

bool unpack(const std::vector<char>& bytes, const TileRenderer& tiles, int spp, Piece& piece) {
  if (bytes.size() < sizeof(PieceHeader)) return false;
  std::memcpy(&piece.header, bytes.data(), sizeof(PieceHeader));
  const PieceHeader& h = piece.header;
  if (h.tile == -1 && bytes.size() == sizeof(PieceHeader)) return true;
  if (h.tile < 0 || h.tile >= tiles.tiles() || h.pass < 0 || h.pass > spp || h.s0 < 0 || h.s0 > spp) return false;
  const size_t pixels = size_t(tiles.rect(h.tile).pixels());
  if (bytes.size() != sizeof(PieceHeader) + pixels * sizeof(PixelSums)) return false;
  piece.sums.resize(pixels);
  std::memcpy(static_cast<void*>(piece.sums.data()), bytes.data() + sizeof(PieceHeader), pixels * sizeof(PixelSums));
  return true;
}

// The main thread's wait between looks at MPI when there was nothing to do: asleep until a
// render thread finishes a piece, or for a time that doubles while nothing happens (back to the
// shortest once something does). mpirun binds each rank to one core, which the main thread
// shares with the rank's render thread: a fixed 100 us poll woke it 10,000 times a second, each
// an MPI progress call and two context switches on that core, and the render ran ~55% slower than
// in one process (docs/BENCHMARKS.md, "The image-parallel slowdown"). The wait is scaled to how
// long a piece takes (the pieces seen so far): a rank holds two pieces more than its `threads`
// render, which last it a piece's time over `threads`, so an answer within half of that is never
// waited for, and waking more often only takes the core from the render thread (starting again
// from 50 us after every message, 2 ranks switched context ~3,000 times a second each, twice as
// often as with this wait: docs/BENCHMARKS.md, issue 47's fifth session). Until a piece is done:
// from 50 us to 2 ms.
class Idle {
 public:
  explicit Idle(int threads) : m_threads(std::max(1, threads)) {}
  void wait(PieceWorkers& workers, bool busy) {
    if (busy) {
      m_wait = m_shortest;
      return;
    }
    workers.waitForDone(m_wait);
    m_wait = std::min(m_wait * 2, m_longest);
  }
  // A piece took `seconds` to render (on any rank).
  void pieceDone(double seconds) {
    if (!(seconds >= 0 && seconds < 3600)) return;  // (another rank's figure: no NaN reaches the clock)
    m_pieceSeconds += seconds;
    ++m_pieces;
    // The time between two of the rank's pieces finishing.
    const auto mean = std::chrono::duration<double>(m_pieceSeconds / double(m_pieces) / m_threads);
    m_shortest = std::clamp(std::chrono::duration_cast<std::chrono::microseconds>(mean / 2), kShortest, kLongest);
    m_longest = std::clamp(std::chrono::duration_cast<std::chrono::microseconds>(mean * 2), kLongest, kLongestScaled);
  }

 private:
  static constexpr std::chrono::microseconds kShortest{50}, kLongest{2000}, kLongestScaled{8000};
  std::chrono::microseconds m_shortest = kShortest, m_longest = kLongest, m_wait = kShortest;
  int m_threads;
  double m_pieceSeconds = 0;
  uint64_t m_pieces = 0;
};

}  // namespace

RenderResult renderFrameDistributed(MpiJob& job, const Camera& camera, const Integrator& integrator,
                                    const RenderOptions& options, Film& film, Film* direct, RankFigures* figures) {
  const int w = film.width(), h = film.height();
  const TileRenderer tiles(camera, integrator, options, w, h);
  // As many threads as the rank may use cores (TBB reads the affinity mask mpirun binds it to).
  const int threads = options.threads > 0 ? options.threads : std::max(1, tbb::this_task_arena::max_concurrency());
  const int inFlight = threads + 2;  // pieces a rank holds: some waiting beside the busy threads
  const int size = job.size();
  // Rank 0's sums of the frame, allocated (and zeroed) before the frame's clock starts, as
  // renderFrame allocates its own: on this kind of VM the page faults of ~40 MB of sums cost
  // ~0.1 s, which is not rendering.
  std::vector<PixelSums> sums(job.rank() == 0 ? size_t(w) * h : 0);
  const auto start = Clock::now();
  PieceWorkers workers(tiles, threads);
  RenderResult result;

  if (job.rank() == 0) {
    // Pieces go out pass by pass, as renderFrame renders (so a stopped render has every pixel
    // sampled alike): pending[p] holds the tiles whose pass p is next; a tile comes back before
    // its next passes go out.
    std::vector<std::deque<int>> pending(1);
    std::vector<int> passOf(size_t(tiles.tiles()), 0), startOf(size_t(tiles.tiles()), 0);
    for (int t = 0; t < tiles.tiles(); ++t) pending[0].push_back(t);
    std::vector<int> piecesOf(size_t(size), 0);
    std::vector<double> busyOf(size_t(size), 0.0);
    int out = 0, localHeld = 0, doneRanks = 0;
    uint64_t samplesDone = 0;
    const double samplesAll = double(w) * h * options.spp;
    auto take = [&](Piece& piece) {
      for (std::deque<int>& tilesOfPass : pending) {
        if (tilesOfPass.empty()) continue;
        const int t = tilesOfPass.front();
        tilesOfPass.pop_front();
        const TileRenderer::Rect r = tiles.rect(t);
        piece.header = {};
        piece.header.tile = t;
        piece.header.pass = passOf[size_t(t)];
        piece.header.s0 = startOf[size_t(t)];
        piece.sums.resize(size_t(r.pixels()));
        for (int y = r.y0; y < r.y1; ++y)
          std::copy_n(sums.begin() + ptrdiff_t(size_t(y) * w + r.x0), r.x1 - r.x0,
                      piece.sums.begin() + ptrdiff_t(size_t(y - r.y0) * (r.x1 - r.x0)));
        ++out;
        return true;
      }
      return false;
    };
    auto store = [&](const Piece& piece, int from) {
      const int t = piece.header.tile;
      const TileRenderer::Rect r = tiles.rect(t);
      for (int y = r.y0; y < r.y1; ++y)
        for (int x = r.x0; x < r.x1; ++x) {
          PixelSums& p = sums[size_t(y) * w + x];
          const PixelSums& q = piece.sums[size_t(y - r.y0) * (r.x1 - r.x0) + size_t(x - r.x0)];
          samplesDone += uint64_t((q.converged ? options.spp : q.samples) - (p.converged ? options.spp : p.samples));
          p = q;
        }
      --out;
      ++piecesOf[size_t(from)];
      busyOf[size_t(from)] += piece.header.busySeconds;
      startOf[size_t(t)] = piece.header.s0;
      const int pass = passOf[size_t(t)] = piece.header.pass;
      if (piece.header.open) {
        if (pending.size() <= size_t(pass)) pending.resize(size_t(pass) + 1);
        pending[size_t(pass)].push_back(t);
      }
    };
    std::deque<int> waiting;  // ranks that asked for a piece and have no answer yet
    Idle idle(threads);
    Outbox outbox;
    std::vector<char> bytes;
    double lastPrint = -1, stoppedAt = -1;
    bool printed = false;
    for (;;) {
      bool busy = false;
      const bool stop = stopRequested();
      if (stop && stoppedAt < 0) stoppedAt = since(start);
      for (Piece piece; !stop && localHeld < inFlight && take(piece); ++localHeld) workers.push(std::move(piece));
      for (Piece piece; workers.pop(piece); busy = true) {
        idle.pieceDone(piece.header.busySeconds);
        store(piece, 0);
        --localHeld;
      }
      int flag = 0;
      MPI_Status status;
      MPI_Iprobe(MPI_ANY_SOURCE, MPI_ANY_TAG, MPI_COMM_WORLD, &flag, &status);
      if (flag) {
        busy = true;
        const int from = status.MPI_SOURCE;
        bytes = receive(status);
        if (status.MPI_TAG == kRequest) {
          waiting.push_back(from);
        } else if (status.MPI_TAG == kResult) {
          Piece piece;
          if (!unpack(bytes, tiles, options.spp, piece) || piece.header.tile < 0) {
            std::fprintf(stderr, "isotrace: rank %d sent a malformed piece (%zu bytes)\n", from, bytes.size());
            job.abort(1);
          }
          idle.pieceDone(piece.header.busySeconds);
          store(piece, from);
        } else if (status.MPI_TAG == kDone) {
          ++doneRanks;
        } else {
          std::fprintf(stderr, "isotrace: rank %d sent an unknown message (tag %d)\n", from, status.MPI_TAG);
          job.abort(1);
        }
      }
      // A rank that asks while every remaining tile is out waits for the next pass of one;
      // "no more" (tile -1) only once all is done, or after a stop.
      for (Piece piece; !waiting.empty() && !stop && take(piece); waiting.pop_front(), busy = true) {
        pack(piece, bytes);
        outbox.send(std::move(bytes), waiting.front(), kPiece);
      }
      const bool allOut = std::all_of(pending.begin(), pending.end(), [](const std::deque<int>& d) { return d.empty(); });
      for (; !waiting.empty() && (stop || (allOut && out == 0)); waiting.pop_front()) {
        pack(Piece{}, bytes);
        outbox.send(std::move(bytes), waiting.front(), kPiece);
      }
      outbox.progress();
      if (options.progress) {
        const double elapsed = since(start);
        if (elapsed - lastPrint >= 0.25) {
          lastPrint = elapsed;
          const double fraction = std::min(1.0, double(samplesDone) / std::max(1.0, samplesAll));
          const int bar = int(fraction * 30);
          std::fprintf(stderr, "\r[%.*s%*s] %5.1f%%  elapsed %.0fs, %d ranks ", bar, "==============================",
                       30 - bar, "", fraction * 100, elapsed, size);
          std::fflush(stderr);
          printed = true;
        }
      }
      // The end: every rank said it is done, and no piece is out (after a stop: none is handed out).
      if (localHeld == 0 && doneRanks == size - 1 && out == 0) break;
      // After a stop the others get half a second to send what they have (mpirun kills its
      // ranks a second after it forwards the signal); the image is written with what came.
      if (stop && localHeld == 0 && since(start) - stoppedAt > 0.5) {
        std::fprintf(stderr, "\nisotrace: stopped waiting for %d rank(s) after the stop request\n", size - 1 - doneRanks);
        job.abandon();
        break;
      }
      idle.wait(workers, busy);
    }
    if (printed) std::fprintf(stderr, "\n");
    if (doneRanks == size - 1) outbox.drain();
    result.counters = workers.join();
    result.seconds = since(start);
    if (figures) *figures = RankFigures{piecesOf, busyOf, {}, {}, {}, {}, {}, {}};
    if (doneRanks == size - 1) {
      RayCounters total;
      sendCounters(result.counters, total, 0);
      result.counters = total;
    }
    resolveFrame(sums, options, film, direct, result);
    return result;
  }

  // Every other rank: keeps up to `inFlight` pieces asked for or in hand, returns each.
  int asked = 0, held = 0;
  bool noMore = false;
  Idle idle(threads);
  Outbox outbox;
  std::vector<char> bytes;
  for (;;) {
    bool busy = false;
    const bool stop = stopRequested();
    for (; !noMore && !stop && asked + held < inFlight; ++asked) outbox.send({}, 0, kRequest);
    int flag = 0;
    MPI_Status status;
    MPI_Iprobe(0, kPiece, MPI_COMM_WORLD, &flag, &status);
    if (flag) {
      busy = true;
      bytes = receive(status);
      --asked;
      Piece piece;
      if (!unpack(bytes, tiles, options.spp, piece)) {
        std::fprintf(stderr, "isotrace: %srank 0 sent a malformed piece (%zu bytes)\n", job.where().c_str(), bytes.size());
        job.abort(1);
      }
      if (piece.header.tile < 0) {
        noMore = true;
      } else {
        workers.push(std::move(piece));
        ++held;
      }
    }
    for (Piece piece; workers.pop(piece); busy = true) {
      idle.pieceDone(piece.header.busySeconds);
      pack(piece, bytes);
      outbox.send(std::move(bytes), 0, kResult);
      --held;
    }
    outbox.progress();
    if (held == 0 && asked == 0 && (noMore || stop)) break;
    idle.wait(workers, busy);
  }
  outbox.send({}, 0, kDone);
  outbox.drain();
  result.counters = workers.join();
  result.seconds = since(start);
  RayCounters unused;
  sendCounters(result.counters, unused, 0);
  return result;
}

}  // namespace iso

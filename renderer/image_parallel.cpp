// Image-parallel rendering under MPI (renderFrameDistributed): every rank renders a share of
// the frame's tiles as one process renders all of them, a rank that runs out takes idle tiles
// from the others, and rank 0 gathers the sums.
#include <mpi.h>

#include <algorithm>
#include <cstdio>
#include <cstdlib>
#include <cstring>
#include <deque>
#include <thread>

#include "renderer/distributed.h"
#include "renderer/mpi_messages.h"

namespace iso {

using namespace mpi;

bool dealAllToFirstForTest() {
  static const bool first = [] {
    const char* v = std::getenv("ISOTRACE_TEST_DEAL");
    return v && std::strcmp(v, "first") == 0;
  }();
  return first;
}

namespace {

// The rank that starts with tile (tileX, tileY): the tiles dealt along the diagonals, so that
// next to a tile are the other ranks' (a costly object's tiles, which lie together, are shared
// out evenly), or with ISOTRACE_TEST_DEAL=first every tile to rank 0 (dealAllToFirstForTest),
// which then answers every other rank's first request before it renders a tile.
int ownerOf(int tileX, int tileY, int ranks) { return dealAllToFirstForTest() ? 0 : (tileX + tileY) % ranks; }

// A tile handed from one rank to another: which, its next pass and that pass's first sample;
// its sums (row-major over the tile) follow.
struct HandedTile {
  int32_t tile = -1, pass = 0, s0 = 0, pad = 0;
};

// One rank's part of a frame: its tiles (those it was dealt and those it took from others), the
// answers to other ranks' requests for tiles, and its requests when it runs out.
class RankTiles {
 public:
  RankTiles(const MpiJob& job, const TileRenderer& tiles, const RenderOptions& options, std::vector<PixelSums>& frame,
            int width)
      : m_job(job), m_tiles(tiles), m_options(options), m_frame(frame), m_width(width) {}

  // The tiles this rank was dealt, their sums in the frame (rank 0) or in blocks of its own;
  // returns their pixels.
  size_t deal(const std::vector<int>& dealt) {
    size_t pixels = 0;
    for (int t : dealt) pixels += size_t(m_tiles.rect(t).pixels());
    if (m_job.rank() != 0) m_dealtSums.resize(pixels);
    m_dealt.slots.reserve(dealt.size());
    size_t at = 0;
    for (int t : dealt) {
      m_dealt.slots.push_back(slotFor(t, m_dealtSums.data() + at));
      at += size_t(m_tiles.rect(t).pixels());
    }
    return pixels;
  }

  // Renders the dealt tiles; between two of its tiles the calling (main) thread answers the
  // other ranks' requests with some of the tiles no thread is on.
  RenderResult renderDealt(ProgressBar& progress) {
    if (dealAllToFirstForTest() && m_job.rank() == 0)
      for (; m_answered < m_job.size() - 1; std::this_thread::yield()) answer(&m_dealt);
    return renderTiles(m_tiles, m_dealt, m_options, progress, [&] { answer(&m_dealt); });
  }

  // Once its own tiles are done: asks the other ranks in turn for tiles and renders what they
  // hand over (a rank that runs out may take some of them from it in turn), until every other
  // rank has said in a row that it has none (or a stop request); then waits for every rank to be
  // done, answering requests with "none" meanwhile. The result's seconds are those spent rendering.
  RenderResult takeFromOthers(ProgressBar& progress) {
    RenderResult result;
    const int ranks = m_job.size(), rank = m_job.rank();
    for (int none = 0, from = (rank + 1) % ranks; ranks > 1 && none < ranks - 1 && !stopRequested();) {
      MPI_Send(nullptr, 0, MPI_BYTE, from, kTakeRequest, MPI_COMM_WORLD);
      const size_t before = m_taken.slots.size();
      waitFor([&](const MPI_Status& status) {
        if (status.MPI_TAG != kHanded || status.MPI_SOURCE != from) return false;
        receive(status, m_bytes);
        if (!takeHanded(m_bytes)) {
          std::fprintf(stderr, "isotrace: %srank %d handed over malformed tiles (%zu bytes)\n", m_job.where().c_str(), from,
                       m_bytes.size());
          m_job.abort(1);
        }
        return true;
      });
      if (m_taken.slots.size() == before) {
        ++none;
        from = (from + 1) % ranks == rank ? (from + 2) % ranks : (from + 1) % ranks;
        continue;
      }
      none = 0;
      const RenderResult part = renderTiles(m_tiles, m_taken, m_options, progress, [&] { answer(&m_taken); });
      result.counters.add(part.counters);
      result.seconds += part.seconds;
    }
    MPI_Request everyone;
    MPI_Ibarrier(MPI_COMM_WORLD, &everyone);
    waitFor([&](const MPI_Status&) { return false; }, &everyone);
    m_outbox.drain();
    return result;
  }

  // The tiles this rank ends the frame with (dealt and not handed over, and taken) and where
  // each one's sums are (row-major over the tile, on ranks other than 0).
  std::vector<const TileSlot*> ours() const {
    std::vector<const TileSlot*> list;
    for (const TileSet* set : {&m_dealt, &m_taken})
      for (const TileSlot& slot : set->slots)
        if (slot.ours) list.push_back(&slot);
    return list;
  }
  int handedOver() const { return m_handedOver; }

 private:
  TileSlot slotFor(int tile, PixelSums* block) const {
    const TileRenderer::Rect r = m_tiles.rect(tile);
    if (m_job.rank() == 0) return TileSlot{tile, &m_frame[size_t(r.y0) * size_t(m_width) + size_t(r.x0)], size_t(m_width)};
    return TileSlot{tile, block, size_t(r.x1 - r.x0)};
  }

  // Answers every request for tiles that has come: from `from` (the tiles being rendered,
  // dealt or taken), about half of what is left that no thread is on (the tiles furthest behind first);
  // nothing once the frame is stopped or when `from` is null.
  void answer(TileSet* from) {
    for (;;) {
      int flag = 0;
      MPI_Status status;
      MPI_Iprobe(MPI_ANY_SOURCE, kTakeRequest, MPI_COMM_WORLD, &flag, &status);
      if (!flag) break;
      MPI_Recv(nullptr, 0, MPI_BYTE, status.MPI_SOURCE, kTakeRequest, MPI_COMM_WORLD, MPI_STATUS_IGNORE);
      std::vector<char> bytes(sizeof(int32_t), 0);
      if (from && !stopRequested()) hand(*from, bytes);
      m_outbox.send(std::move(bytes), status.MPI_SOURCE, kHanded);
      ++m_answered;
    }
    m_outbox.progress();
  }

  // Picks the tiles to hand over and writes them: a count, then per tile a HandedTile and its sums.
  void hand(TileSet& from, std::vector<char>& bytes) {
    std::vector<TileSlot*> idle;
    {
      std::lock_guard<std::mutex> lock(from.mutex);
      int64_t left = 0;  // samples left in the tiles still ours (an estimate: adaptive sampling may end them sooner)
      for (TileSlot& slot : from.slots) {
        if (!slot.ours || !slot.open) continue;
        left += int64_t(m_tiles.rect(slot.tile).pixels()) * (m_options.spp - slot.s0);
        if (!slot.busy) idle.push_back(&slot);
      }
      std::stable_sort(idle.begin(), idle.end(), [](const TileSlot* a, const TileSlot* b) { return a->pass < b->pass; });
      int64_t handed = 0;
      size_t n = 0;
      for (; n < idle.size() && 2 * handed < left; ++n) {
        handed += int64_t(m_tiles.rect(idle[n]->tile).pixels()) * (m_options.spp - idle[n]->s0);
        idle[n]->ours = false;
      }
      idle.resize(n);
    }
    // (The handed tiles are no thread's and no longer ours: nothing else touches them now.)
    size_t size = sizeof(int32_t);
    for (const TileSlot* slot : idle) size += sizeof(HandedTile) + size_t(m_tiles.rect(slot->tile).pixels()) * sizeof(PixelSums);
    bytes.resize(size);
    const int32_t count = int32_t(idle.size());
    std::memcpy(bytes.data(), &count, sizeof count);
    char* at = bytes.data() + sizeof count;
    for (const TileSlot* slot : idle) {
      const HandedTile head{slot->tile, slot->pass, slot->s0, 0};
      std::memcpy(at, &head, sizeof head);
      at += sizeof head;
      const TileRenderer::Rect r = m_tiles.rect(slot->tile);
      for (int y = 0; y < r.y1 - r.y0; ++y) {
        const size_t row = size_t(r.x1 - r.x0) * sizeof(PixelSums);
        std::memcpy(at, static_cast<const void*>(slot->first + size_t(y) * slot->stride), row);
        at += row;
      }
    }
    m_handedOver += count;
  }

  // Takes the tiles of a message `hand` wrote (none: an empty list) into m_taken; false if the
  // bytes are not such a message for this frame.
  bool takeHanded(const std::vector<char>& bytes) {
    int32_t count = 0;
    if (bytes.size() < sizeof count) return false;
    std::memcpy(&count, bytes.data(), sizeof count);
    if (count < 0 || count > m_tiles.tiles()) return false;
    size_t at = sizeof count;
    for (int32_t i = 0; i < count; ++i) {
      HandedTile head;
      if (bytes.size() - at < sizeof head) return false;
      std::memcpy(&head, bytes.data() + at, sizeof head);
      at += sizeof head;
      if (head.tile < 0 || head.tile >= m_tiles.tiles() || head.pass < 0 || head.pass > m_options.spp ||
          head.s0 < 0 || head.s0 >= m_options.spp)
        return false;
      const TileRenderer::Rect r = m_tiles.rect(head.tile);
      const size_t row = size_t(r.x1 - r.x0) * sizeof(PixelSums);
      if (bytes.size() - at < row * size_t(r.y1 - r.y0)) return false;
      PixelSums* block = nullptr;
      if (m_job.rank() != 0) block = m_takenSums.emplace_back(size_t(r.pixels())).data();
      TileSlot slot = slotFor(head.tile, block);
      slot.pass = head.pass;
      slot.s0 = head.s0;
      for (int y = 0; y < r.y1 - r.y0; ++y, at += row)
        std::memcpy(static_cast<void*>(slot.first + size_t(y) * slot.stride), bytes.data() + at, row);
      m_taken.slots.push_back(slot);
    }
    return at == bytes.size();
  }

  // Looks at MPI until `done` takes a message (or `request` completes), answering requests for
  // tiles with "none" meanwhile; sleeps between looks (from 20 us, doubling to 1 ms: this rank
  // has nothing to render).
  template <class Done>
  void waitFor(Done&& done, MPI_Request* request = nullptr) {
    auto wait = std::chrono::microseconds(20);
    for (;;) {
      answer(nullptr);
      int flag = 0;
      if (request) {
        MPI_Test(request, &flag, MPI_STATUS_IGNORE);
        if (flag) return;
      } else {
        MPI_Status status;
        MPI_Iprobe(MPI_ANY_SOURCE, kHanded, MPI_COMM_WORLD, &flag, &status);
        if (flag && done(status)) return;
      }
      std::this_thread::sleep_for(wait);
      wait = std::min(wait * 2, std::chrono::microseconds(1000));
    }
  }

  const MpiJob& m_job;
  const TileRenderer& m_tiles;
  const RenderOptions& m_options;
  std::vector<PixelSums>& m_frame;  // rank 0's
  int m_width;
  TileSet m_dealt, m_taken;
  std::vector<PixelSums> m_dealtSums;            // other ranks: the dealt tiles' sums, tile after tile
  std::deque<std::vector<PixelSums>> m_takenSums;  // other ranks: each taken tile's
  Outbox m_outbox;
  std::vector<char> m_bytes;
  int m_handedOver = 0, m_answered = 0;
};

}  // namespace

RenderResult renderFrameDistributed(MpiJob& job, const Camera& camera, const Integrator& integrator,
                                    const RenderOptions& options, Film& film, Film* direct, RankFigures* figures) {
  const int w = film.width(), h = film.height();
  const TileRenderer tiles(camera, integrator, options, w, h);
  const int rank = job.rank(), ranks = job.size();
  std::vector<int> dealt;
  for (int t = 0; t < tiles.tiles(); ++t) {
    const TileRenderer::Rect r = tiles.rect(t);
    if (ownerOf(r.x0 / TileRenderer::kTile, r.y0 / TileRenderer::kTile, ranks) == rank) dealt.push_back(t);
  }

  // The sums, allocated (and zeroed) before the frame's clock starts, as renderFrame allocates
  // its own (on this kind of VM the page faults of ~40 MB of sums cost ~0.1 s, which is not
  // rendering): rank 0 renders in place in the frame's sums; another rank keeps its tiles' sums
  // one block after another, about 1 / ranks of a frame's.
  std::vector<PixelSums> sums(rank == 0 ? size_t(w) * size_t(h) : 0);
  RankTiles mine(job, tiles, options, sums, w);
  const size_t pixels = mine.deal(dealt);

  const auto start = Clock::now();
  ProgressBar progress(options, pixels);  // (the bar shows this rank's share)
  RenderResult own = mine.renderDealt(progress);
  const RenderResult taken = mine.takeFromOthers(progress);
  own.counters.add(taken.counters);
  const double busy = own.seconds + taken.seconds;
  progress.finish();

  RenderResult result;
  sendCounters(own.counters, result.counters, 0);
  const std::vector<const TileSlot*> ours = mine.ours();
  std::vector<int> ids;
  for (const TileSlot* slot : ours) ids.push_back(slot->tile);
  gatherTiles(
      job, tiles, ids, [&](size_t i) { return ours[i]->first; },
      [&](int tile, const PixelSums* block) {
        const TileRenderer::Rect r = tiles.rect(tile);
        for (int y = r.y0; y < r.y1; ++y, block += r.x1 - r.x0)
          std::copy_n(block, r.x1 - r.x0, sums.begin() + ptrdiff_t(size_t(y) * size_t(w) + size_t(r.x0)));
      });
  const double figuresMine[3] = {double(ours.size()), busy, double(mine.handedOver())};
  std::vector<double> figuresAll(size_t(3 * ranks));
  MPI_Gather(figuresMine, 3, MPI_DOUBLE, figuresAll.data(), 3, MPI_DOUBLE, 0, MPI_COMM_WORLD);
  result.seconds = since(start);
  if (rank != 0) return result;
  if (figures) {
    *figures = RankFigures{};
    for (int q = 0; q < ranks; ++q) {
      figures->tiles.push_back(int(figuresAll[size_t(3 * q)]));
      figures->busySeconds.push_back(figuresAll[size_t(3 * q + 1)]);
      figures->tilesMoved.push_back(int(figuresAll[size_t(3 * q + 2)]));
    }
  }
  resolveFrame(sums, options, film, direct, result);
  return result;
}

}  // namespace iso

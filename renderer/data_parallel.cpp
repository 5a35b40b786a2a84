// Data-parallel rendering under MPI (renderFrameDataParallel): each rank holds part of every
// volume and the ranks answer each other's rays (docs/distributed.md).
#include <mpi.h>
#include <tbb/blocked_range.h>
#include <tbb/enumerable_thread_specific.h>
#include <tbb/parallel_for.h>
#include <tbb/task_arena.h>

#include <algorithm>
#include <cstdio>
#include <cstring>
#include <limits>
#include <type_traits>

#include "renderer/distributed.h"
#include "renderer/mpi_messages.h"
#include "renderer/wavefront.h"

namespace iso {

using namespace mpi;

namespace {

// (The hits a rank answers are of iso-surfaces only, the rays' mask says so: a triangle hit's
// pointers into its rank's meshes, Hit::triangles and toWorld, never travel.)
static_assert(std::is_trivially_copyable_v<Ray> && std::is_trivially_copyable_v<Hit>,
              "rays and hits go between ranks as bytes (every rank runs the same binary)");

// One stage of a round of paths (its camera, shadow or continuation rays) on its way through the
// ranks: this rank's rays and what is known of them so far, and the rays the other ranks asked of
// this rank in the same stage.
struct Flight {
  RayBatch batch;        // this rank's rays (a Wave's stage)
  std::vector<int> from;  // the rank whose hit batch.hits holds
  std::vector<Ray> theirs;  // the rays other ranks sent here, and where they came from
  std::vector<int> theirIndex, theirRank;
  std::vector<std::vector<char>> asks, backs;  // this rank's messages, by rank, being written
};

// The ranks of a data-parallel render answering each other's rays. A rank traces its own rays
// whole (meshes, which every rank holds, and its part of the volumes) and sends each to the other
// ranks whose volume part the ray's segment passes through, which trace it against their
// iso-surfaces only (World::kVolumeMask) and send back what they found (hits only). A stage is
// three steps — ask, answer, gather — that every rank takes for each flight of a slot in the same
// order (the slots in any order: a slot's messages pair up by their tag and order alone).
// Messages go point to point and never block the sender, so a rank waits only when no slot has
// the messages its next step needs.
class RankTracer {
 public:
  RankTracer(const World& world, tbb::task_arena& arena, int rank, int ranks)
      : m_world(world), m_arena(arena), m_rank(rank), m_ranks(ranks), m_cell(world.largestCell()),
        m_lower(size_t(ranks)), m_upper(size_t(ranks)) {
    // Every rank's volume box, on every rank.
    Vec3d lo, hi;
    world.volumeBounds(lo, hi);
    double mine[6] = {lo.x, lo.y, lo.z, hi.x, hi.y, hi.z};
    std::vector<double> all(static_cast<size_t>(6 * ranks));
    MPI_Allgather(mine, 6, MPI_DOUBLE, all.data(), 6, MPI_DOUBLE, MPI_COMM_WORLD);
    // Padded for rounding (a ray's segment is tested in double against the box of bricks).
    for (int r = 0; r < ranks; ++r) {
      const double* b = &all[size_t(6 * r)];
      for (int a = 0; a < 3; ++a) {
        const double pad = 1e-6 * (std::fabs(b[a]) + std::fabs(b[3 + a]) + (b[3 + a] - b[a])) + 1e-9;
        m_lower[size_t(r)][a] = b[a] - pad;
        m_upper[size_t(r)][a] = b[3 + a] + pad;
      }
    }
  }

  // Step 1: this rank traces its batch whole and sends each to the other ranks whose volume box its
  // segment reaches: a shadow ray only if nothing here blocks it; a closest-hit ray that hit here
  // shortened to two cell diagonals past the hit. (The others need only look before the hit, but
  // their walks must cut the ray's cells where the single process cuts them, at the ray's end, or
  // a hit's bits could change: no cell of a closer hit reaches that far, and they hold no brick the
  // shortened ray does not reach either way.) Camera rays go in the batch's packets, as in one
  // process. `more`: whether this rank's round still has paths asking for rays (sent with a shadow
  // stage's rays; the round ends when no rank's has).
  void ask(Flight& f, int slot, bool more, TraversalStats& stats) {
    RayBatch& b = f.batch;
    const size_t n = b.size();
    f.from.assign(n, m_rank);
    parallel(b.units(), stats, [&](size_t u, TraversalStats& s) { traceBatch(m_world, b, u, u + 1, s); });
    f.asks.resize(size_t(m_ranks));
    const int32_t header[2] = {more ? 1 : 0, 0};
    for (std::vector<char>& bytes : f.asks) bytes.assign(reinterpret_cast<const char*>(header), reinterpret_cast<const char*>(header + 2));
    for (size_t i = 0; i < n; ++i) {
      if (b.shadow && b.found[i]) continue;
      Asked a{b.rays[i], int(i)};
      if (!b.shadow && b.found[i]) {
        const float reach = float(2 * m_cell / double(length(a.ray.dir)));
        a.ray.tfar = std::min(a.ray.tfar, std::nextafter(b.hits[i].t + reach, INFINITY) * (1 + 1e-6f));
      }
      for (int q = 0; q < m_ranks; ++q)
        if (q != m_rank && reaches(a.ray, q)) {
          append(f.asks[size_t(q)], a);
          raysSent += 1;
        }
    }
    raysAsked += double(n);
    for (int q = 0; q < m_ranks; ++q)
      if (q != m_rank) post(f.asks[size_t(q)], q, kAsk + 2 * slot);
  }

  // Step 2: the rays the other ranks sent in this stage, traced against this rank's iso-surfaces,
  // and what they found sent back. False when this is a shadow stage and no rank's round had paths
  // asking for rays (`more`, this rank's): the round is over and nothing was sent.
  bool answer(Flight& f, int slot, bool more, TraversalStats& stats) {
    f.theirs.clear();
    f.theirIndex.clear();
    f.theirRank.clear();
    bool any = more;
    for (int q = 0; q < m_ranks; ++q) {
      if (q == m_rank) continue;
      const std::vector<char> bytes = receiveFrom(q, kAsk + 2 * slot);
      int32_t header[2];
      if (bytes.size() < sizeof(header) || (bytes.size() - sizeof(header)) % sizeof(Asked) != 0)
        MPI_Abort(MPI_COMM_WORLD, 1);  // (a rank of this job sent it: cannot happen)
      std::memcpy(header, bytes.data(), sizeof(header));
      any = any || header[0] != 0;
      for (size_t at = sizeof(header); at < bytes.size(); at += sizeof(Asked)) {
        Asked a;
        std::memcpy(static_cast<void*>(&a), bytes.data() + at, sizeof(Asked));
        f.theirs.push_back(a.ray);
        f.theirIndex.push_back(a.index);
        f.theirRank.push_back(q);
      }
    }
    const bool shadow = f.batch.shadow;
    if (shadow && !any) return false;
    raysReceived += double(f.theirs.size());
    std::vector<Found> answers(f.theirs.size());
    parallel(f.theirs.size(), stats, [&](size_t k, TraversalStats& s) {
      Ray r = f.theirs[k];
      r.mask = World::kVolumeMask;
      answers[k].index = f.theirIndex[k];
      answers[k].found = shadow ? m_world.occluded(r, s) : m_world.intersect(r, answers[k].hit, s);
    });
    // Back to the rank that asked: the hits found with the index of the ray in its flight (a
    // shadow ray: the index alone, of the rays found blocked).
    f.backs.resize(size_t(m_ranks));
    for (std::vector<char>& bytes : f.backs) bytes.clear();
    for (size_t k = 0; k < answers.size(); ++k) {
      if (!answers[k].found) continue;
      std::vector<char>& bytes = f.backs[size_t(f.theirRank[k])];
      if (shadow)
        append(bytes, answers[k].index);
      else
        append(bytes, answers[k]);
    }
    for (int q = 0; q < m_ranks; ++q)
      if (q != m_rank) post(f.backs[size_t(q)], q, kAsk + 1 + 2 * slot);
    return true;
  }

  // Step 3: the other ranks' answers. Then the batch's found and hits are those of the whole
  // scene: the closest hit, of equal ones the lowest rank's; a shadow ray blocked if any rank
  // blocks it.
  void gather(Flight& f, int slot) {
    RayBatch& b = f.batch;
    const size_t n = b.size();
    for (int q = 0; q < m_ranks; ++q) {
      if (q == m_rank) continue;
      const std::vector<char> bytes = receiveFrom(q, kAsk + 1 + 2 * slot);
      const size_t size = b.shadow ? sizeof(int) : sizeof(Found);
      if (bytes.size() % size != 0) MPI_Abort(MPI_COMM_WORLD, 1);
      for (size_t at = 0; at < bytes.size(); at += size) {
        Found a;
        if (b.shadow)
          std::memcpy(&a.index, bytes.data() + at, sizeof(int));
        else
          std::memcpy(static_cast<void*>(&a), bytes.data() + at, sizeof(Found));
        const size_t i = size_t(a.index);
        if (a.index < 0 || i >= n) MPI_Abort(MPI_COMM_WORLD, 1);
        if (b.shadow) {
          b.found[i] = 1;
        } else if (!b.found[i] || a.hit.t < b.hits[i].t || (a.hit.t == b.hits[i].t && q < f.from[i])) {
          b.hits[i] = a.hit;
          b.found[i] = 1;
          f.from[i] = q;
        }
      }
    }
  }

  // Whether the messages the next step of slot `slot` needs (`back`: answers, for gather; or
  // rays, for answer) have come from every other rank.
  bool arrived(int slot, bool back) {
    for (int q = 0; q < m_ranks; ++q) {
      int flag = 1;
      if (q != m_rank) MPI_Iprobe(q, kAsk + (back ? 1 : 0) + 2 * slot, MPI_COMM_WORLD, &flag, MPI_STATUS_IGNORE);
      if (!flag) return false;
    }
    return true;
  }
  // Time spent looking for messages that had not come (`since`: when the look began).
  void waited(Clock::time_point since) {
    m_outbox.progress();
    waitSeconds += iso::since(since);
  }
  // Waits until every message this rank sent is taken.
  void drain() {
    const auto t0 = Clock::now();
    m_outbox.drain();
    waitSeconds += since(t0);
  }

  // The rank that renders each tile. The tiles whose centre ray passes through a volume box are
  // dealt first, each to the rank whose box that ray enters first while it has fewer than its
  // share of them (their number over the ranks, rounded up), the rest of them to the ranks with
  // room in turn; then the tiles that see no volume box, in turn, to the ranks with the fewest
  // tiles. A rank's camera rays then mostly find their hits in its own part and go nowhere else
  // (dealt t mod N, half of them entered the other rank's box first), and every rank has about as
  // many tiles of each kind.
  std::vector<int> tileOwners(const TileRenderer& tiles, const Camera& camera) const {
    const int n = tiles.tiles();
    std::vector<int> owner(size_t(n), -1), first(size_t(n), -1), count(size_t(m_ranks), 0);
    int seeing = 0;  // tiles whose centre ray passes through a box
    for (int t = 0; t < n; ++t) {
      const TileRenderer::Rect r = tiles.rect(t);
      const Ray ray = camera.generateRay(0.5f * float(r.x0 + r.x1), 0.5f * float(r.y0 + r.y1));
      double firstT = INFINITY, enters = 0;
      for (int q = 0; q < m_ranks; ++q)
        if (reaches(ray, q, &enters) && enters < firstT) {
          first[size_t(t)] = q;
          firstT = enters;
        }
      if (first[size_t(t)] >= 0) ++seeing;
    }
    const int share = (seeing + m_ranks - 1) / m_ranks;
    for (int t = 0; t < n; ++t) {
      const int q = first[size_t(t)];
      if (q >= 0 && count[size_t(q)] < share) {
        owner[size_t(t)] = q;
        ++count[size_t(q)];
      }
    }
    // The rest, each to the rank with the fewest tiles so far (the lowest of equal ones).
    for (bool seen : {true, false})
      for (int t = 0; t < n; ++t) {
        if (owner[size_t(t)] >= 0 || (first[size_t(t)] >= 0) != seen) continue;
        const int q = int(std::min_element(count.begin(), count.end()) - count.begin());
        owner[size_t(t)] = q;
        ++count[size_t(q)];
      }
    return owner;
  }

  // Whether any rank says yes (collective).
  bool anyRank(bool mine) {
    const auto t0 = Clock::now();
    int v = mine ? 1 : 0, all = 0;
    MPI_Allreduce(&v, &all, 1, MPI_INT, MPI_LOR, MPI_COMM_WORLD);
    waitSeconds += since(t0);
    return all != 0;
  }

  // Rays of this rank's paths, their copies sent to other ranks, the rays other ranks sent it,
  // bytes this rank sent, seconds it spent waiting for other ranks' messages and for its own to
  // be taken.
  double raysAsked = 0, raysSent = 0, raysReceived = 0, bytesSent = 0, waitSeconds = 0;

 private:
  struct Found {
    Hit hit;
    int index = 0;  // of the ray in the asking rank's flight
    int found = 0;
  };
  // A ray sent to another rank, with its index in this rank's flight.
  struct Asked {
    Ray ray;
    int index;
  };

  template <typename T>
  static void append(std::vector<char>& bytes, const T& value) {
    const char* p = reinterpret_cast<const char*>(&value);
    bytes.insert(bytes.end(), p, p + sizeof(T));
  }

  void post(std::vector<char>& bytes, int to, int tag) {
    m_outbox.progress();  // the buffers of the messages taken go (a busy rank may never wait)
    bytesSent += double(bytes.size());
    m_outbox.send(std::move(bytes), to, tag);
    bytes.clear();
  }

  std::vector<char> receiveFrom(int q, int tag) {
    const auto t0 = Clock::now();
    MPI_Status status;
    MPI_Probe(q, tag, MPI_COMM_WORLD, &status);
    std::vector<char> bytes = receive(status);
    waitSeconds += since(t0);
    return bytes;
  }

  // Whether the segment of `r` passes through rank q's volume box (padded for rounding), and
  // where it enters it (`enters`, a parameter of `r`).
  bool reaches(const Ray& r, int q, double* enters = nullptr) const {
    const Vec3d lo = m_lower[size_t(q)], hi = m_upper[size_t(q)];
    if (!(lo.x <= hi.x)) return false;
    const Vec3d o = r.origin(), d(r.dir);
    double t0 = r.tnear, t1 = r.tfar;
    for (int a = 0; a < 3; ++a) {
      if (d[a] == 0) {
        if (o[a] < lo[a] || o[a] > hi[a]) return false;
        continue;
      }
      const double inv = 1 / d[a];
      double ta = (lo[a] - o[a]) * inv, tb = (hi[a] - o[a]) * inv;
      if (ta > tb) std::swap(ta, tb);
      t0 = std::max(t0, ta);
      t1 = std::min(t1, tb);
    }
    if (enters) *enters = t0;
    return t0 <= t1 * (1 + 1e-6) + 1e-9;
  }

  // answer(i, stats) for i in [0, n), on this rank's threads.
  template <typename F>
  void parallel(size_t n, TraversalStats& stats, F&& answer) {
    tbb::enumerable_thread_specific<TraversalStats> local;
    m_arena.execute([&] {
      tbb::parallel_for(tbb::blocked_range<size_t>(0, n, 16), [&](const tbb::blocked_range<size_t>& r) {
        TraversalStats& s = local.local();
        for (size_t i = r.begin(); i < r.end(); ++i) answer(i, s);
      });
    });
    for (const TraversalStats& s : local) stats.add(s);
  }

  const World& m_world;
  tbb::task_arena& m_arena;
  int m_rank, m_ranks;
  double m_cell;  // World::largestCell
  std::vector<Vec3d> m_lower, m_upper;
  Outbox m_outbox;
};

// A round of paths: a pass's samples of a run of this rank's pixels (a Wave), in one slot of the
// pipeline. Its next step: start (the slot's next round, if any, and its camera rays), answer (the
// other ranks' rays of its flight), gather (their answers, then the paths' next stage); idle when
// the slot has no more rounds in the pass.
struct Round {
  enum Step { kStart, kAnswer, kGather, kIdle } step = kIdle;
  size_t index = 0;       // of the round in the pass: slot k takes rounds k, k + kSlots, ...
  bool more = false;      // paths still asking for rays (this rank's)
  size_t p0 = 0, p1 = 0;  // its pixels, of this rank's
  Wave wave;
  Flight flight;
};

}  // namespace

RenderResult renderFrameDataParallel(MpiJob& job, const Camera& camera, const Integrator& integrator,
                                     const RenderOptions& options, Film& film, Film* direct, RankFigures* figures) {
  const int w = film.width(), h = film.height(), ranks = job.size(), rank = job.rank();
  const TileRenderer tiles(camera, integrator, options, w, h);
  const World& world = integrator.world();
  tbb::task_arena arena(options.threads > 0 ? options.threads : tbb::task_arena::automatic);
  RankTracer tracer(world, arena, rank, ranks);
  tbb::enumerable_thread_specific<RayCounters> counters;
  RayCounters traced;  // the traversal of the rays this rank traced and answered
  // The tiles this rank rendered, and their sums (in packet order, forEachPixelInPacketOrder).
  std::vector<int> mine;
  std::vector<PixelSums> sums;
  std::vector<Wave::Pixel> pixels;  // this rank's pixels (x, y), tile by tile; sums alike
  const std::vector<int> owner = tracer.tileOwners(tiles, camera);
  for (int tile = 0; tile < tiles.tiles(); ++tile) {
    if (owner[size_t(tile)] != rank) continue;
    mine.push_back(tile);
    forEachPixelInPacketOrder(tiles.rect(tile), [&](int x, int y) { pixels.emplace_back(x, y); });
  }
  sums.resize(pixels.size());
  // Rank 0's frame, which gathers every rank's tiles. Both are allocated (and zeroed) before the
  // frame's clock starts, as renderFrame allocates its sums: the render seconds of one process and
  // of the ranks count the same work.
  std::vector<PixelSums> frame(rank == 0 ? size_t(w) * size_t(h) : 0);
  const auto start = Clock::now();
  // The answers to the round's stage, to its paths, on this rank's threads.
  auto deliver = [&](Round& round) {
    const RayBatch& b = round.flight.batch;
    arena.execute([&] {
      tbb::parallel_for(tbb::blocked_range<size_t>(0, b.size(), 16), [&](const tbb::blocked_range<size_t>& r) {
        round.wave.deliver(b, r.begin(), r.end(), counters.local());
      });
    });
  };
  // The wavefront flow's stages (a Wave's, as TileRenderer::renderPassWavefront takes them) for
  // rounds of paths: camera rays, then shadow rays and continuation rays, until no path of the
  // round on any rank asks for one. A pass goes through this rank's pixels in rounds of kPathsPerRound paths (as many rounds
  // on every rank: the busiest one's), kSlots rounds in flight: a rank takes the next step of any
  // slot whose messages have come, so that while the other ranks answer one round's rays it traces
  // another's. All tiles take a pass (1, 1, 2, 4, 8, 16, 16, ... samples, as in one process) before
  // any takes the next, so that a stop request, honoured after each pass (once the first is done),
  // leaves every pixel sampled. (One round of 8,192 paths at a time, every rank in lockstep: the
  // exchanges, whose cost is mostly per stage, wanted many rays each — 2,048: twice as long in
  // them; 32,768: the paths left the caches. docs/BENCHMARKS.md, "Data-parallel rendering".)
  constexpr int kSlots = 4;
  constexpr int kPathsPerRound = 2048;
  std::vector<Round> slots(kSlots);
  const size_t mostPixels = size_t((tiles.tiles() + ranks - 1) / ranks) * TileRenderer::kTile * TileRenderer::kTile;  // (share)
  int s0 = 0;
  for (int pass = 0; s0 < options.spp; ++pass) {
    const int s1 = TileRenderer::nextPassStart(s0, pass, options.spp), ns = s1 - s0;
    const size_t maxPixels = std::max<size_t>(1, size_t(kPathsPerRound) / size_t(ns));
    const size_t rounds = (mostPixels + maxPixels - 1) / maxPixels;
    for (int k = 0; k < kSlots; ++k) {
      slots[size_t(k)].step = Round::kStart;
      slots[size_t(k)].index = size_t(k);
    }
    auto finish = [&](Round& round) {
      round.wave.finish([&](size_t i) -> PixelSums& { return sums[round.p0 + i]; });
    };
    auto begin = [&](Round& round) {
      round.p0 = std::min(pixels.size(), round.index * maxPixels);
      round.p1 = std::min(pixels.size(), round.p0 + maxPixels);
      round.wave.start(camera, integrator, options, pixels.data() + round.p0, round.p1 - round.p0, s0, s1);
      round.wave.collect(round.flight.batch);
    };
    // The answers to the round's last stage, then its next stage: shadow rays after closest-hit
    // rays (or the round's end: see RankTracer::answer), closest-hit rays after shadow rays.
    auto advance = [&](Round& round, int slot) {
      tracer.gather(round.flight, slot);
      deliver(round);
      if (!round.flight.batch.shadow) round.more = round.wave.pending();
      round.wave.collect(round.flight.batch);
    };
    for (;;) {
      const auto look = Clock::now();
      bool open = false, stepped = false;
      for (int k = 0; k < kSlots; ++k) {
        Round& round = slots[size_t(k)];
        if (round.step == Round::kIdle) continue;
        open = true;
        if (round.step == Round::kStart) {
          if (round.index >= rounds) {
            round.step = Round::kIdle;
            continue;
          }
          begin(round);
        } else if (round.step == Round::kAnswer) {
          if (!tracer.arrived(k, false)) continue;
          stepped = true;
          if (tracer.answer(round.flight, k, round.more, traced.traversal)) {
            round.step = Round::kGather;
          } else {  // the round is over on every rank
            finish(round);
            round.index += kSlots;
            round.step = Round::kStart;
          }
          continue;
        } else {
          if (!tracer.arrived(k, true)) continue;
          advance(round, k);
        }
        stepped = true;
        tracer.ask(round.flight, k, round.more, traced.traversal);
        round.step = Round::kAnswer;
      }
      if (!open) break;
      if (!stepped) tracer.waited(look);
    }
    s0 = s1;
    if (tracer.anyRank(stopRequested())) break;  // any rank's request: every rank stops here
  }
  // Every rank knows whether the frame stopped short (a sequence then ends on every rank).
  const bool stoppedShort = s0 < options.spp;
  tracer.drain();



  // Rank 0 gathers every rank's tiles.
  RenderResult result;
  RayCounters mineCounters = traced;
  for (const RayCounters& c : counters) mineCounters.add(c);
  sendCounters(mineCounters, result.counters, 0);
  // Rank by rank, point to point, in pieces of at most 64 MiB (a large image's sums pass 2 GiB,
  // MPI's counts are int), rank 0 placing each tile's pixels straight into the frame's sums.
  constexpr size_t kChunk = (size_t(64) << 20) / sizeof(PixelSums);
  auto place = [&](const std::vector<int>& ids, auto&& next) {  // next(): the next pixel's sums
    for (int tile : ids)
      forEachPixelInPacketOrder(tiles.rect(tile), [&](int x, int y) { frame[size_t(y) * size_t(w) + size_t(x)] = next(); });
  };
  if (rank == 0) {
    size_t at = 0;
    place(mine, [&] { return sums[at++]; });
    for (int q = 1; q < ranks; ++q) {
      int count = 0;
      MPI_Recv(&count, 1, MPI_INT, q, kTiles, MPI_COMM_WORLD, MPI_STATUS_IGNORE);
      if (count < 0 || count > tiles.tiles()) job.abort(1);  // (a rank of this job sent it: cannot happen)
      std::vector<int> ids(static_cast<size_t>(count));
      MPI_Recv(ids.data(), count, MPI_INT, q, kTiles, MPI_COMM_WORLD, MPI_STATUS_IGNORE);
      size_t pixelsOf = 0;
      for (int tile : ids) {
        if (tile < 0 || tile >= tiles.tiles()) job.abort(1);
        pixelsOf += size_t(tiles.rect(tile).pixels());
      }
      std::vector<PixelSums> piece;
      size_t used = 0, left = pixelsOf;
      place(ids, [&] {
        if (used == piece.size()) {
          piece.resize(std::min(kChunk, left));
          MPI_Recv(piece.data(), int(piece.size() * sizeof(PixelSums)), MPI_BYTE, q, kSums, MPI_COMM_WORLD,
                   MPI_STATUS_IGNORE);
          left -= piece.size();
          used = 0;
        }
        return piece[used++];
      });
    }
  } else {
    const int count = int(mine.size());
    MPI_Send(&count, 1, MPI_INT, 0, kTiles, MPI_COMM_WORLD);
    MPI_Send(mine.data(), count, MPI_INT, 0, kTiles, MPI_COMM_WORLD);
    for (size_t at = 0; at < sums.size(); at += kChunk) {
      const size_t n = std::min(kChunk, sums.size() - at);
      MPI_Send(&sums[at], int(n * sizeof(PixelSums)), MPI_BYTE, 0, kSums, MPI_COMM_WORLD);
    }
  }
  result.seconds = since(start);
  constexpr int kFigures = 5;
  double asked[kFigures] = {tracer.raysAsked, tracer.raysSent, tracer.raysReceived, tracer.bytesSent, tracer.waitSeconds};
  std::vector<double> allAsked(static_cast<size_t>(kFigures * ranks));
  MPI_Gather(asked, kFigures, MPI_DOUBLE, allAsked.data(), kFigures, MPI_DOUBLE, 0, MPI_COMM_WORLD);
  if (rank != 0) {
    result.interrupted = stoppedShort;
    return result;
  }
  if (figures) {
    figures->tiles.assign(static_cast<size_t>(ranks), 0);
    for (int t : owner) ++figures->tiles[size_t(t)];
    figures->raysAsked.clear();
    figures->raysSent.clear();
    figures->raysReceived.clear();
    figures->bytesSent.clear();
    figures->busySeconds.clear();
    figures->waitSeconds.clear();
    for (int q = 0; q < ranks; ++q) {
      const double* f = &allAsked[size_t(kFigures * q)];
      figures->raysAsked.push_back(f[0]);
      figures->raysSent.push_back(f[1]);
      figures->raysReceived.push_back(f[2]);
      figures->bytesSent.push_back(f[3]);
      figures->waitSeconds.push_back(f[4]);
      figures->busySeconds.push_back(std::max(0.0, result.seconds - f[4]));
    }
  }
  resolveFrame(frame, options, film, direct, result);
  return result;
}

}  // namespace iso


// Data-parallel rendering under MPI (renderFrameDataParallel): each rank holds part of every
// volume and the ranks answer each other's rays (docs/distributed.md).
#include <mpi.h>
#include <tbb/blocked_range.h>
#include <tbb/enumerable_thread_specific.h>
#include <tbb/parallel_for.h>
#include <tbb/task_arena.h>

#include <algorithm>
#include <cfloat>
#include <cstdio>
#include <cstddef>
#include <cstdlib>
#include <cstring>
#include <limits>
#include <memory>
#include <string>
#include <type_traits>

#include "renderer/ask_filter.h"
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
// ranks: this rank's rays, what is known of them so far, and how many ranks have yet to answer.
struct Flight {
  RayBatch batch;         // this rank's rays (a Wave's stage)
  std::vector<int> from;  // the rank whose hit batch.hits holds
  int waiting = 0;        // ranks asked about this stage's rays that have not answered yet
  uint32_t stage = 0;     // counts the flight's stages (an answer names the stage it answers)
};

// The ranks of a data-parallel render answering each other's rays. A rank traces its own rays
// whole (meshes, which every rank holds, and its part of the volumes) and sends each to the other
// ranks whose volume part the ray's segment passes through, which trace it against their
// iso-surfaces only (World::kVolumeMask) and send back what they found (hits only). Asking and
// answering are independent: a rank answers whatever rays have come whenever it looks (serve),
// between steps of its own, and a flight waits only for the answers of the ranks it asked. So a
// rank never waits for another rank's own work, only for its answers; messages go only to the
// ranks a stage's rays reach, point to point, never blocking the sender.
class RankTracer {
 public:
  RankTracer(const World& world, tbb::task_arena& arena, int rank, int ranks)
      : m_world(world), m_arena(arena), m_rank(rank), m_ranks(ranks), m_cell(world.largestCell()),
        m_selected(size_t(ranks)), m_ask(size_t(ranks)) {
    // Every rank's boxes of each split volume (those with iso-surfaces), on every rank: the
    // cells it answers for and the cells it holds.
    std::vector<char> split(world.volumes().size(), 0);
    for (const SurfaceInfo& s : world.surfaces()) split[size_t(s.volume)] = 1;
    std::vector<const VolumeInfo*> volumes;
    std::vector<int> mine;
    for (size_t v = 0; v < split.size(); ++v) {
      if (!split[v]) continue;
      const VolumeInfo& vol = world.volumes()[v];
      volumes.push_back(&vol);
      for (const Vec3i& c : {vol.ownLo, vol.ownHi, vol.heldLo, vol.heldHi}) mine.insert(mine.end(), {c.x, c.y, c.z});
    }
    std::vector<int> all(mine.size() * size_t(ranks));
    MPI_Allgather(mine.data(), int(mine.size()), MPI_INT, all.data(), int(mine.size()), MPI_INT, MPI_COMM_WORLD);
    for (size_t k = 0; k < volumes.size(); ++k) {
      std::vector<Vec3i> cells;  // by rank: own lo, hi, held lo, hi
      for (int q = 0; q < ranks; ++q)
        for (int c = 0; c < 4; ++c) {
          const int* at = &all[size_t(q) * mine.size() + 12 * k + size_t(3 * c)];
          cells.push_back({at[0], at[1], at[2]});
        }
      m_volumes.push_back(SplitVolume(*volumes[k], cells, rank));
      m_asksAny = m_asksAny || !m_volumes.back().holdsAll;
    }
  }

  // This rank traces the flight's batch whole and sends each ray to the other ranks whose volume
  // box its segment reaches: a shadow ray only if nothing here blocks it; a closest-hit ray that
  // hit here shortened to two cell diagonals past the hit. (The others need only look before the
  // hit, but their walks must cut the ray's cells where the single process cuts them, at the ray's
  // end, or a hit's bits could change: no cell of a closer hit reaches that far, and they hold no
  // brick the shortened ray does not reach either way.) Camera rays go in the batch's packets, as
  // in one process. `slot` names the flight in the messages; f.waiting counts the ranks asked.
  void ask(Flight& f, int slot, TraversalStats& stats) {
    RayBatch& b = f.batch;
    const size_t n = b.size();
    ++f.stage;
    f.from.assign(n, m_rank);
    parallel(b.units(), stats, [&](size_t u, TraversalStats& s) { traceBatch(m_world, b, u, u + 1, s); });
    // The rays each rank is asked about (with their ends), then each message written at once.
    for (std::vector<Selected>& list : m_selected) list.clear();
    if (m_asksAny) {
      // Each ray's segment (as arrays for the float test), then the float test for every volume
      // (filterAsks), the double one for the rays it leaves open.
      m_segments.resize(n);
      for (size_t i = 0; i < n; ++i) {
        const Ray& ray = b.rays[i];
        float tfar = ray.tfar;
        if (!b.shadow && b.found[i]) {
          const float reach = float(2 * m_cell / double(length(ray.dir)));
          tfar = std::min(tfar, nextFloatUp(b.hits[i].t + reach) * (1 + 1e-6f));
        }
        const Vec3f o = ray.org64 ? Vec3f(*ray.org64) : ray.org;
        m_segments.ox[i] = o.x;
        m_segments.oy[i] = o.y;
        m_segments.oz[i] = o.z;
        m_segments.dx[i] = ray.dir.x;
        m_segments.dy[i] = ray.dir.y;
        m_segments.dz[i] = ray.dir.z;
        m_segments.t0[i] = ray.tnear;
        m_segments.t1[i] = tfar;
      }
      m_settled.assign(n, 1);
      for (const SplitVolume& v : m_volumes) {
        if (v.holdsAll) continue;
        if (v.world)
          filterAsks(m_segments, n, v.filter, m_settled.data());
        else
          std::fill(m_settled.begin(), m_settled.end(), 0);
      }
    }
    // (Camera rays go in packets, the 4x2 pixels of one sample: the rays asked of a rank from one
    // packet are traced there as a packet too. `packet`: ray i's.)
    const bool packets = !b.packetEnds.empty();
    uint32_t packet = 0;
    for (size_t i = 0; m_asksAny && i < n; ++i) {
      if (m_settled[i] || (b.shadow && b.found[i])) continue;
      const Ray& ray = b.rays[i];
      const float tfar = m_segments.t1[i];
      if (!whomToAsk(ray, tfar, m_ask)) continue;
      const bool whole = !isShort(ray);
      while (packets && i >= b.packetEnds[packet]) ++packet;
      for (int q = 0; q < m_ranks; ++q)
        if (m_ask[size_t(q)]) {
          m_selected[size_t(q)].push_back({uint32_t(i), tfar, whole, packet});
          m_ask[size_t(q)] = 0;
        }
    }
    raysAsked += double(n);
    f.waiting = 0;
    const AskHeader header{int32_t(slot), f.stage, b.shadow ? 1 : 0};
    for (int q = 0; q < m_ranks; ++q) {
      const std::vector<Selected>& list = m_selected[size_t(q)];
      if (list.empty()) continue;
      size_t size = sizeof(AskHeader);
      for (const Selected& sel : list) size += sel.whole ? sizeof(AskedWhole) : sizeof(AskedShort);
      std::vector<char> bytes(size);
      std::memcpy(bytes.data(), &header, sizeof(AskHeader));
      char* at = bytes.data() + sizeof(AskHeader);
      for (size_t k = 0; k < list.size(); ++k) {
        const Selected& sel = list[k];
        const Ray& ray = b.rays[sel.index];
        if (!sel.whole) {
          const bool starts = packets && (k == 0 || sel.packet != list[k - 1].packet);
          const AskedShort a{int32_t(sel.index), starts ? kPacketStart : 0, ray.org, ray.dir, ray.tnear, sel.tfar};
          std::memcpy(at, &a, sizeof a);
          at += sizeof a;
        } else {
          AskedWhole a{int32_t(sel.index), kWhole, ray};
          a.ray.tfar = sel.tfar;
          std::memcpy(at, static_cast<const void*>(&a), sizeof a);
          at += sizeof a;
        }
      }
      raysSent += double(list.size());
      post(bytes, q, kAsk);
      ++f.waiting;
    }
  }

  // Answers every ray another rank has asked about so far (traced against this rank's
  // iso-surfaces), and takes every answer that has come to this rank's flights (`flights[slot]`):
  // a closest hit kept if it is closer (of equal ones the lower rank's), a shadow ray blocked if
  // any rank blocks it. Whether anything came.
  bool serve(std::vector<Flight*>& flights, TraversalStats& stats) {
    return handleWhatCame(kAsk, kAnswer, [&](int tag, const MPI_Status& status) {
      if (tag == kAsk)
        answer(status, stats);
      else
        take(status, flights);
    });
  }

  // Waits for, and answers, the other ranks until every rank has finished its flights of the pass
  // (this one's are: no flight is waiting). `between()` runs between looks (the driver's other
  // messages; whether anything came). Collective.
  template <typename Between>
  void finishPass(std::vector<Flight*>& flights, TraversalStats& stats, Between&& between) {
    MPI_Request done;
    MPI_Ibarrier(MPI_COMM_WORLD, &done);
    for (;;) {
      const auto t0 = Clock::now();
      int flag = 0;
      MPI_Test(&done, &flag, MPI_STATUS_IGNORE);
      if (flag) {
        waitSeconds += since(t0);
        return;
      }
      const bool served = serve(flights, stats);
      if (!between() && !served) waited(t0);
    }
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
  // (Between passes the tiles are dealt again by what they cost: dealTilesByCost.)
  struct Deal {
    std::vector<int> owner;  // the rank of each tile
    std::vector<int> first;  // the rank whose box the tile's centre ray enters first, or -1
  };
  Deal tileOwners(const TileRenderer& tiles, const Camera& camera) const {
    const int n = tiles.tiles();
    std::vector<int> owner(size_t(n), -1), first(size_t(n), -1), count(size_t(m_ranks), 0);
    int seeing = 0;  // tiles whose centre ray passes through a box
    for (int t = 0; t < n; ++t) {
      const TileRenderer::Rect r = tiles.rect(t);
      const Ray ray = camera.generateRay(0.5f * float(r.x0 + r.x1), 0.5f * float(r.y0 + r.y1));
      double firstT = INFINITY, enters = 0;
      for (int q = 0; q < m_ranks; ++q)
        if (reaches(ray, ray.tfar, q, &enters) && enters < firstT) {
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
    if (dealAllToFirstForTest()) std::fill(owner.begin(), owner.end(), 0);
    return {owner, first};
  }

  // Every rank's `values` summed, on every rank (collective; its time counts as waiting).
  void sumOverRanks(std::vector<double>& values) {
    const auto t0 = Clock::now();
    MPI_Allreduce(MPI_IN_PLACE, values.data(), int(values.size()), MPI_DOUBLE, MPI_SUM, MPI_COMM_WORLD);
    waitSeconds += since(t0);
  }

  // Rays of this rank's paths, their copies sent to other ranks, the rays other ranks sent it,
  // bytes this rank sent, seconds it spent waiting for other ranks' messages and for its own to
  // be taken.
  double raysAsked = 0, raysSent = 0, raysReceived = 0, bytesSent = 0, waitSeconds = 0;

 private:
  // A hit an answering rank found, with the index of its ray in the asker's flight: an
  // iso-surface's (the rays it traces meet nothing else), whose other fields are a default Hit's,
  // its float position its double one rounded and its incoming direction the ray's (88 bytes,
  // not a whole Hit's 168).
  struct FoundIso {
    int32_t index;
    float t, tError, spawnOffset;
    Vec3d position64;
    Vec3f pError, normal, shading;
    int32_t material, surface;
    uint8_t insideAfter, cap;

    static FoundIso of(const Hit& h, int index) {
      FoundIso a{};
      a.index = index;
      a.t = h.t;
      a.tError = h.tError;
      a.spawnOffset = h.spawnOffset;
      a.position64 = h.position64;
      a.pError = h.pError;
      a.normal = h.normal;
      a.shading = h.shading;
      a.material = h.material;
      a.surface = h.surface;
      a.insideAfter = h.insideAfter;
      a.cap = h.cap;
      return a;
    }
    // The Hit World::fillHit made of it on the answering rank (`incoming`: the ray's direction).
    void into(Hit& h, const Vec3f& incoming) const {
      h = Hit();
      h.t = t;
      h.tError = tError;
      h.spawnOffset = spawnOffset;
      h.position64 = position64;
      h.position = Vec3f(position64);
      h.pError = pError;
      h.normal = normal;
      h.shading = shading;
      h.material = material;
      h.surface = surface;
      h.insideAfter = insideAfter != 0;
      h.cap = cap != 0;
      h.incoming = incoming;
    }
  };
  // A ray sent to another rank, with its index in this rank's flight: most rays (from the camera
  // or a triangle: isShort) as their origin, direction and extent alone, 40 bytes, the rest of
  // them a default Ray's; the others (leaving an iso-surface, with their origin in double and
  // their start class) whole, 112 bytes. A camera packet's rays asked of a rank go one after
  // another, the first flagged kPacketStart: the rank traces them as a packet, as the asker does
  // (World::intersectPacket: the same hits as one at a time, in fewer instructions).
  struct AskedShort {
    int32_t index;
    int32_t flags;  // kWhole: an AskedWhole, not this; kPacketStart: the first ray asked of a camera packet
    Vec3f org, dir;
    float tnear, tfar;
  };
  static constexpr int32_t kWhole = 1, kPacketStart = 2;
  struct AskedWhole {
    int32_t index;
    int32_t flags;
    Ray ray;
  };
  static bool isShort(const Ray& r) {
    static const Ray plain;  // (built once: this runs for every ray asked of another rank)
    return !r.org64 && r.fromSurface == plain.fromSurface && r.fromInside == plain.fromInside &&
           r.fromCap == plain.fromCap && std::memcmp(&r.fromOffset, &plain.fromOffset, sizeof(Vec3d)) == 0;
  }
  // What an ask (then AskedShort and AskedWhole rays) and an answer (then FoundIso hits, or a
  // shadow stage's indices of the rays found blocked) begin with: the asking rank's flight and its stage.
  struct AskHeader {
    int32_t slot;
    uint32_t stage;
    int32_t shadow;
  };

  template <typename T>
  static void append(std::vector<char>& bytes, const T& value) {
    const size_t at = bytes.size();
    bytes.resize(at + sizeof(T));
    std::memcpy(bytes.data() + at, static_cast<const void*>(&value), sizeof(T));
  }
  template <typename T>
  static T read(const std::vector<char>& bytes, size_t at) {
    T value;
    std::memcpy(static_cast<void*>(&value), bytes.data() + at, sizeof(T));
    return value;
  }

  void post(std::vector<char>& bytes, int to, int tag) {
    m_outbox.progress();  // the buffers of the messages taken go (a busy rank may never wait)
    bytesSent += double(bytes.size());
    m_outbox.send(std::move(bytes), to, tag);
    bytes.clear();
  }

  // The rays of the ask `status` announced, traced against this rank's iso-surfaces, and what
  // they found sent back to the asking rank.
  void answer(const MPI_Status& status, TraversalStats& stats) {
    receive(status, m_inbox);
    const std::vector<char>& bytes = m_inbox;
    if (bytes.size() < sizeof(AskHeader)) MPI_Abort(MPI_COMM_WORLD, 1);  // (a rank of this job sent it: cannot happen)
    const AskHeader header = read<AskHeader>(bytes, 0);
    // The rays, as this rank traces them (the batch reused from ask to ask), camera rays in the
    // packets they were asked from (each begun by a kPacketStart ray), as the asker traces them.
    RayBatch& batch = m_answering;
    batch.shadow = header.shadow != 0;
    batch.rays.clear();
    batch.packetEnds.clear();
    m_indices.clear();
    bool packed = false;  // the message's rays come in packets (its first is flagged)
    size_t packetStart = 0;
    for (size_t at = sizeof(AskHeader); at < bytes.size();) {
      if (bytes.size() - at < sizeof(AskedShort)) MPI_Abort(MPI_COMM_WORLD, 1);
      const AskedShort a = read<AskedShort>(bytes, at);
      const size_t k = batch.rays.size();
      if (a.flags & kPacketStart) {
        if (k == 0) packed = true;
        else if (packed) batch.packetEnds.push_back(uint32_t(k));  // (the packet before ends here)
        packetStart = k;
      }
      // (A rank of this job sent it, so none of these can happen.)
      if ((a.flags & ~(kWhole | kPacketStart)) || ((a.flags & kPacketStart) && !packed) ||
          (packed && ((a.flags & kWhole) || batch.shadow || k - packetStart >= size_t(World::kPacket))))
        MPI_Abort(MPI_COMM_WORLD, 1);
      m_indices.push_back(a.index);
      if (a.flags & kWhole) {
        if (bytes.size() - at < sizeof(AskedWhole)) MPI_Abort(MPI_COMM_WORLD, 1);
        batch.rays.push_back(read<AskedWhole>(bytes, at).ray);
        at += sizeof(AskedWhole);
      } else {
        Ray& r = batch.rays.emplace_back();
        r.org = a.org;
        r.dir = a.dir;
        r.tnear = a.tnear;
        r.tfar = a.tfar;
        at += sizeof(AskedShort);
      }
      batch.rays.back().mask = World::kVolumeMask;
    }
    if (packed) batch.packetEnds.push_back(uint32_t(batch.rays.size()));
    const size_t n = batch.size();
    raysReceived += double(n);
    batch.prepareResults();
    parallel(batch.units(), stats, [&](size_t u, TraversalStats& s) { traceBatch(m_world, batch, u, u + 1, s); });
    // The hits found with the index of the ray in the asker's flight (a shadow ray: the index
    // alone, of the rays found blocked).
    std::vector<char> back;
    back.reserve(sizeof(AskHeader) + n * (header.shadow ? sizeof(int) : sizeof(FoundIso)));  // (no copies as it grows)
    append(back, header);
    for (size_t k = 0; k < n; ++k) {
      if (!batch.found[k]) continue;
      if (header.shadow) {
        append(back, m_indices[k]);
      } else {
        const Hit& h = batch.hits[k];
        if (h.surface < 0 || h.mesh >= 0) MPI_Abort(MPI_COMM_WORLD, 1);  // (the mask lets only iso-surfaces through)
        append(back, FoundIso::of(h, m_indices[k]));
      }
    }
    post(back, status.MPI_SOURCE, kAnswer);
  }

  // The answer `status` announced, into the flight it answers.
  void take(const MPI_Status& status, std::vector<Flight*>& flights) {
    receive(status, m_inbox);
    const std::vector<char>& bytes = m_inbox;
    const int q = status.MPI_SOURCE;
    if (bytes.size() < sizeof(AskHeader)) MPI_Abort(MPI_COMM_WORLD, 1);
    const AskHeader header = read<AskHeader>(bytes, 0);
    if (header.slot < 0 || size_t(header.slot) >= flights.size()) MPI_Abort(MPI_COMM_WORLD, 1);
    Flight& f = *flights[size_t(header.slot)];
    RayBatch& b = f.batch;
    const size_t size = b.shadow ? sizeof(int) : sizeof(FoundIso);
    if (header.stage != f.stage || (header.shadow != 0) != b.shadow || f.waiting <= 0 ||
        (bytes.size() - sizeof(AskHeader)) % size != 0)
      MPI_Abort(MPI_COMM_WORLD, 1);
    for (size_t at = sizeof(AskHeader); at < bytes.size(); at += size) {
      if (b.shadow) {
        const int index = read<int>(bytes, at);
        if (index < 0 || size_t(index) >= b.size()) MPI_Abort(MPI_COMM_WORLD, 1);
        b.found[size_t(index)] = 1;
        continue;
      }
      const FoundIso a = read<FoundIso>(bytes, at);
      const size_t i = size_t(a.index);
      if (a.index < 0 || i >= b.size()) MPI_Abort(MPI_COMM_WORLD, 1);
      if (b.found[i] && !(a.t < b.hits[i].t || (a.t == b.hits[i].t && q < f.from[i]))) continue;
      a.into(b.hits[i], b.rays[i].dir);
      b.found[i] = 1;
      f.from[i] = q;
    }
    --f.waiting;
  }

  // Whether the segment of `r` up to `tfar` passes through rank q's own box of some volume
  // (padded for rounding), and where it enters the first (`enters`, a parameter of `r`).
  bool reaches(const Ray& r, float tfar, int q, double* enters = nullptr) const {
    bool any = false;
    double first = INFINITY;
    for (const SplitVolume& v : m_volumes) {
      const Segment s = v.segment(r, tfar);
      double t0 = s.t0, t1 = s.t1;
      if (v.own[size_t(q)].clip(s, s.pad, t0, t1)) {
        any = true;
        first = std::min(first, t0);
      }
    }
    if (enters) *enters = first;
    return any;
  }

  // The ranks that must be asked about the segment of `r` up to `tfar` (`ask`, by rank; whether
  // any): those whose own box of some volume the segment passes through where this rank does not
  // hold the bricks (its copies of their bricks, "replicate"). Most segments lie wholly in this
  // rank's part of every volume (a ray from a hit here to the next hit here): one test each.
  // (`ask` is all 0 when called: the caller clears what it read.)
  bool whomToAsk(const Ray& r, float tfar, std::vector<char>& ask) const {
    bool any = false;
    for (const SplitVolume& v : m_volumes) {
      if (v.holdsAll) continue;
      const Segment s = v.segment(r, tfar);
      if (std::isfinite(s.t1) && v.heldHere.holds(s, s.t0, s.t1, s.pad)) continue;
      for (int q = 0; q < m_ranks; ++q) {
        if (q == m_rank || ask[size_t(q)]) continue;
        double t0 = s.t0, t1 = s.t1;
        if (!v.own[size_t(q)].clip(s, s.pad, t0, t1)) continue;
        if (v.heldHere.holds(s, t0, t1, s.pad)) continue;  // its part there lies in the bricks held here
        ask[size_t(q)] = 1;
        any = true;
      }
    }
    return any;
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
  // A ray's segment [t0, t1] in a volume's query space (below), and how far rounding may move its
  // points there.
  struct Segment {
    Vec3d o, d;
    double t0, t1, pad;
    Vec3d at(double t) const { return o + d * t; }
  };
  // A box of a volume's query space, [lo, hi] on each axis.
  struct Box {
    Vec3d lo, hi;
    // Narrows [t0, t1] to the part of segment `s` inside the box grown by `pad`; whether any is left.
    // (This and holds() run for every ray a rank traces: axis by axis, written out, each stopping
    // at the first axis that decides. Once t0 > t1 no later axis can undo it.)
    bool clip(const Segment& s, double pad, double& t0, double& t1) const {
      return slab(s.o.x, s.d.x, lo.x - pad, hi.x + pad, t0, t1) && slab(s.o.y, s.d.y, lo.y - pad, hi.y + pad, t0, t1) &&
             slab(s.o.z, s.d.z, lo.z - pad, hi.z + pad, t0, t1) && t0 <= t1;  // (the last: a zero direction)
    }
    static bool slab(double o, double d, double lo, double hi, double& t0, double& t1) {
      if (d == 0) return !(o < lo || o > hi);
      const double inv = 1 / d;
      double ta = (lo - o) * inv, tb = (hi - o) * inv;
      if (ta > tb) std::swap(ta, tb);
      t0 = std::max(t0, ta);
      t1 = std::min(t1, tb);
      return t0 <= t1;
    }
    // Whether the part [t0, t1] (finite) of segment s lies in the box shrunk by `pad` (a box is
    // convex: both ends do).
    bool holds(const Segment& s, double t0, double t1, double pad) const {
      const Vec3d l{lo.x + pad, lo.y + pad, lo.z + pad}, h{hi.x - pad, hi.y - pad, hi.z - pad};
      auto in = [&](const Vec3d& p) { return p.x >= l.x && p.y >= l.y && p.z >= l.z && p.x <= h.x && p.y <= h.y && p.z <= h.z; };
      return in(s.at(t0)) && in(s.at(t1));
    }
  };
  // A volume split over the ranks, its boxes in its *query space*: world space when the volume's
  // grid axes are the world's (scaled, mirrored, moved: most volumes), so a ray needs no
  // transform; its grid's index space otherwise (a ray's parameter is the same in both).
  struct SplitVolume {
    bool world = false;  // query space is world space (else: index space, through toIndex)
    Transform toIndex;
    double stretch = 1;  // query units per world unit (the largest row sum of the transform)
    double cell = 1;     // a cell's smallest side in query units
    double scale = 0;    // the largest world coordinate of the grid's box
    std::vector<Box> own;  // by rank: the cells it answers for
    // This rank's held box (its own and its copies of its neighbours' bricks), unbounded on the
    // sides where it holds the volume to its end (nothing lies beyond), and whether that is
    // everywhere: then it asks nobody about this volume.
    Box heldHere;
    bool holdsAll = false;
    AskFilterVolume filter;  // (world query space only) the float test's boxes and pad

    // `cells`: by rank, the own box's cells [lo, hi) and the held box's.
    SplitVolume(const VolumeInfo& vol, const std::vector<Vec3i>& cells, int rank) {
      const Grid& g = *vol.grid;
      toIndex = worldToIndex(g.origin(), g.spacing(), vol.toObject);
      world = true;
      for (int i = 0; i < 3; ++i)
        for (int j = 0; j < 3; ++j) world = world && (i == j || toIndex.m[i][j] == 0);
      const Transform toWorld = toIndex.inverse();
      for (const Vec3d& c : gridBoxCorners(vol)) scale = std::max({scale, std::fabs(c.x), std::fabs(c.y), std::fabs(c.z)});
      if (world) {
        cell = INFINITY;
        for (int a = 0; a < 3; ++a) cell = std::min(cell, 1 / std::fabs(toIndex.m[a][a]));
      } else {
        const Vec3d rows = toIndex.absRowSums();
        stretch = std::max({rows.x, rows.y, rows.z});
      }
      // A box of cells [lo, hi) in query space; `open`: sides at the grid's ends unbounded.
      const Vec3i last = g.dims() - Vec3i{1, 1, 1};
      auto box = [&](Vec3i lo, Vec3i hi, bool open) {
        Vec3d l(lo), h(hi);
        for (int a = 0; a < 3; ++a) {
          if (open && lo[a] <= 0) l[a] = -1e300;
          if (open && hi[a] >= last[a]) h[a] = 1e300;
        }
        if (!world) return Box{l, h};
        const Vec3d p = toWorld.point(l), q = toWorld.point(h);
        return Box{min(p, q), max(p, q)};
      };
      for (size_t q = 0; q < cells.size() / 4; ++q) own.push_back(box(cells[4 * q], cells[4 * q + 1], false));
      const Vec3i heldLo = cells[size_t(4 * rank + 2)], heldHi = cells[size_t(4 * rank + 3)];
      heldHere = box(heldLo, heldHi, true);
      holdsAll = heldLo == Vec3i{0, 0, 0} && heldHi == last;
      // The float test's boxes: rounded to contain the other ranks' boxes, to lie in the held one
      // (its open sides +-FLT_MAX); its pad (twice over in filterAsks) as segment() makes it.
      auto rounded = [](const Box& b, bool outwards) {
        AskFilterBox f;
        for (int a = 0; a < 3; ++a) {
          float lo = float(std::clamp(b.lo[a], -double(FLT_MAX), double(FLT_MAX)));
          float hi = float(std::clamp(b.hi[a], -double(FLT_MAX), double(FLT_MAX)));
          if (outwards ? double(lo) > b.lo[a] : double(lo) < b.lo[a]) lo = outwards ? nextFloatDown(lo) : nextFloatUp(lo);
          if (outwards ? double(hi) < b.hi[a] : double(hi) > b.hi[a]) hi = outwards ? nextFloatUp(hi) : nextFloatDown(hi);
          f.lo[a] = lo;
          f.hi[a] = hi;
        }
        return f;
      };
      filter.held = rounded(heldHere, false);
      for (size_t q = 0; q < own.size(); ++q)
        if (int(q) != rank) filter.others.push_back(rounded(own[q], true));
      filter.padPerReach = float(1e-5 * stretch);
      filter.padFixed = float(1e-5 * scale * stretch + 1e-4 * cell);
    }

    Segment segment(const Ray& r, float tfar) const {
      const Vec3d org = r.origin();
      const double reach = std::max({std::fabs(org.x), std::fabs(org.y), std::fabs(org.z)});
      Segment s;
      s.o = world ? org : toIndex.point(org);
      s.d = world ? Vec3d(r.dir) : toIndex.vector(Vec3d(r.dir));
      s.t0 = r.tnear;
      s.t1 = tfar;
      // A float ray's points are rounded by ~2^-24 of the world coordinates on their way (origin,
      // direction times t, the walk's own grid ray): 1e-5 of them is ~170 times that.
      s.pad = 1e-5 * (2 * reach + scale) * stretch + 1e-4 * cell;
      return s;
    }
  };
  std::vector<SplitVolume> m_volumes;
  bool m_asksAny = false;  // whether this rank may ask another anything (it does not hold every volume whole)
  // A ray of a stage asked of a rank: its index in the flight, the end the rank is asked to look
  // to, and whether it goes whole (AskedWhole) or as an AskedShort.
  struct Selected {
    uint32_t index;
    float tfar;
    bool whole;
    uint32_t packet;  // (a camera stage's) the ray's packet
  };
  std::vector<std::vector<Selected>> m_selected;  // by rank: the rays of the stage being asked
  std::vector<char> m_ask;                         // by rank: whether a ray is asked of it (whomToAsk)
  AskFilterRays m_segments;              // a stage's rays' segments, for filterAsks
  std::vector<unsigned char> m_settled;  // by ray: filterAsks found it asked of nobody
  std::vector<char> m_inbox;               // the message being read (an ask or an answer)
  // An ask's rays as this rank traces them (with what they found), their indices in the asker's flight.
  RayBatch m_answering;
  std::vector<int> m_indices;
  Outbox m_outbox;
};

// A round of paths: a pass's samples of a run of this rank's pixels (a Wave), in one slot of the
// pipeline. Its next step: start (the slot's next round, if any, and its camera rays), wait (for
// the answers to its flight's rays), or idle (the slot has no more rounds in the pass).
struct Round {
  enum Step { kStart, kWait, kIdle } step = kIdle;
  size_t p0 = 0, p1 = 0;  // its pixels, of this rank's
  double seconds = 0;     // spent on its steps so far (this rank's own work: not the answers)
  Wave wave;
  Flight flight;
};

// This rank's tiles (in tile order), their pixels in packet order tile by tile, the tile of each
// pixel and where its sums are: each tile's sums are a block of their own, in packet order, so a
// tile dealt to another rank takes its block along and nothing else moves (rebuilding one array
// of every pixel's sums cost ~0.1 s a pass: fresh pages are dear on a VM).
struct RankTiles {
  std::vector<int> tiles;
  std::vector<Wave::Pixel> pixels;
  std::vector<int> tileOf;
  std::vector<PixelSums*> sums;
  std::vector<std::unique_ptr<PixelSums[]>> blocks;  // by tile index: its sums, if this rank's

  // The tiles `owner` gives `rank`, with their sums zeroed.
  RankTiles(const TileRenderer& renderer, const std::vector<int>& owner, int rank) : blocks(size_t(renderer.tiles())) {
    for (int tile = 0; tile < renderer.tiles(); ++tile)
      if (owner[size_t(tile)] == rank) blocks[size_t(tile)] = std::make_unique<PixelSums[]>(size_t(renderer.rect(tile).pixels()));
    list(renderer);
  }

  // A tile's sums appended to `out` (as bytes), and its block let go: the tile is another rank's.
  void handOver(const TileRenderer& renderer, int tile, std::vector<char>& out) {
    const char* p = reinterpret_cast<const char*>(blocks[size_t(tile)].get());
    out.insert(out.end(), p, p + size_t(renderer.rect(tile).pixels()) * sizeof(PixelSums));
    blocks[size_t(tile)].reset();
  }
  // A tile handed over: its block made from the sums at `at` in `bytes` (`at` moved past them).
  // Whether they were all there and the tile was not already here.
  bool takeOver(const TileRenderer& renderer, int tile, const std::vector<char>& bytes, size_t& at) {
    if (tile < 0 || tile >= renderer.tiles() || blocks[size_t(tile)]) return false;
    const size_t n = size_t(renderer.rect(tile).pixels());
    if (bytes.size() < at || bytes.size() - at < n * sizeof(PixelSums)) return false;
    blocks[size_t(tile)] = std::make_unique<PixelSums[]>(n);
    std::memcpy(static_cast<void*>(blocks[size_t(tile)].get()), bytes.data() + at, n * sizeof(PixelSums));
    at += n * sizeof(PixelSums);
    return true;
  }

  // Dealt again (`before` the owners so far, `after` the new ones): every tile this rank gives
  // away goes to its new rank with its sums (one message a tile, in tile order), every tile it
  // gets comes with its sums from the rank that had it (collective among the ranks concerned).
  // The lists are the old ones until list() is called.
  void redeal(const TileRenderer& renderer, const std::vector<int>& before, const std::vector<int>& after, int rank) {
    Outbox outbox;
    for (int tile = 0; tile < renderer.tiles(); ++tile) {  // (in tile order, as the receivers take them)
      if (before[size_t(tile)] != rank || after[size_t(tile)] == rank) continue;
      std::vector<char> bytes(sizeof(int));
      std::memcpy(bytes.data(), &tile, sizeof(int));
      handOver(renderer, tile, bytes);
      outbox.send(std::move(bytes), after[size_t(tile)], kMoved);
    }
    for (int tile = 0; tile < renderer.tiles(); ++tile) {
      if (after[size_t(tile)] != rank || before[size_t(tile)] == rank) continue;
      MPI_Status status;
      MPI_Probe(before[size_t(tile)], kMoved, MPI_COMM_WORLD, &status);
      const std::vector<char> bytes = receive(status);
      int sent = -1;
      if (bytes.size() >= sizeof(int)) std::memcpy(&sent, bytes.data(), sizeof(int));
      size_t at = sizeof(int);
      if (sent != tile || !takeOver(renderer, tile, bytes, at) || at != bytes.size())
        MPI_Abort(MPI_COMM_WORLD, 1);  // (a rank of this job sent it: cannot happen)
    }
    outbox.drain();
  }

  // The pixel lists cut to their first n (the tiles list stays).
  void truncate(size_t n) {
    pixels.resize(n);
    tileOf.resize(n);
    sums.resize(n);
  }

  // A tile this rank took (its block already here), its pixels added at the end of the lists.
  void append(const TileRenderer& renderer, int tile) {
    tiles.push_back(tile);
    PixelSums* block = blocks[size_t(tile)].get();
    forEachPixelInPacketOrder(renderer.rect(tile), [&](int x, int y) {
      pixels.emplace_back(x, y);
      tileOf.push_back(tile);
      sums.push_back(block++);
    });
  }

  // The lists, from the blocks this rank holds: the tiles in tile order, or, when `cost` is known
  // (by tile index), the tiles whose rays enter this rank's box first (`first`, by tile index)
  // before the others, each kind the costliest first. A pass thus ends on the cheapest tiles,
  // and the tiles given away during it (from the end) are those another rank renders as well.
  void list(const TileRenderer& renderer, const std::vector<double>& cost = {}, const std::vector<int>& first = {},
            int rank = -1) {
    tiles.clear();
    pixels.clear();
    tileOf.clear();
    sums.clear();
    for (int tile = 0; tile < renderer.tiles(); ++tile)
      if (blocks[size_t(tile)]) tiles.push_back(tile);
    if (!cost.empty())
      std::stable_sort(tiles.begin(), tiles.end(), [&](int a, int b) {
        const bool ha = !first.empty() && first[size_t(a)] == rank, hb = !first.empty() && first[size_t(b)] == rank;
        return ha != hb ? ha : cost[size_t(a)] > cost[size_t(b)];
      });
    const std::vector<int> order = std::move(tiles);
    tiles.clear();
    for (int tile : order) append(renderer, tile);
  }
};

// The test hook ISOTRACE_TEST_REDEAL=rotate: every tile goes to the next rank after every pass
// and none moves during one (tests/mpi_test.cpp: the image stays the same bits however often
// the tiles move; what is asked of whom is the same from run to run).
bool rotateTilesForTest() {
  const char* v = std::getenv("ISOTRACE_TEST_REDEAL");
  return v && std::string(v) == "rotate";
}

}  // namespace

std::vector<int> dealTilesByCost(std::vector<int> owner, const std::vector<int>& first, const std::vector<double>& cost,
                                 const std::vector<double>& busy) {
  const size_t ranks = busy.size();
  if (ranks < 2) return owner;
  double mean = 0;
  for (double b : busy) mean += b / double(ranks);
  if (!(mean > 0) || !(*std::max_element(busy.begin(), busy.end()) > 1.03 * mean)) return owner;
  std::vector<double> load = busy;
  // The ranks by load, busiest first (the lower rank of equal ones).
  std::vector<int> order(ranks);
  for (size_t r = 0; r < ranks; ++r) order[r] = int(r);
  std::stable_sort(order.begin(), order.end(), [&](int a, int b) { return load[size_t(a)] > load[size_t(b)]; });
  // Each rank's tiles, the costliest first (the lower index of equal ones).
  std::vector<int> byCost(owner.size());
  for (size_t t = 0; t < owner.size(); ++t) byCost[t] = int(t);
  std::stable_sort(byCost.begin(), byCost.end(), [&](int a, int b) { return cost[size_t(a)] > cost[size_t(b)]; });
  std::vector<std::vector<int>> tilesOf(ranks);
  for (int t : byCost)
    if (owner[size_t(t)] >= 0 && size_t(owner[size_t(t)]) < ranks) tilesOf[size_t(owner[size_t(t)])].push_back(t);
  for (int d : order) {
    for (auto q = order.rbegin(); q != order.rend() && load[size_t(d)] > mean; ++q) {
      if (!(load[size_t(*q)] < mean)) break;
      for (int kind = 0; kind < 2; ++kind)
        for (int t : tilesOf[size_t(d)]) {
          const double gap = std::min(load[size_t(d)] - mean, mean - load[size_t(*q)]);
          const double c = cost[size_t(t)];
          const int f = first[size_t(t)];
          const bool ofKind = kind == 0 ? f == *q : f < 0;
          if (owner[size_t(t)] != d || !ofKind || !(c > 0) || c > gap) continue;
          owner[size_t(t)] = *q;
          load[size_t(d)] -= c;
          load[size_t(*q)] += c;
        }
    }
  }
  return owner;
}

RenderResult renderFrameDataParallel(MpiJob& job, const Camera& camera, const Integrator& integrator,
                                     const RenderOptions& options, Film& film, Film* direct, RankFigures* figures) {
  const int w = film.width(), h = film.height(), ranks = job.size(), rank = job.rank();
  const TileRenderer tiles(camera, integrator, options, w, h);
  const World& world = integrator.world();
  tbb::task_arena arena(options.threads > 0 ? options.threads : tbb::task_arena::automatic);
  // Rank 0's frame, which gathers every rank's tiles, allocated (and zeroed) before the frame's
  // clock starts, as renderFrame allocates its sums: the render seconds of one process and of the
  // ranks count the same work. (Before the ranks meet in RankTracer's all-gather: at 960x540 its
  // 171 MB held the other ranks ~0.4 s at their first answers, counted as their waiting.)
  std::vector<PixelSums> frame(rank == 0 ? size_t(w) * size_t(h) : 0);
  RankTracer tracer(world, arena, rank, ranks);
  tbb::enumerable_thread_specific<RayCounters> counters;
  RayCounters traced;  // the traversal of the rays this rank traced and answered
  // The tiles this rank renders (dealt before the frame the same way on every rank, and again
  // between passes by what they cost), their pixels and sums (in packet order).
  const RankTracer::Deal deal = tracer.tileOwners(tiles, camera);
  std::vector<int> owner = deal.owner;
  RankTiles mine(tiles, owner, rank);
  int movedMine = 0;  // tiles this rank handed to others
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
  // round asks for one. A pass goes through this rank's pixels in rounds of kPathsPerRound paths,
  // kSlots rounds in flight: while the other ranks answer one round's rays this rank traces
  // another's, and it answers their rays between its own steps. All tiles take a pass (1, 1, 2,
  // 4, 8, 16, 16, ... samples, as in one process) before any takes the next, so that a stop
  // request, honoured after each pass (once the first is done), leaves every pixel sampled. (The
  // exchanges, whose cost is mostly per stage, want many rays each: 2,048 paths a round; 8 in
  // flight hide the other ranks' answers better than 4, 16 no better than 8; docs/BENCHMARKS.md,
  // "Data-parallel rendering" and "Scale-out (issue 47, third session)".)
  constexpr int kSlots = 8;
  constexpr int kPathsPerRound = 2048;
  // A rank with no round left to start asks for tiles once this few of its rounds are in flight
  // (asked earlier, it takes work it would have had time for: tiles go back and forth).
  constexpr size_t kAskWhenInFlight = 2;
  std::vector<Round> slots(kSlots);
  std::vector<Flight*> flights;
  for (Round& round : slots) flights.push_back(&round.flight);
  const int n = tiles.tiles();
  // What this rank's own work on each of its tiles cost in the pass (the seconds of its rounds'
  // steps, shared among their pixels), for dealing the tiles again before the next.
  std::vector<double> tileSeconds(size_t(n), 0.0);
  // (ISOTRACE_TEST_REDEAL=rotate moves every tile after every pass and nothing during one, so
  // that where each tile is, and what is asked of whom, is the same from run to run.)
  const bool rotate = rotateTilesForTest();
  // Tiles handed during a pass to a rank that ran out of rounds to start (give, below): this
  // rank's messages of them, sent without blocking.
  Outbox handOut;
  int s0 = 0;
  for (int pass = 0; s0 < options.spp; ++pass) {
    const int s1 = TileRenderer::nextPassStart(s0, pass, options.spp), ns = s1 - s0;
    const size_t maxPixels = std::max<size_t>(1, size_t(kPathsPerRound) / size_t(ns));
    // The pass's rounds (runs of this rank's pixels), started in order by whichever slot is free.
    std::vector<std::pair<size_t, size_t>> rounds;
    size_t nextRound = 0;
    auto addRounds = [&](size_t from, size_t to) {
      for (size_t p = from; p < to; p += maxPixels) rounds.emplace_back(p, std::min(to, p + maxPixels));
    };
    addRounds(0, mine.pixels.size());
    const auto passStart = Clock::now();
    const double waitedBefore = tracer.waitSeconds;
    for (Round& round : slots) round.step = Round::kStart;
    bool moved = false;  // tiles came or went during the pass
    const std::vector<int> dealt = owner;  // the tiles' ranks as the pass began

    // Taking and giving tiles during the pass, so that the ranks end it together whatever their
    // speed: a rank with no round left to start asks the other ranks in turn (kTakeTiles) until one
    // gives it tiles or all have none; a rank asked gives whole tiles from the end of its rounds
    // not yet started, at most half of their pixels, with their sums (kGivenTiles), and renders
    // only the rest. A tile's sums go with it, its samples of the pass are all taken on one rank,
    // so the image keeps its bits. (Which tiles move depends on the machine's speed; the owners
    // are agreed again at the pass's end.)
    int asking = -1;                         // the rank asked, until it answers
    int refusals = 0;                        // ranks that answered "none" since tiles last came
    int victim = (rank + 1) % ranks;         // the next rank to ask
    bool exhausted = ranks < 2 || rotate;    // every other rank has answered "none" (or the rotate hook: no taking)
    int firstAsks = 0;                       // (the test hook: other ranks' first requests answered)
    auto give = [&](const MPI_Status& status) {
      const std::vector<char> bytes = receive(status);
      int asked = -1;
      if (bytes.size() == sizeof(int)) std::memcpy(&asked, bytes.data(), sizeof(int));
      if (asked != pass) MPI_Abort(MPI_COMM_WORLD, 1);  // (a rank of this job sent it: cannot happen)
      ++firstAsks;
      std::vector<int> given;
      size_t cut = 0;
      if (nextRound < rounds.size()) {
        const size_t u0 = rounds[nextRound].first, u1 = rounds.back().second;
        cut = u1;
        while (cut > u0) {
          const int tile = mine.tileOf[cut - 1];
          const size_t pixels = size_t(tiles.rect(tile).pixels());
          if (cut < u0 + pixels || 2 * (u1 - cut + pixels) > u1 - u0) break;  // (not all unstarted, or more than half)
          cut -= pixels;
          given.push_back(tile);
        }
      }
      std::vector<char> out(2 * sizeof(int));
      const int count = int(given.size());
      std::memcpy(out.data(), &pass, sizeof(int));
      std::memcpy(out.data() + sizeof(int), &count, sizeof(int));
      for (int tile : given) {
        const char* t = reinterpret_cast<const char*>(&tile);
        out.insert(out.end(), t, t + sizeof(int));
      }
      for (int tile : given) mine.handOver(tiles, tile, out);  // (its pixels lie past `cut`: no round reads them now)
      if (!given.empty()) {
        while (rounds.size() > nextRound && rounds.back().first >= cut) rounds.pop_back();
        if (rounds.size() > nextRound && rounds.back().second > cut) rounds.back().second = cut;
        movedMine += count;
        moved = true;
      }
      handOut.send(std::move(out), status.MPI_SOURCE, kGivenTiles);
    };
    auto take = [&](const MPI_Status& status) {
      const std::vector<char> bytes = receive(status);
      int header[2] = {-1, -1};
      if (bytes.size() >= sizeof header) std::memcpy(header, bytes.data(), sizeof header);
      if (header[0] != pass || header[1] < 0 || header[1] > n || status.MPI_SOURCE != asking) MPI_Abort(MPI_COMM_WORLD, 1);
      size_t at = sizeof header + size_t(header[1]) * sizeof(int);
      if (bytes.size() < at) MPI_Abort(MPI_COMM_WORLD, 1);
      // (Past the last round lie only the pixels of tiles given away; a Wave reads its pixels
      // only while it starts, so the lists may grow under rounds in flight.)
      mine.truncate(rounds.empty() ? 0 : rounds.back().second);
      const size_t from = mine.pixels.size();
      for (int k = 0; k < header[1]; ++k) {
        int tile = -1;
        std::memcpy(&tile, bytes.data() + sizeof header + size_t(k) * sizeof(int), sizeof(int));
        if (!mine.takeOver(tiles, tile, bytes, at)) MPI_Abort(MPI_COMM_WORLD, 1);
        mine.append(tiles, tile);
      }
      if (at != bytes.size()) MPI_Abort(MPI_COMM_WORLD, 1);
      addRounds(from, mine.pixels.size());
      asking = -1;
      if (header[1] == 0) {
        exhausted = ++refusals >= ranks - 1;
      } else {
        refusals = 0;
        moved = true;
        for (Round& round : slots)
          if (round.step == Round::kIdle) round.step = Round::kStart;
      }
    };
    // Answers requests for tiles and takes the answers to this rank's; whether any came.
    auto serveTiles = [&] {
      const bool any = handleWhatCame(kTakeTiles, kGivenTiles, [&](int tag, const MPI_Status& status) {
        if (tag == kTakeTiles)
          give(status);
        else
          take(status);
      });
      handOut.progress();
      return any;
    };
    // (The test hook: rank 0, holding every tile, answers every other rank's first request
    // before it starts a round.)
    if (pass == 0 && rank == 0 && dealAllToFirstForTest())
      while (firstAsks < ranks - 1) {
        const auto t0 = Clock::now();
        if (!serveTiles()) tracer.waited(t0);
      }

    // The round's next stage asked of the ranks, or, when no path asks for a ray, the round's
    // samples added to its pixels' sums and the slot on to its next round.
    auto advance = [&](Round& round, int slot) {
      if (!round.wave.pending()) {
        round.wave.finish([&](size_t i) -> PixelSums& { return *mine.sums[round.p0 + i]; });
        round.step = Round::kStart;
        return true;
      }
      round.wave.collect(round.flight.batch);
      tracer.ask(round.flight, slot, traced.traversal);
      round.step = Round::kWait;
      return false;
    };
    for (;;) {
      const auto look = Clock::now();
      bool open = false, stepped = tracer.serve(flights, traced.traversal);
      stepped = serveTiles() || stepped;
      auto inFlight = [&] {
        return size_t(std::count_if(slots.begin(), slots.end(), [](const Round& r) { return r.step == Round::kWait; }));
      };
      if (!exhausted && asking < 0 && nextRound >= rounds.size() && inFlight() <= kAskWhenInFlight) {
        std::vector<char> ask(sizeof(int));
        std::memcpy(ask.data(), &pass, sizeof(int));
        handOut.send(std::move(ask), victim, kTakeTiles);
        asking = victim;
        victim = (victim + 1) % ranks == rank ? (victim + 2) % ranks : (victim + 1) % ranks;
      }
      for (int k = 0; k < kSlots; ++k) {
        Round& round = slots[size_t(k)];
        if (round.step == Round::kIdle) continue;
        open = true;
        if (round.step == Round::kWait && round.flight.waiting > 0) continue;
        const auto t0 = Clock::now();
        if (round.step == Round::kStart) {
          if (nextRound >= rounds.size()) {
            round.step = Round::kIdle;
            continue;
          }
          round.p0 = rounds[nextRound].first;
          round.p1 = rounds[nextRound].second;
          ++nextRound;
          round.seconds = 0;
          round.wave.start(camera, integrator, options, mine.pixels.data() + round.p0, round.p1 - round.p0, s0, s1);
        } else {  // every rank asked has answered: the stage's hits to its paths
          deliver(round);
        }
        const size_t p0 = round.p0, p1 = round.p1;
        const bool done = advance(round, k);
        round.seconds += since(t0);
        if (done) {  // what the round's own work cost, to its pixels' tiles
          const double each = round.seconds / double(std::max<size_t>(1, p1 - p0));
          for (size_t i = p0; i < p1; ++i) tileSeconds[size_t(mine.tileOf[i])] += each;
        }
        stepped = true;
        break;  // (then the other ranks' rays that came meanwhile)
      }
      if (!open && exhausted && asking < 0) break;
      if (!stepped) tracer.waited(look);
    }
    tracer.finishPass(flights, traced.traversal, serveTiles);
    s0 = s1;
    // Every rank's costs of the pass, its tiles (rank + 1 for each it holds: tiles moved during
    // the pass) and whether any rank was asked to stop, in one collective.
    std::vector<double> shared(size_t(2 * n + ranks + 1), 0.0);
    for (int tile = 0; tile < n; ++tile)
      if (mine.blocks[size_t(tile)]) {
        shared[size_t(tile)] = tileSeconds[size_t(tile)];
        shared[size_t(n + ranks + 1 + tile)] = rank + 1;
      }
    shared[size_t(n + rank)] = since(passStart) - (tracer.waitSeconds - waitedBefore);
    shared[size_t(n + ranks)] = stopRequested() ? 1 : 0;
    tracer.sumOverRanks(shared);
    for (int tile = 0; tile < n; ++tile) owner[size_t(tile)] = int(shared[size_t(n + ranks + 1 + tile)]) - 1;
    if (moved) mine.list(tiles);  // (this rank's tiles as they are now)
    if (shared[size_t(n + ranks)] > 0) break;  // any rank's request: every rank stops here
    std::fill(tileSeconds.begin(), tileSeconds.end(), 0.0);
    if (s0 >= options.spp) break;
    const std::vector<double> cost(shared.begin(), shared.begin() + n);
    std::vector<int> next(owner.size());
    if (rotate) {
      for (size_t t = 0; t < owner.size(); ++t) next[t] = (owner[t] + 1) % ranks;
    } else {
      // Dealt again from the pass's deal, not from where tiles went during it (a tile taken by a
      // rank its rays do not reach first would stay there, its rays asked of the giver in every
      // pass): by what each rank's dealt tiles cost, i.e. its busy seconds with the cost of the
      // tiles it gave away added back and of those it took taken off.
      std::vector<double> busy(shared.begin() + n, shared.begin() + n + ranks);
      for (int tile = 0; tile < n; ++tile)
        if (owner[size_t(tile)] != dealt[size_t(tile)]) {
          busy[size_t(owner[size_t(tile)])] -= cost[size_t(tile)];
          busy[size_t(dealt[size_t(tile)])] += cost[size_t(tile)];
        }
      next = dealTilesByCost(dealt, deal.first, cost, busy);
    }
    if (next != owner) {
      const auto t0 = Clock::now();
      for (int tile : mine.tiles) movedMine += next[size_t(tile)] != rank;
      mine.redeal(tiles, owner, next, rank);
      owner = std::move(next);
      tracer.waitSeconds += since(t0);  // (the sums in flight: the ranks wait for each other)
    }
    // The costliest tiles first: the pass's last rounds are its cheapest, and the ranks finish it
    // nearer together.
    mine.list(tiles, cost, deal.first, rank);
  }
  // Every rank knows whether the frame stopped short (a sequence then ends on every rank).
  const bool stoppedShort = s0 < options.spp;
  tracer.drain();
  handOut.drain();

  // Rank 0 gathers every rank's tiles.
  RenderResult result;
  RayCounters mineCounters = traced;
  for (const RayCounters& c : counters) mineCounters.add(c);
  sendCounters(mineCounters, result.counters, 0);
  // Rank by rank, point to point, a tile's sums a message, rank 0 placing each tile's pixels
  // straight into the frame's sums.
  auto place = [&](int tile, const PixelSums* block) {
    forEachPixelInPacketOrder(tiles.rect(tile), [&](int x, int y) { frame[size_t(y) * size_t(w) + size_t(x)] = *block++; });
  };
  if (rank == 0)
    for (int tile : mine.tiles) place(tile, mine.blocks[size_t(tile)].get());
  gatherTiles(
      job, tiles, mine.tiles, [&](size_t i) { return mine.blocks[size_t(mine.tiles[i])].get(); }, place);
  result.seconds = since(start);
  constexpr int kFigures = 6;
  double asked[kFigures] = {tracer.raysAsked, tracer.raysSent, tracer.raysReceived, tracer.bytesSent, tracer.waitSeconds,
                            double(movedMine)};
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
    figures->tilesMoved.clear();
    for (int q = 0; q < ranks; ++q) {
      const double* f = &allAsked[size_t(kFigures * q)];
      figures->raysAsked.push_back(f[0]);
      figures->raysSent.push_back(f[1]);
      figures->raysReceived.push_back(f[2]);
      figures->bytesSent.push_back(f[3]);
      figures->waitSeconds.push_back(f[4]);
      figures->tilesMoved.push_back(int(f[5]));
      figures->busySeconds.push_back(std::max(0.0, result.seconds - f[4]));
    }
  }
  resolveFrame(frame, options, film, direct, result);
  return result;
}

}  // namespace iso


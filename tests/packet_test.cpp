// Rays traced in Embree packets (World::intersectPacket / occludedPacket) against the same rays
// traced one at a time: every field of every hit equal bit for bit, on the examples' real
// meshes and volumes, at the origin and with the whole scene moved 1e5 away, for camera rays
// in 4x2 pixel packets and for rays spawned from hits (which start on an iso-surface with a
// given class) in packets of 8 unrelated rays.
#include <gtest/gtest.h>

#include <cstring>
#include <random>

#include "integrators/sampler.h"
#include "scene/world.h"
#include "volume/packet_walk.h"
#include "tests/test_util.h"

namespace iso {
namespace {

template <typename T>
bool sameBits(const T& a, const T& b) {
  return std::memcmp(&a, &b, sizeof(T)) == 0;
}

// The texture frames shading builds from two hits (World::textureFrame), as bits.
bool sameFrame(const Hit& a, const Hit& b) {
  const TextureFrame fa = World::textureFrame(a), fb = World::textureFrame(b);
  return sameBits(fa.uv, fb.uv) && sameBits(fa.dpdu, fb.dpdu) && sameBits(fa.dpdv, fb.dpdv);
}

// The fields a caller reads, compared as bits (a NaN equals itself; -0 differs from 0).
::testing::AssertionResult sameHit(const Hit& a, const Hit& b) {
  const bool same = sameBits(a.t, b.t) && sameBits(a.tError, b.tError) && sameBits(a.position, b.position) &&
                    sameBits(a.position64, b.position64) && sameBits(a.pError, b.pError) &&
                    sameBits(a.normal, b.normal) && sameBits(a.shading, b.shading) && a.triangles == b.triangles &&
                    a.prim == b.prim && a.toWorld == b.toWorld && sameFrame(a, b) && a.material == b.material &&
                    a.surface == b.surface && a.mesh == b.mesh && a.light == b.light && a.triangle == b.triangle &&
                    sameBits(a.b1, b.b1) && sameBits(a.b2, b.b2) && sameBits(a.spawnOffset, b.spawnOffset) &&
                    sameBits(a.incoming, b.incoming) && a.insideAfter == b.insideAfter && a.cap == b.cap;
  if (same) return ::testing::AssertionSuccess();
  return ::testing::AssertionFailure() << "fields t/normal/shading/position64/tError/insideAfter same: "
                                       << sameBits(a.t, b.t) << sameBits(a.normal, b.normal) << sameBits(a.shading, b.shading)
                                       << sameBits(a.position64, b.position64) << sameBits(a.tError, b.tError)
                                       << (a.insideAfter == b.insideAfter) << "; packet t " << a.t << " surface " << a.surface << " mesh " << a.mesh
                                       << " / single t " << b.t << " surface " << b.surface << " mesh " << b.mesh;
}

struct Counts {
  size_t rays = 0, isoHits = 0, meshHits = 0, blocked = 0;
};

// Camera rays of a w x h image in 4x2 packets, then one spawned ray per hit (random
// direction, from the hit's own spawnRay) in packets of 8, traced both ways and compared;
// the spawned rays also as shadow rays.
Counts comparePacketsWithSingleRays(const SceneDesc& scene, int w, int h, uint32_t seed) {
  const World world(scene, IntersectorSpec{});
  const Camera camera(world.camera(), w, h);
  TraversalStats stats;
  std::mt19937 rng(seed);
  std::uniform_real_distribution<float> u01(0, 1);
  Counts counts;
  std::vector<Hit> firstHits;
  for (int y0 = 0; y0 < h; y0 += 2)
    for (int x0 = 0; x0 < w; x0 += 4) {
      Ray rays[World::kPacket];
      int n = 0;
      for (int dy = 0; dy < 2; ++dy)
        for (int dx = 0; dx < 4; ++dx)
          if (x0 + dx < w && y0 + dy < h) rays[n++] = camera.generateRay(x0 + dx + u01(rng), y0 + dy + u01(rng));
      Hit hits[World::kPacket];
      bool found[World::kPacket];
      world.intersectPacket(rays, n, hits, found, stats);
      for (int i = 0; i < n; ++i) {
        Hit single;
        const bool f = world.intersect(rays[i], single, stats);
        EXPECT_EQ(found[i], f) << "camera ray at " << x0 << "," << y0 << " lane " << i;
        if (!f || !found[i]) continue;
        EXPECT_TRUE(sameHit(hits[i], single)) << "camera ray at " << x0 << "," << y0 << " lane " << i;
        ++(single.surface >= 0 ? counts.isoHits : counts.meshHits);
        firstHits.push_back(single);
      }
      counts.rays += size_t(n);
    }
  for (size_t k = 0; k < firstHits.size(); k += World::kPacket) {
    const int n = int(std::min<size_t>(World::kPacket, firstHits.size() - k));
    Ray rays[World::kPacket];
    for (int i = 0; i < n; ++i) {
      const Vec3f w = sampleUniformSphere(u01(rng), u01(rng));
      rays[i] = spawnRay(firstHits[k + size_t(i)], w);
    }
    Hit hits[World::kPacket];
    bool found[World::kPacket], blocked[World::kPacket];
    world.intersectPacket(rays, n, hits, found, stats);
    world.occludedPacket(rays, n, blocked, stats);
    for (int i = 0; i < n; ++i) {
      Hit single;
      const bool f = world.intersect(rays[i], single, stats);
      EXPECT_EQ(found[i], f) << "spawned ray " << k + size_t(i);
      if (f && found[i]) {
        EXPECT_TRUE(sameHit(hits[i], single)) << "spawned ray " << k + size_t(i);
        ++(single.surface >= 0 ? counts.isoHits : counts.meshHits);
      }
      EXPECT_EQ(blocked[i], world.occluded(rays[i], stats)) << "spawned ray " << k + size_t(i);
      counts.blocked += blocked[i];
    }
    counts.rays += size_t(n);
  }
  return counts;
}

// Moves everything the scene places by `offset` (meshes, volumes, camera, point lights).
SceneDesc moved(SceneDesc scene, const Vec3d& offset) {
  for (MeshDesc& m : scene.meshes) m.transform = Transform::translate(offset) * m.transform;
  for (VolumeDesc& v : scene.volumes) {
    v.transform = Transform::translate(offset) * v.transform;
    v.clip = v.clip.transformed(Transform::translate(offset));
  }
  scene.clip = scene.clip.transformed(Transform::translate(offset));
  scene.camera.position = scene.camera.position + offset;
  scene.camera.lookAt = scene.camera.lookAt + offset;
  for (LightDesc& l : scene.lights) l.position = l.position + offset;
  return scene;
}

TEST(Packets, SameHitsAsSingleRaysOnRealMeshesAndVolumes) {
  const std::string root = ISOTRACE_SOURCE_DIR;
  for (const char* file : {"/examples/default.json", "/bench/scenes/neghip.json", "/bench/scenes/lidc2.json",
                           "/examples/ct_chest_cut.json"}) {
    const SceneDesc scene = parseSceneFile(root + file);
    for (const Vec3d offset : {Vec3d{0, 0, 0}, Vec3d{1e5, -1e5, 1e5}}) {
      SCOPED_TRACE(std::string(file) + " offset " + std::to_string(offset.x));
      const Counts c = comparePacketsWithSingleRays(moved(scene, offset), 96, 54, 11);
      // The comparison means something: both kinds of surface are hit, many times.
      EXPECT_GT(c.isoHits, 200u);
      EXPECT_GT(c.meshHits, 200u);
      EXPECT_GT(c.blocked, 100u);
      if (HasFailure()) return;
    }
  }
}

// Segments that make the solve work: corners from a real volume's cells, and synthetic ones with
// exact zeros, tiny and huge values, near-double roots (two crossings a hair apart) and faces
// pinned at 0 or 1, as the walk makes them.
std::vector<CellSegment<float>> hardSegments(size_t count, uint32_t seed) {
  std::mt19937 rng(seed);
  std::uniform_real_distribution<float> u01(0, 1), sym(-1, 1);
  std::vector<CellSegment<float>> out;
  while (out.size() < count) {
    CellSegment<float> seg;
    const int kind = int(rng() % 5);
    for (float& g : seg.g) {
      switch (kind) {
        case 0: g = sym(rng); break;                                            // generic
        case 1: g = float(int(rng() % 5) - 2); break;                          // integer data, exact zeros
        case 2: g = sym(rng) * std::ldexp(1.f, int(rng() % 60) - 30); break;   // wide magnitudes
        case 3: g = 0.25f + 1e-6f * sym(rng); break;                           // almost flat
        default: g = sym(rng) * 1e-3f + (rng() % 2 ? 0.5f : -0.5f); break;     // sharp
      }
    }
    if (kind == 3) seg.g[rng() % 8] = -0.25f;  // a close pair of crossings in a corner
    for (int a = 0; a < 3; ++a) {
      seg.a[a] = rng() % 4 == 0 ? float(rng() % 2) : u01(rng);
      seg.b[a] = rng() % 4 == 0 ? float(rng() % 2) : u01(rng);
    }
    if (kind == 4 && rng() % 2) {
      // Near-tangent: every corner shifted so that the cubic's first interior extremum lies
      // within a few 1e-7 of zero, and a walk's doubt (CellSegment::doubt) of up to 2^10 ulps:
      // lanes the vector solve hands to the double decision.
      const Cubic<float> cubic = cellCubic(seg);
      float e[2];
      if (detail::quadraticRootsInUnit(cubic.c[1], 2 * cubic.c[2], 3 * cubic.c[3], e) > 0) {
        const float shift = cubic(e[0]) + 3e-7f * sym(rng);
        for (float& g : seg.g) g -= shift;
      }
      seg.doubt = std::ldexp(std::numeric_limits<float>::epsilon(), int(rng() % 11));
    }
    seg.f0 = trilinear(seg.g, seg.a);
    seg.f1 = trilinear(seg.g, seg.b);
    const float tiny = std::numeric_limits<float>::denorm_min();
    if (seg.f0 == 0) seg.f0 = rng() % 2 ? tiny : -tiny;
    if (seg.f1 == 0) seg.f1 = rng() % 2 ? tiny : -tiny;
    out.push_back(seg);
  }
  return out;
}

// The 8-lane isolation solve against the scalar IsolationIntersector, lane by lane, bit for bit:
// every mask (from one lane to eight; below three lanes it is the scalar code itself), 1 to 8
// refinement steps, first and any.
TEST(Packets, VectorSolveGivesTheScalarBits) {
  const std::vector<CellSegment<float>> segs = hardSegments(8 * 4000, 5);
  std::mt19937 rng(9);
  size_t roots = 0;
  for (int iterations : {1, 3, 8}) {
    const IsolationIntersector scalar{iterations};
    const IsolationPacket packet{iterations};
    for (size_t k = 0; k + kPacketLanes <= segs.size(); k += kPacketLanes) {
      const uint32_t mask = k < 8 * 100 ? 0xffu : (rng() & 0xffu) | 1u << (rng() % 8);
      const CellSegment<float>* lanes[kPacketLanes];
      for (int l = 0; l < kPacketLanes; ++l) lanes[l] = &segs[k + size_t(l)];
      Root<float> got[kPacketLanes];
      const uint32_t found = packet.first(lanes, mask, got);
      const uint32_t any = packet.any(lanes, mask);
      for (int l = 0; l < kPacketLanes; ++l) {
        if (!(mask >> l & 1)) {
          EXPECT_FALSE(found >> l & 1);
          continue;
        }
        Root<float> want;
        const bool has = scalar.first(*lanes[l], want);
        ASSERT_EQ(bool(found >> l & 1), has) << "segment " << k + size_t(l) << ", " << iterations << " steps";
        ASSERT_EQ(bool(any >> l & 1), scalar.any(*lanes[l])) << "segment " << k + size_t(l);
        if (!has) continue;
        ++roots;
        ASSERT_TRUE(sameBits(got[l].s, want.s)) << got[l].s << " vs " << want.s << ", segment " << k + size_t(l);
        ASSERT_TRUE(sameBits(got[l].sError, want.sError)) << got[l].sError << " vs " << want.sError;
        ASSERT_EQ(got[l].tangent, want.tangent);
      }
    }
  }
  EXPECT_GT(roots, 15000u);  // most segments hold a crossing: the comparison means something
}

// The whole-grid packet walk (IsoSurface::intersectPacket, `isotrace bench --ray-flow wavefront`)
// against the scalar walk (IsoSurface::intersect), lane by lane: same hit bits (t, bound,
// normal, class after), on real volumes of every sample type (uint8, uint16, float, sparse
// OpenVDB), at the origin and at 1e5, for rays from outside and from inside with every start
// class, packets of 1 to 8 rays.
TEST(Packets, PacketWalkGivesTheScalarWalksHitsOnRealVolumes) {
  const std::string data = ISOTRACE_SOURCE_DIR "/examples/data/volumes/";
  struct Case {
    const char* file;
    double iso;
  };
  const Case cases[] = {{"neghip_64x64x64_uint8.raw", 40.5}, {"hydrogen_atom_128x128x128_uint8.raw", 20},
                        {"HeadMRVolume.mhd", 80}, {"nucleon/nucleon.nrrd", 60}, {"smoke.vdb", 0.3}};
  std::mt19937 rng(21);
  std::uniform_real_distribution<double> u01(0, 1);
  for (const Case& c : cases)
    for (const double offset : {0.0, 1e5}) {
      SCOPED_TRACE(std::string(c.file) + " offset " + std::to_string(offset));
      VolumeDesc desc;
      desc.file = data + c.file;
      Grid grid = loadVolume(desc).grid;
      grid.setOrigin(grid.origin() + Vec3d{offset, -offset, offset});
      const BrickGrid bricks(grid);
      const IsoSurface surface(grid, bricks, c.iso, IntersectorSpec{});
      const Vec3d lo = grid.origin();
      const Vec3d size = Vec3d(grid.dims() - Vec3i{1, 1, 1}) * grid.spacing();
      size_t hits = 0, lanesCompared = 0;
      for (int packet = 0; packet < 3000; ++packet) {
        const int n = 1 + int(rng() % kPacketLanes);
        IsoSurface::PacketLane lanes[kPacketLanes];
        GridRayCache caches[kPacketLanes];
        // Camera-like packets share an origin outside; the others start inside the box.
        const bool camera = packet % 2 == 0;
        const Vec3d eye = lo + size * 0.5 + Vec3d{1.3, 0.7, -1.1} * length(size);
        for (int l = 0; l < n; ++l) {
          const Vec3d target = lo + Vec3d{u01(rng), u01(rng), u01(rng)} * size;
          IsoSurface::PacketLane& r = lanes[l];
          r.org = camera ? eye : lo + Vec3d{u01(rng), u01(rng), u01(rng)} * size;
          r.dir = normalize(target - r.org + Vec3d{u01(rng) - 0.5, u01(rng) - 0.5, u01(rng) - 0.5} * 1e-3);
          r.tnear = camera ? 0 : 1e-3 * u01(rng);
          r.tfar = u01(rng) < 0.2 ? length(size) * u01(rng) : 1e30;
          r.start = camera ? StartClass::Unknown : StartClass(int(rng() % 3) - 1);
          r.cache = &caches[l];
        }
        SurfaceHit got[kPacketLanes];
        TraversalStats stats;
        const uint32_t found = surface.intersectPacket(lanes, (1u << n) - 1, got, stats);
        for (int l = 0; l < n; ++l) {
          SurfaceHit want;
          const IsoSurface::PacketLane& r = lanes[l];
          const bool has = surface.intersect(r.org, r.dir, r.tnear, r.tfar, want, stats, r.start);
          ASSERT_EQ(bool(found >> l & 1), has) << "packet " << packet << " lane " << l;
          ++lanesCompared;
          if (!has) continue;
          ++hits;
          ASSERT_TRUE(sameBits(got[l].t, want.t)) << got[l].t << " vs " << want.t << ", packet " << packet;
          ASSERT_TRUE(sameBits(got[l].tError, want.tError)) << "packet " << packet;
          ASSERT_TRUE(sameBits(got[l].normal, want.normal)) << "packet " << packet;
          ASSERT_EQ(got[l].insideAfter, want.insideAfter) << "packet " << packet;
          ASSERT_EQ(got[l].tangent, want.tangent);
        }
      }
      EXPECT_GT(hits, lanesCompared / 5);  // a real share of the lanes hit: the test sees solves
    }
}

// World fills a Hit without clearing it first (World::fillHit writes every field, each kind of
// hit its own and the other kind's defaults): a record that held anything before, here every
// field set to nonsense, must come out of a query as a fresh one does, for iso-surface and
// triangle hits, single rays and packets, and a scene of meshes only (traced without lanes).
TEST(Packets, HitRecordsDoNotDependOnWhatTheyHeldBefore) {
  auto poisoned = [] {
    Hit h;
    h.t = -1;
    h.tError = 7;
    h.position = {3, 3, 3};
    h.position64 = {4, 4, 4};
    h.pError = {5, 5, 5};
    h.normal = h.shading = h.incoming = {9, 9, 9};
    static const TriangleMesh nonsense;
    static const Transform skewed;
    h.triangles = &nonsense;
    h.prim = 77;
    h.toWorld = &skewed;
    h.material = h.surface = h.mesh = h.light = h.triangle = h.slice = 99;
    h.b1 = h.b2 = 3;
    h.spawnOffset = 4;
    h.insideAfter = h.cap = true;
    return h;
  };
  const std::string root = ISOTRACE_SOURCE_DIR;
  SceneDesc meshesOnly = parseSceneFile(root + "/bench/scenes/neghip.json");
  meshesOnly.volumes.clear();
  for (const SceneDesc& scene : {parseSceneFile(root + "/examples/default.json"), meshesOnly}) {
    const World world(scene, IntersectorSpec{});
    const Camera camera(world.camera(), 96, 54);
    TraversalStats stats;
    size_t isoHits = 0, meshHits = 0;
    for (int y = 0; y < 54; y += 2)
      for (int x = 0; x < 96; x += 4) {
        Ray rays[World::kPacket];
        for (int i = 0; i < World::kPacket; ++i) rays[i] = camera.generateRay(x + (i & 3) + 0.5f, y + (i >> 2) + 0.5f);
        Hit fresh[World::kPacket], reused[World::kPacket];
        bool found[World::kPacket], foundAgain[World::kPacket];
        for (int i = 0; i < World::kPacket; ++i) {
          found[i] = world.intersect(rays[i], fresh[i], stats);
          reused[i] = poisoned();
          ASSERT_EQ(world.intersect(rays[i], reused[i], stats), found[i]);
          if (!found[i]) continue;
          EXPECT_TRUE(sameHit(reused[i], fresh[i]));
          EXPECT_EQ(reused[i].slice, fresh[i].slice);
          ++(fresh[i].surface >= 0 ? isoHits : meshHits);
          // A spawned ray's hit goes into the record of the hit it left (the integrators' way).
          Hit chained = fresh[i], chainedFresh;
          const Ray next = spawnRay(fresh[i], fresh[i].incoming);
          if (world.intersect(next, chainedFresh, stats)) {
            ASSERT_TRUE(world.intersect(next, chained, stats));
            EXPECT_TRUE(sameHit(chained, chainedFresh));
          }
        }
        for (Hit& h : reused) h = poisoned();
        world.intersectPacket(rays, World::kPacket, reused, foundAgain, stats);
        for (int i = 0; i < World::kPacket; ++i) {
          ASSERT_EQ(foundAgain[i], found[i]);
          if (found[i]) {
            EXPECT_TRUE(sameHit(reused[i], fresh[i]));
          }
        }
        if (HasFailure()) return;
      }
    // Both kinds of record were written over (the meshes-only scene: triangles alone).
    EXPECT_GT(meshHits, 100u);
    if (!scene.volumes.empty()) {
      EXPECT_GT(isoHits, 100u);
    }
  }
}

// A packet holds 1 to 8 rays; anything else is a programming error, refused.
TEST(Packets, RefusesMoreThanEightRays) {
  SceneDesc scene;
  MeshDesc quad;
  quad.shape = MeshShape::Quad;
  scene.meshes.push_back(quad);
  const World world(scene, IntersectorSpec{});
  Ray rays[9];
  Hit hits[9];
  bool found[9];
  TraversalStats stats;
  EXPECT_THROW(world.intersectPacket(rays, 9, hits, found, stats), std::logic_error);
  EXPECT_THROW(world.occludedPacket(rays, 0, found, stats), std::logic_error);
}

// laneCount (a table, not libgcc's popcount call) decides when the vector solve pays and counts
// the solve's lanes for --stats: every 8-lane mask, against the bits counted one by one.
TEST(Packets, LaneCountCountsEveryMask) {
  for (uint32_t mask = 0; mask < 256; ++mask) {
    int bits = 0;
    for (int l = 0; l < kPacketLanes; ++l) bits += (mask >> l) & 1;
    EXPECT_EQ(laneCount(mask), bits) << "mask " << mask;
  }
}

}  // namespace
}  // namespace iso


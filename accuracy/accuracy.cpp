#include "accuracy/accuracy.h"

#include "volume/packet_walk.h"

#include <algorithm>
#include <chrono>
#include <cmath>
#include <cstdio>
#include <cstdlib>
#include <random>

namespace iso {
namespace {

struct TestRay {
  Vec3d org, dir;
};

std::vector<TestRay> makeRays(const Grid& grid, RayKind kind, int n, uint64_t seed) {
  std::mt19937_64 rng(seed);
  std::uniform_real_distribution<double> unit(0, 1);
  const Vec3d lo = grid.origin();
  const Vec3d size = Vec3d(Vec3i{grid.dims().x - 1, grid.dims().y - 1, grid.dims().z - 1}) * grid.spacing();
  const Vec3d center = lo + size * 0.5;
  const double radius = length(size);
  auto randomDir = [&] {
    const double z = 2 * unit(rng) - 1, phi = 2 * M_PI * unit(rng), r = std::sqrt(1 - z * z);
    return Vec3d{r * std::cos(phi), r * std::sin(phi), z};
  };
  auto randomInside = [&] { return lo + Vec3d{unit(rng), unit(rng), unit(rng)} * size; };
  std::vector<TestRay> rays(static_cast<size_t>(n));
  for (auto& r : rays) {
    if (kind == RayKind::Camera) {
      r.org = center + randomDir() * radius;
      r.dir = normalize(randomInside() - r.org);
    } else {
      r.org = randomInside();
      r.dir = randomDir();
    }
  }
  return rays;
}

}  // namespace

AccuracyReport measureAccuracy(const Grid& grid, double iso, const IntersectorSpec& tested,
                               RayKind kind, int n, uint64_t seed, bool packets) {
  const BrickGrid bricks(grid);
  const IsoSurface reference(grid, bricks, iso, {IntersectorKind::Reference, 0});
  const IsoSurface surface(grid, bricks, iso, tested);
  const std::vector<TestRay> rays = makeRays(grid, kind, n, seed);
  const double tfar = 1e30;

  std::vector<SurfaceHit> hits(rays.size());
  std::vector<char> found(rays.size());
  TraversalStats stats;
  const auto start = std::chrono::steady_clock::now();
  if (packets) {
    for (size_t k = 0; k < rays.size(); k += kPacketLanes) {
      const int n = int(std::min<size_t>(kPacketLanes, rays.size() - k));
      IsoSurface::PacketLane lanes[kPacketLanes];
      GridRayCache caches[kPacketLanes];
      for (int l = 0; l < n; ++l) {
        lanes[l].org = rays[k + size_t(l)].org;
        lanes[l].dir = rays[k + size_t(l)].dir;
        lanes[l].tfar = tfar;
        lanes[l].cache = &caches[l];
      }
      const uint32_t yes = surface.intersectPacket(lanes, (1u << n) - 1, &hits[k], stats);
      for (int l = 0; l < n; ++l) found[k + size_t(l)] = char(yes >> l & 1);
    }
  } else {
    for (size_t i = 0; i < rays.size(); ++i)
      found[i] = surface.intersect(rays[i].org, rays[i].dir, 0, tfar, hits[i], stats);
  }
  const double seconds = std::chrono::duration<double>(std::chrono::steady_clock::now() - start).count();

  AccuracyReport report;
  report.rays = rays.size();
  report.nsPerRay = seconds * 1e9 / double(rays.size());
  std::vector<double> dts;
  for (size_t i = 0; i < rays.size(); ++i) {
    SurfaceHit ref;
    const bool refFound = reference.intersect(rays[i].org, rays[i].dir, 0, tfar, ref, stats);
    if (refFound && ref.tangent) { ++report.tangentOnly; continue; }
    // t is in world units along a unit world direction; cell units divide by the spacing
    // seen along the ray.
    const double cell = 1 / length(rays[i].dir / grid.spacing());
    if (refFound) ++report.referenceHits;
    // A hit further from the reference than its own error bound found another crossing
    // (or none): later is a miss of the first one, earlier is a false hit.
    const double slack = found[i] ? hits[i].tError + ref.tError : 0;
    const bool miss = refFound && (!found[i] || hits[i].t > ref.t + slack);
    // A hit within its own bound of the ray's start is a start point on the surface: the
    // class there is a matter of rounding, in either precision.
    const bool atStart = found[i] && hits[i].t <= hits[i].tError;
    const bool falseHit =
        !miss && found[i] && (!refFound ? !atStart : hits[i].t < ref.t - slack);
    if ((miss || falseHit) && std::getenv("ISOTRACE_ACCURACY_DEBUG"))
      std::fprintf(stderr, "%s ray %zu: org %.17g %.17g %.17g dir %.17g %.17g %.17g ref %d t %.9g +- %.3g, tested %d t %.9g +- %.3g\n",
                   miss ? "miss" : "false hit", i, rays[i].org.x, rays[i].org.y, rays[i].org.z,
                   rays[i].dir.x, rays[i].dir.y, rays[i].dir.z, int(refFound), ref.t, ref.tError,
                   int(found[i]), hits[i].t, hits[i].tError);
    if (miss) { ++report.misses; continue; }
    if (falseHit) { ++report.falseHits; continue; }
    if (refFound) dts.push_back(std::fabs(hits[i].t - ref.t) / cell);
  }
  if (!dts.empty()) {
    std::sort(dts.begin(), dts.end());
    report.medianDt = dts[dts.size() / 2];
    report.p99Dt = dts[std::min(dts.size() - 1, size_t(double(dts.size()) * 0.99))];
    report.maxDt = dts.back();
  }
  return report;
}

}  // namespace iso

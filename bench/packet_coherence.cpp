// How full would SIMD packets of rays be in the brick walk? The question behind issue 11's
// verdict (docs/BENCHMARKS.md, "Sixth session"): a brick callback that takes Embree's 8- or
// 16-wide packets walks the lanes' DDAs in lockstep, so it pays for the longest walk of the
// packet in each brick, whatever the other lanes do.
//
// For one ray per pixel (pixel centres) and three kinds of rays — camera rays, rays from the
// iso-surface hits towards the scene's first directional light, one cosine-distributed bounce
// from each hit — this lists the bricks each ray queries, front to back as Embree would
// (a closest-hit query stops past the nearest hit, an occlusion query at the first one), and
// the cells walked in each. Packets are tiles of 4x2 (8-wide) or 4x4 (16-wide) pixels; for
// every (packet, brick) the lockstep walk takes as many steps as its longest lane. Printed:
// the lanes active per packet-brick, and the cells walked per lockstep step (the most a
// lockstep walk could gain over one ray at a time; the solve of a cell diverges further).
//
//   build/bench/packet_coherence SCENE.json [WIDTH]      (WIDTH 16-1920, default 320; the
//                                                         height keeps the scene's aspect)
#include <algorithm>
#include <cstdio>
#include <cstdlib>
#include <exception>
#include <map>
#include <random>
#include <string>
#include <vector>

#include "scene/world.h"

using namespace iso;

namespace {

struct BrickQuery {
  uint64_t brick;  // surface index << 32 | primitive
  uint64_t cells;
};

// The tight boxes of every surface's active bricks (object space), as Embree holds them.
struct BrickBox {
  float lower[3], upper[3];
};
std::vector<std::vector<BrickBox>> brickBoxes(const World& world) {
  std::vector<std::vector<BrickBox>> boxes(world.surfaces().size());
  for (size_t si = 0; si < boxes.size(); ++si) {
    const IsoSurface& surface = *world.surfaces()[si].surface;
    boxes[si].resize(surface.activeBricks().size());
    for (uint32_t p = 0; p < boxes[si].size(); ++p) surface.primitiveBounds(p, boxes[si][p].lower, boxes[si][p].upper);
  }
  return boxes;
}

// The bricks of every surface a ray queries, nearest box first, and the cells walked in each
// (surfaces are walked one after the other: the bricks of a later one beyond an earlier one's
// hit are not queried, as Embree's shortened ray would not reach them).
void walkBricks(const World& world, const std::vector<std::vector<BrickBox>>& boxes, const Ray& ray, double tfar,
                bool anyHit, std::vector<BrickQuery>& out) {
  out.clear();
  std::vector<std::pair<double, uint32_t>> entered;
  for (size_t si = 0; si < boxes.size(); ++si) {
    const IsoSurface& surface = *world.surfaces()[si].surface;
    const Vec3d org = surface.objectOrigin(ray.origin()), dir = surface.objectDirection(Vec3d(ray.dir));
    const StartClass start = ray.fromSurface == int(si)
                                 ? (ray.fromInside ? StartClass::Inside : StartClass::Outside)
                                 : StartClass::Unknown;
    entered.clear();
    for (uint32_t p = 0; p < boxes[si].size(); ++p) {
      const BrickBox& box = boxes[si][p];
      double t0 = ray.tnear, t1 = tfar;
      for (int a = 0; a < 3; ++a) {
        double ta = (box.lower[a] - org[a]) / dir[a], tb = (box.upper[a] - org[a]) / dir[a];
        if (ta > tb) std::swap(ta, tb);
        t0 = std::max(t0, ta);
        t1 = std::min(t1, tb);
      }
      if (t0 <= t1) entered.push_back({t0, p});
    }
    std::sort(entered.begin(), entered.end());
    for (const auto& [tEnter, p] : entered) {
      if (tEnter > tfar) break;
      TraversalStats stats;
      bool hit;
      if (anyHit) {
        hit = surface.occludedBrick(p, org, dir, ray.tnear, tfar, stats, start);
      } else {
        SurfaceHit h;
        hit = surface.intersectBrick(p, org, dir, ray.tnear, tfar, h, stats, start);
        if (hit) tfar = std::min(tfar, h.t);  // the nearest hit so far ends every surface's walk
      }
      out.push_back({uint64_t(si) << 32 | p, stats.cellsVisited});
      if (hit && anyHit) return;
    }
  }
}

void printCoherence(const char* kind, const std::vector<std::vector<BrickQuery>>& perPixel, int width, int height) {
  for (const int lanes : {8, 16}) {
    const int tileX = 4, tileY = lanes / 4;
    uint64_t queries = 0, cells = 0, groups = 0, active = 0, steps = 0;
    for (int y0 = 0; y0 + tileY <= height; y0 += tileY)
      for (int x0 = 0; x0 + tileX <= width; x0 += tileX) {
        std::map<uint64_t, std::pair<int, uint64_t>> bricks;  // lanes in it, longest walk
        for (int y = y0; y < y0 + tileY; ++y)
          for (int x = x0; x < x0 + tileX; ++x)
            for (const BrickQuery& q : perPixel[size_t(y) * width + x]) {
              ++queries;
              cells += q.cells;
              auto& b = bricks[q.brick];
              ++b.first;
              b.second = std::max(b.second, q.cells);
            }
        for (const auto& [brick, b] : bricks) {
          ++groups;
          active += b.first;
          steps += b.second;
        }
      }
    if (groups == 0) {
      std::printf("%-15s %2d-wide: no brick queries\n", kind, lanes);
      continue;
    }
    std::printf("%-15s %2d-wide: %8llu queries %9llu cells | %7llu packet-bricks, %5.2f lanes active, "
                "%5.2f cells per lockstep step (%4.1f%% of the lanes)\n",
                kind, lanes, (unsigned long long)queries, (unsigned long long)cells, (unsigned long long)groups,
                double(active) / double(groups), double(cells) / double(steps),
                100.0 * double(cells) / (double(lanes) * double(steps)));
  }
}

}  // namespace

int main(int argc, char** argv) {
  if (argc < 2 || argc > 3) {
    std::fprintf(stderr, "usage: packet_coherence SCENE.json [WIDTH]\n");
    return 2;
  }
  try {
    int width = 320;
    if (argc == 3) {
      char* end = nullptr;
      const long w = std::strtol(argv[2], &end, 10);
      if (end == argv[2] || *end != '\0' || w < 16 || w > 1920) {
        std::fprintf(stderr, "packet_coherence: WIDTH: expected a whole number from 16 to 1920, got '%s'\n", argv[2]);
        return 2;
      }
      width = int(w);
    }
    const SceneDesc scene = parseSceneFile(argv[1]);
    const int height = std::max(1, int(double(width) * scene.settings.height / scene.settings.width + 0.5));
    World world(scene, IntersectorSpec{});
    if (world.surfaces().empty()) {
      std::fprintf(stderr, "packet_coherence: %s: the scene has no iso-surface\n", argv[1]);
      return 2;
    }
    Vec3f toSun{0, 1, 0};
    for (const LightDesc& light : scene.lights)
      if (light.type == LightType::Directional) {
        toSun = Vec3f(-normalize(light.direction));
        break;
      }
    const Camera camera(world.camera(), width, height);
    const auto boxes = brickBoxes(world);
    std::mt19937 rng(7);
    std::uniform_real_distribution<float> uniform(0.f, 1.f);
    const size_t pixels = size_t(width) * size_t(height);
    std::vector<std::vector<BrickQuery>> cameraRays(pixels), sunRays(pixels), bounceRays(pixels);
    for (int y = 0; y < height; ++y)
      for (int x = 0; x < width; ++x) {
        const size_t i = size_t(y) * width + x;
        const Ray ray = camera.generateRay(float(x) + 0.5f, float(y) + 0.5f);
        Hit hit;
        TraversalStats stats;
        const bool found = world.intersect(ray, hit, stats);
        // A triangle in front ends the walk there, as Embree's shortened ray would.
        walkBricks(world, boxes, ray, found && hit.surface < 0 ? double(hit.t) : 1e30, false, cameraRays[i]);
        if (!found || hit.surface < 0) continue;
        const Vec3f n = dot(hit.normal, ray.dir) < 0 ? hit.normal : -hit.normal;
        if (dot(n, toSun) > 0) walkBricks(world, boxes, spawnRay(hit, toSun), 1e30, true, sunRays[i]);
        const float u0 = uniform(rng), u1 = uniform(rng);
        const Vec3f bounce = Frame::fromNormal(n, ray.dir).toWorld(sampleCosineHemisphere(u0, u1));
        walkBricks(world, boxes, spawnRay(hit, bounce), 1e30, false, bounceRays[i]);
      }
    std::printf("%s, %dx%d, one ray per pixel and kind\n", argv[1], width, height);
    printCoherence("camera", cameraRays, width, height);
    printCoherence("sun shadow", sunRays, width, height);
    printCoherence("diffuse bounce", bounceRays, width, height);
  } catch (const std::exception& e) {
    std::fprintf(stderr, "packet_coherence: %s\n", e.what());
    return 2;
  }
  return 0;
}

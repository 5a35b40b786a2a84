// Prints each intersector against the double-precision reference on real volumes and
// procedural fields: misses, false hits, |dt| in cells, time per ray.
//   build/bench/intersector_accuracy [RAYS]
#include <cstdio>
#include <cstdlib>
#include <string>

#include "accuracy/accuracy.h"
#include "volume/loaders.h"
#include "volume/procedural.h"

using namespace iso;

int main(int argc, char** argv) {
  const int rays = argc > 1 ? std::atoi(argv[1]) : 100000;
  const std::string data = std::string(ISOTRACE_DATA_DIR) + "/volumes/";
  struct Case { std::string name; Grid grid; double iso; };
  std::vector<Case> cases;
  cases.push_back({"nucleon iso 60", loadVolumeFile(data + "nucleon/nucleon.nrrd"), 60});
  cases.push_back({"neghip iso 40.5", loadVolumeFile(data + "neghip_64x64x64_uint8.raw"), 40.5});
  cases.push_back({"hydrogen iso 20", loadVolumeFile(data + "hydrogen_atom_128x128x128_uint8.raw"), 20});
  cases.push_back({"bucky iso 128", loadVolumeFile(data + "bucky_32x32x32_uint8.raw"), 128});
  cases.push_back({"gyroid 64^3 iso 0", makeProceduralGrid(Field::Gyroid, {64, 64, 64}), 0});
  cases.push_back({"marschner-lobb 41^3 iso 0.5", makeProceduralGrid(Field::MarschnerLobb, {41, 41, 41}), 0.5});
  const char* specs[] = {"linear", "neubauer", "schwarze", "isolation:1", "isolation:2",
                         "isolation:4", "isolation", "reference"};
  std::printf("%-28s %-10s %-12s %8s %8s %8s %8s %10s %10s %10s %8s\n", "volume", "rays", "intersector",
              "refHits", "tangent", "misses", "false", "median|dt|", "p99|dt|", "max|dt|", "ns/ray");
  for (const Case& c : cases) {
    for (RayKind kind : {RayKind::Camera, RayKind::Secondary}) {
      for (const char* name : specs) {
        IntersectorSpec spec;
        std::string error;
        parseIntersector(name, spec, error);
        const AccuracyReport r = measureAccuracy(c.grid, c.iso, spec, kind, rays, 42);
        std::printf("%-28s %-10s %-12s %8llu %8llu %8llu %8llu %10.2e %10.2e %10.2e %8.0f\n",
                    c.name.c_str(), kind == RayKind::Camera ? "camera" : "secondary",
                    intersectorName(spec).c_str(), (unsigned long long)r.referenceHits,
                    (unsigned long long)r.tangentOnly, (unsigned long long)r.misses,
                    (unsigned long long)r.falseHits, r.medianDt, r.p99Dt, r.maxDt, r.nsPerRay);
        std::fflush(stdout);
      }
    }
  }
}

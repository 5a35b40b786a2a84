// Prints the numerical stress suite (accuracy/stress.h) for every intersector:
//   build/bench/stress
#include <cstdio>

#include "accuracy/stress.h"

using namespace iso;

int main() {
  const char* specs[] = {"linear", "neubauer", "schwarze", "isolation:1", "isolation", "reference"};
  std::printf("%-24s %-12s %6s %8s %7s %7s %5s %7s  %s\n", "case", "intersector", "rays", "refHits", "misses",
              "wrong", "nans", "parity", "what");
  for (const StressCase& c : stressCases()) {
    for (const char* name : specs) {
      IntersectorSpec spec;
      std::string error;
      parseIntersector(name, spec, error);
      const StressResult r = runStress(c, spec);
      std::printf("%-24s %-12s %6llu %8llu %7llu %7llu %5llu %7llu  %s\n", c.name.c_str(), intersectorName(spec).c_str(),
                  (unsigned long long)r.rays, (unsigned long long)r.referenceHits, (unsigned long long)r.misses,
                  (unsigned long long)r.wrongRoots, (unsigned long long)r.nans, (unsigned long long)r.parityErrors,
                  name == specs[0] ? c.what.c_str() : "");
      std::fflush(stdout);
    }
  }
}

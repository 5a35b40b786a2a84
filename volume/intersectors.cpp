#include "volume/intersectors.h"

namespace iso {

const char* intersectorList() { return "linear, neubauer[:N], schwarze, isolation[:N], reference"; }

bool parseIntersector(const std::string& text, IntersectorSpec& spec, std::string& error) {
  std::string name = text;
  int iterations = -1;
  const auto colon = text.find(':');
  if (colon != std::string::npos) {
    name = text.substr(0, colon);
    const std::string n = text.substr(colon + 1);
    if (n.empty() || n.size() > 3 || n.find_first_not_of("0123456789") != std::string::npos ||
        std::stoi(n) < 1 || std::stoi(n) > 200) {
      error = "iteration count in '" + text + "' must be a whole number from 1 to 200";
      return false;
    }
    iterations = std::stoi(n);
  }
  IntersectorSpec s;
  if (name == "linear") s.kind = IntersectorKind::Linear;
  else if (name == "neubauer") { s.kind = IntersectorKind::Neubauer; s.iterations = 3; }
  else if (name == "schwarze") s.kind = IntersectorKind::Schwarze;
  else if (name == "isolation") { s.kind = IntersectorKind::Isolation; s.iterations = 8; }
  else if (name == "reference") s.kind = IntersectorKind::Reference;
  else {
    error = "unknown intersector '" + text + "' (known: " + intersectorList() + ")";
    return false;
  }
  if (iterations > 0) {
    if (s.kind != IntersectorKind::Neubauer && s.kind != IntersectorKind::Isolation) {
      error = "intersector '" + name + "' takes no iteration count";
      return false;
    }
    s.iterations = iterations;
  }
  spec = s;
  return true;
}

std::string intersectorName(const IntersectorSpec& spec) {
  switch (spec.kind) {
    case IntersectorKind::Linear: return "linear";
    case IntersectorKind::Neubauer: return "neubauer:" + std::to_string(spec.iterations);
    case IntersectorKind::Schwarze: return "schwarze";
    case IntersectorKind::Isolation: return "isolation:" + std::to_string(spec.iterations);
    case IntersectorKind::Reference: return "reference";
  }
  return "?";
}

namespace detail {

bool firstInDouble(const CellSegment<float>& seg, Root<float>& root) {
  CellSegment<double> wide;
  if (seg.hasExact)
    seg.exactCorners(seg.exactCells, seg.exactCell, seg.exactIso, wide.g);
  else
    for (int i = 0; i < 8; ++i) wide.g[i] = seg.g[i];
  wide.a = seg.hasExact ? seg.exactEnd(0) : Vec3d(seg.a);
  wide.b = seg.hasExact ? seg.exactEnd(1) : Vec3d(seg.b);
  wide.f0 = seg.f0;
  wide.f1 = seg.f1;
  const Cubic<double> cubic = cellCubic(wide);
  double s[4], f[4];
  const int n = isolate(wide, cubic, s, f);
  for (int i = 0; i + 1 < n; ++i) {
    if (isInside(f[i]) != isInside(f[i + 1])) {
      const Root<double> r = refineWithBound(s[i], s[i + 1], f[i], f[i + 1], 200, wide, cubic);
      const float rs = std::clamp(float(r.s), 0.f, 1.f);
      const float error = float(r.sError + std::fabs(double(rs) - r.s));
      root = {rs, std::nextafter(error, 2.f), false};
      return true;
    }
  }
  return false;
}

}  // namespace detail

}  // namespace iso

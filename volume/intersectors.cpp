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

}  // namespace iso

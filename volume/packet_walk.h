#pragma once
// Up to 8 rays' walks through one brick together (an Embree packet's lanes on one primitive).
// Each lane is a CellWalk (volume/traversal.h): the DDA and every decision a cell makes are the
// scalar walk's own code. What the lanes share is the solve: each step takes every lane to its
// next cell to solve and solves their cubics together, 8 lanes per instruction (AVX2 when the
// CPU has it, chosen at run time; SSE otherwise). The vector solve of the isolation intersector
// gives the scalar one's bits (same operations in the same order on every lane, no FMA
// contraction: packet_walk.cpp is built with -ffp-contract=off); tests/packet_test.cpp checks
// it lane by lane on real volumes. The other intersectors solve lane by lane.
#include <cstdint>
#include <new>
#include <type_traits>
#include <utility>

#include "volume/traversal.h"

namespace iso {

constexpr int kPacketLanes = 8;

// The lanes set in an 8-lane mask. (The build targets baseline x86-64, without POPCNT, where
// __builtin_popcount is a call into libgcc: two of them per solve step.)
inline int laneCount(uint32_t mask) {
  constexpr unsigned char kNibble[16] = {0, 1, 1, 2, 1, 2, 2, 3, 1, 2, 2, 3, 2, 3, 3, 4};
  return kNibble[mask & 15] + kNibble[(mask >> 4) & 15];
}

// Per-lane scratch of a packet query, left uninitialised: a query constructs (or assigns) the
// entries of its active lanes only. The types held are trivially destructible plain data;
// zero-filling 8 of each on every brick a packet visits cost more than the walk's setup.
template <typename T>
class LaneSlots {
 public:
  static_assert(std::is_trivially_destructible_v<T>);
  T& operator[](int lane) { return *std::launder(reinterpret_cast<T*>(m_bytes) + lane); }
  const T& operator[](int lane) const { return *std::launder(reinterpret_cast<const T*>(m_bytes) + lane); }
  T* data() { return std::launder(reinterpret_cast<T*>(m_bytes)); }
  template <typename... Args>
  T& emplace(int lane, Args&&... args) {
    return *new (m_bytes + sizeof(T) * size_t(lane)) T(std::forward<Args>(args)...);
  }
  // Default-initialised (emplace(lane) value-initialises: zeroes first what T leaves unset).
  T& construct(int lane) { return *new (m_bytes + sizeof(T) * size_t(lane)) T; }

 private:
  alignas(T) unsigned char m_bytes[sizeof(T) * kPacketLanes];
};

// The isolation intersector (IsolationIntersector in volume/intersectors.h) on up to 8 segments.
// Lanes not in `mask` are ignored (their pointers may be null).
struct IsolationPacket {
  int iterations = 8;
  // Bit l of the result: segs[l] has a crossing; roots[l] is then IsolationIntersector::first's.
  uint32_t first(const CellSegment<float>* const segs[kPacketLanes], uint32_t mask, Root<float> roots[kPacketLanes]) const;
  // Bit l: IsolationIntersector::any(*segs[l]).
  uint32_t any(const CellSegment<float>* const segs[kPacketLanes], uint32_t mask) const;
};

// Any scalar intersector, lane by lane, with IsolationPacket's interface.
template <typename Intersector>
struct LaneByLane {
  Intersector solver;
  uint32_t first(const CellSegment<float>* const segs[kPacketLanes], uint32_t mask, Root<float> roots[kPacketLanes]) const {
    uint32_t found = 0;
    for (int l = 0; l < kPacketLanes; ++l)
      if ((mask >> l & 1) && solver.first(*segs[l], roots[l])) found |= 1u << l;
    return found;
  }
  uint32_t any(const CellSegment<float>* const segs[kPacketLanes], uint32_t mask) const {
    uint32_t found = 0;
    for (int l = 0; l < kPacketLanes; ++l)
      if ((mask >> l & 1) && solver.any(*segs[l])) found |= 1u << l;
    return found;
  }
};

// Walks the lanes in `live` (whose begin() returned true) to their first crossing: bit l of the
// result is set when lane l found one (hits[l], for closest-hit queries). Each step takes every
// live lane on through the cells it passes to its next cell to solve (or its end), then solves
// those cells together: a lane that passes cells while another solves does not leave the next
// solve short of a lane (at a lockstep of one cell per lane and step, 35-50% of the vector
// solve's lanes were busy). Each lane gets exactly what traverseCells gives it alone: its cells
// are visited, solved and advanced in the same order.
template <bool AnyHit, typename Cells, typename PacketSolver>
uint32_t traversePacket(CellWalk<float, Cells>* walks, uint32_t live, const PacketSolver& solver,
                        CellHit<float>* hits, TraversalStats& stats) {
  using Visit = typename CellWalk<float, Cells>::Visit;
  uint32_t found = 0;
  const CellSegment<float>* segs[kPacketLanes] = {};
  while (live) {
    ++stats.lockstepSteps;
    uint32_t solve = 0;
    for (uint32_t rest = live; rest; rest &= rest - 1) {
      const int l = __builtin_ctz(rest);
      const uint32_t bit = 1u << l;
      for (;;) {
        const Visit v = walks[l].visit(stats);
        if (v == Visit::Solve) {
          solve |= bit;
          segs[l] = &walks[l].segment();
          break;
        }
        if (v == Visit::StartCrossing) {
          if constexpr (!AnyHit) walks[l].startHit(hits[l], stats);
          found |= bit;
          live &= ~bit;
          break;
        }
        if (!walks[l].advance()) {  // (a cell passed)
          live &= ~bit;
          break;
        }
      }
    }
    if (!solve) continue;  // (every lane ended)
    ++stats.solveSteps;
    stats.solveLanes += uint64_t(laneCount(solve));
    if constexpr (AnyHit) {
      const uint32_t yes = solver.any(segs, solve);
      found |= yes;
      live &= ~yes;
    } else {
      Root<float> roots[kPacketLanes];
      const uint32_t yes = solver.first(segs, solve, roots);
      for (uint32_t rest = yes; rest; rest &= rest - 1) {
        const int l = __builtin_ctz(rest);
        walks[l].hitAt(roots[l], hits[l], stats);
      }
      found |= yes;
      live &= ~yes;
    }
    // The lanes still live solved a cell without a crossing: on to the next.
    for (uint32_t rest = live; rest; rest &= rest - 1) {
      const int l = __builtin_ctz(rest);
      if (!walks[l].advance()) live &= ~(1u << l);
    }
  }
  return found;
}

}  // namespace iso

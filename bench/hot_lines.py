#!/usr/bin/env python3
"""Where one function's own instructions go, by source line through the inlining (callgrind).

callgrind_annotate charges an inlined helper's instructions to the helper's file and line, summed
over every function it was inlined into (vec3.h's operator- over the whole program), so it cannot
say that a given function spends 100 instructions a hit in one inlined Vec3 subtraction. This
script reads a callgrind file made with --dump-instr=yes, takes the self cost of every
instruction of the functions whose name contains NAME (not what they call), and maps each
address through addr2line -i to its chain of inlined lines: "vec3.h:23 <- world_trace.cpp:331 <-
world_trace.cpp:311" is the operator- at vec3.h:23 inlined at line 331, itself inlined at 311.

The binary needs debug information for the lines; a second build of the same code with -g gives
the same instructions (cmake -S . -B /tmp/build-g -DCMAKE_BUILD_TYPE=Release -DCMAKE_CXX_FLAGS=-g).
Usage:
  valgrind --tool=callgrind --dump-instr=yes --callgrind-out-file=cg.out \\
      --toggle-collect='iso::TileRenderer::renderPass(*' /tmp/build-g/isotrace render SCENE ... --threads 1
  bench/hot_lines.py cg.out 'World::intersectPacket' /tmp/build-g/isotrace [--top 30] [--depth 3]
(On this machine valgrind needs the Highway timer stand-in: see bench/stage_breakdown.py.)
Prints the function's self instructions, then the chains of inlined lines that cost most.
"""
import argparse
import collections
import re
import subprocess


def self_costs(path, name, event="Ir"):
    """{address: self cost} of the functions whose name contains `name`: instructions, or another
    event the file holds (e.g. Bcm, mispredicted conditional branches, with --branch-sim=yes)."""
    names, costs = {}, collections.Counter()
    current, last, after_call = "", 0, False
    column = 0
    for line in open(path):
        line = line.rstrip("\n")
        if line.startswith("events:"):
            events = line.split()[1:]
            if event not in events:
                raise SystemExit("hot_lines: the file has no event %s (it has %s)" % (event, " ".join(events)))
            column = events.index(event)
            continue
        m = re.match(r"^(c?)fn=\((\d+)\)(?: (.*))?$", line)
        if m:
            if m.group(3):
                names[m.group(2)] = m.group(3)
            if not m.group(1):
                current = names.get(m.group(2), "")
            continue
        if line.startswith("calls="):
            after_call = True  # the next cost line is the call's inclusive cost
            continue
        m = re.match(r"^(0x[0-9a-f]+|[+-]\d+|\*)\s+\S+((?:\s+\d+)+)", line)
        if not m:
            continue
        a = m.group(1)
        if a.startswith("0x"):
            last = int(a, 16)
        elif a[0] in "+-":
            last += int(a)
        if after_call:
            after_call = False
            continue
        if name in current:
            values = m.group(2).split()
            if column < len(values):  # (callgrind leaves out trailing zeros)
                costs[last] += int(values[column])
    return costs


def main():
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("callgrind_file")
    parser.add_argument("name", help="a part of the function's name, e.g. 'World::intersectPacket'")
    parser.add_argument("binary", help="the binary that ran, with debug information")
    parser.add_argument("--top", type=int, default=30)
    parser.add_argument("--depth", type=int, default=3, help="inlined frames shown per line")
    parser.add_argument("--event", default="Ir", help="the cost to rank lines by (Ir; Bcm with --branch-sim=yes)")
    args = parser.parse_args()
    costs = self_costs(args.callgrind_file, args.name, args.event)
    print("self", sum(costs.values()))
    addresses = sorted(costs)
    chains, current = {}, None
    out = subprocess.run(["addr2line", "-e", args.binary, "-a", "-i"] + [hex(a) for a in addresses],
                         stdout=subprocess.PIPE, text=True, check=True).stdout
    for line in out.split("\n"):
        if line.startswith("0x"):
            current = int(line, 16)
            chains[current] = []
        elif line and current is not None:
            chains[current].append(line.split("/")[-1])
    by_chain = collections.Counter()
    for a, c in costs.items():
        by_chain[" <- ".join(chains.get(a, ["?"])[:args.depth])] += c
    for chain, c in by_chain.most_common(args.top):
        print(f"{c:>12,}  {chain}")


if __name__ == "__main__":
    main()

#!/usr/bin/env python3
"""`isotrace view`: time from an iso change to the first frame showing it, and samples per
second while the image refines.

For each scene, starts `isotrace view SCENE --port 0 --resolution 480x360`, listens to its
event stream, and --changes times moves iso-surface 0 between two values (a quarter and
three quarters of the way between the current value and the volume's range ends); for each,
the time from sending the change to the first frame of the new version, and the samples per
pixel per second until the scene's spp is reached. Prints medians.
Usage: bench/view_latency.py [--changes 10] [--integrator NAME] [--ray-flow F] [SCENE.json ...]
--ray-flow: the scene's integrator.ray_flow for the run (a copy of the scene beside it, removed after).
"""
import argparse
import http.client
import json
import os
import statistics
import subprocess
import sys
import time

ROOT = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))
ISOTRACE = os.path.join(ROOT, "build", "isotrace")


class Events:
    """The server-sent frames of one connection, as dicts."""

    def __init__(self, host, port):
        self.conn = http.client.HTTPConnection(host, port, timeout=60)
        self.conn.request("GET", "/api/events")
        self.response = self.conn.getresponse()

    def next_frame(self):
        lines = []
        while True:
            line = self.response.readline().decode()
            if line in ("\n", "\r\n"):
                if lines and lines[0].startswith("event: frame"):
                    return json.loads(lines[1][len("data: "):])
                lines = []
            elif line:
                lines.append(line.rstrip("\n"))
            else:
                raise EOFError("event stream ended")


def post(host, port, path, body):
    conn = http.client.HTTPConnection(host, port, timeout=60)
    conn.request("POST", path, body=json.dumps(body), headers={"Content-Type": "application/json"})
    r = conn.getresponse()
    data = json.loads(r.read())
    if r.status != 200:
        sys.exit("view_latency: %s: %s" % (path, data))
    return data


def main():
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("scenes", nargs="*")
    parser.add_argument("--changes", type=int, default=10)
    parser.add_argument("--integrator")
    parser.add_argument("--ray-flow", choices=("wavefront", "scalar"))
    a = parser.parse_args()
    scenes = a.scenes or [os.path.join(ROOT, "examples", n + ".json") for n in ("default", "ct_head", "mri_brain")]
    print("| scene | integrator | ray flow | first preview after an iso change, ms (median, min-max) | spp reached | samples/s while refining (median) |")
    print("|---|---|---|---|---|---|")
    for scene in scenes:
        copy = None
        if a.ray_flow:
            with open(scene) as f:
                desc = json.load(f)
            desc.setdefault("integrator", {})["ray_flow"] = a.ray_flow
            copy = os.path.join(os.path.dirname(os.path.abspath(scene)), ".view_latency_%d.json" % os.getpid())
            with open(copy, "w") as f:
                json.dump(desc, f)
        server = subprocess.Popen([ISOTRACE, "view", copy or scene, "--port", "0", "--resolution", "480x360"],
                                  stdout=subprocess.PIPE, stderr=subprocess.DEVNULL, text=True)
        try:
            url = server.stdout.readline().strip()
            host, port = url[len("http://"):].rstrip("/").split(":")
            port = int(port)
            if a.integrator:
                post(host, port, "/api/state", {"integrator": a.integrator})
            conn = http.client.HTTPConnection(host, port)
            conn.request("GET", "/api/state")
            state = json.loads(conn.getresponse().read())
            surface = state["surfaces"][0]
            values = [surface["value"] + (surface["min"] - surface["value"]) * 0.25,
                      surface["value"] + (surface["max"] - surface["value"]) * 0.25]
            events = Events(host, port)
            latencies, rates, reached = [], [], 0
            for i in range(a.changes):
                start = time.perf_counter()
                version = post(host, port, "/api/state", {"surface": 0, "value": values[i % 2]})["version"]
                first = None
                while True:
                    f = events.next_frame()
                    if f["version"] != version:
                        continue
                    if first is None:
                        first = time.perf_counter() - start
                    if f["spp"] >= f["spp_target"]:
                        elapsed = time.perf_counter() - start
                        reached = f["spp"]
                        rates.append(f["spp"] * 480 * 360 / elapsed)
                        break
                latencies.append(first * 1000)
            print("| %s | %s | %s | %.0f (%.0f-%.0f) | %d | %.3g |" % (
                os.path.splitext(os.path.basename(scene))[0], state["integrator"], a.ray_flow or "scene's",
                statistics.median(latencies),
                min(latencies), max(latencies), reached, statistics.median(rates)))
        finally:
            server.send_signal(2)
            server.wait(timeout=10)
            if copy:
                os.remove(copy)


if __name__ == "__main__":
    main()

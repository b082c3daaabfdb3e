#!/usr/bin/env python3
"""The layout experiment over the network (BENCHMARKS.md, "Remote terrains").

For each terrain file (one per layout) and each injected latency, serves the files with
`relief serve --latency-ms L` on loopback, flies PATH headless (no rendering, frames paced like a
display) from a fresh cache, and prints one markdown row: requests and bytes (total and per
frame), the causal round trips and the time to the first complete frame, coarse frames, the
longest update (the refining thread never waits, so this is refinement alone) and whether the
final strip equals the local file's (by digest).

usage: bench_remote.py RELIEF PATH.json TOLERANCE_PX PACE_MS LATENCIES_MS FILE.relief...
  e.g. bench_remote.py target/release/relief low.json 2 16 1,20,50 synth_*.relief
"""
import json
import os
import shutil
import subprocess
import sys
import tempfile
import time


def fly(relief, target, path, tol, pace, out, env):
    cmd = [relief, "fly", target, "--path", path, "--no-render", "--tolerance", str(tol),
           "--pace", str(pace), "--quiet", "--stats", out]
    subprocess.run(cmd, check=True, env=env, stdout=subprocess.DEVNULL)
    with open(out) as f:
        return json.load(f)


def main():
    if len(sys.argv) < 7:
        sys.exit(__doc__)
    relief, path, tol, pace, lats = sys.argv[1], sys.argv[2], float(sys.argv[3]), float(sys.argv[4]), sys.argv[5]
    files = sys.argv[6:]
    work = tempfile.mkdtemp(prefix="relief-net-")
    env = dict(os.environ, RELIEF_CACHE_DIR=os.path.join(work, "cache"))
    local = {f: fly(relief, f, path, tol, pace, os.path.join(work, "local.json"), env)["summary"] for f in files}
    print(f"path {path}, tau = {tol} px, frames paced {pace} ms, no rendering")
    print()
    print("| layout | latency | requests | MiB | requests / frame | KiB / frame | round trips to first complete frame | first complete frame (s) | coarse frames | longest update (ms) | final strip = local |")
    print("|---|---|---|---|---|---|---|---|---|---|---|")
    for lat in [int(x) for x in lats.split(",")]:
        port = 18000 + lat
        server = subprocess.Popen([relief, "serve", "--port", str(port), "--latency-ms", str(lat), *files],
                                  stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)
        time.sleep(1.0)
        try:
            for f in files:
                shutil.rmtree(env["RELIEF_CACHE_DIR"], ignore_errors=True)
                url = f"http://127.0.0.1:{port}/{os.path.basename(f)}"
                r = fly(relief, url, path, tol, pace, os.path.join(work, "remote.json"), env)
                s, frames = r["summary"], r["frames"]
                n = len(frames)
                layout = s["source"].split(", ")[1].replace(" layout", "")
                first = s["first_complete_frame"]
                same = "yes" if s["final_digest"] == local[f]["final_digest"] else "NO"
                print(f"| {layout} | {lat} ms | {s['requests']} | {s['net_bytes'] / 2**20:.1f} | "
                      f"{s['requests'] / n:.2f} | {s['net_bytes'] / n / 1024:.0f} | "
                      f"{s['first_complete_round_trips'] if first is not None else 'none'} | "
                      f"{s['first_complete_s']:.2f} (frame {first}) | " if first is not None else
                      f"| {layout} | {lat} ms | {s['requests']} | {s['net_bytes'] / 2**20:.1f} | "
                      f"{s['requests'] / n:.2f} | {s['net_bytes'] / n / 1024:.0f} | none | none | ", end="")
                print(f"{s['coarse_frames']} of {n} | {s['update_ms']['max']:.1f} | {same} |")
                sys.stdout.flush()
        finally:
            server.terminate()
            server.wait()
    shutil.rmtree(work, ignore_errors=True)


if __name__ == "__main__":
    main()

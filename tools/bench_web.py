#!/usr/bin/env python3
"""The web viewer's figures for BENCHMARKS.md (issue 45), in one run on this machine:

- the wasm's size, raw and gzip -9;
- time to the first complete frame (page start to a frame that had every record it needed and
  nothing in flight), and its round trips, at 0 and 50 ms added per request (`relief serve
  --latency-ms`), median of --runs page loads each, over the bundled Zürich terrain;
- refinement time per frame (mean: the page's clock ticks in 0.1 ms), wasm in headless Chromium vs native (the page's own code, the
  `refine_views` example), on the same turntable views (overview orbit turned 2° a frame);
- frames per second of the turntable on SwiftShader (WebGL2 on the CPU: for scale only).

Needs: target/release/relief and the viewer in target/viewer (bash tools/web.sh), Chromium's
headless shell (tools/browser.py). Usage: python3 tools/bench_web.py [--runs 5] [--json]
"""
import argparse
import gzip
import json
import os
import re
import statistics
import subprocess
import sys
import tempfile
import time

ROOT = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))
sys.path.insert(0, os.path.join(ROOT, "tools"))
import browser  # noqa: E402

RELIEF = os.path.join(ROOT, "target", "release", "relief")
VIEWER = os.path.join(ROOT, "target", "viewer")


def serve(path, latency_ms):
    p = subprocess.Popen(
        [RELIEF, "serve", path, "--viewer", "--viewer-dir", VIEWER, "--port", "0", "--latency-ms", str(latency_ms)],
        stdout=subprocess.PIPE,
        stderr=subprocess.DEVNULL,
        text=True,
    )
    line = p.stdout.readline().strip()
    if not line.startswith("http://"):
        p.kill()
        sys.exit(f"bench_web: relief serve printed {line!r}")
    return p, line


def page(url, width, height, timeout=120, ready=None):
    kw = {"ready_expr": ready} if ready else {}
    r = browser.run(url, None, width, height, timeout, **kw)
    if r["code"] != 0:
        sys.exit(f"bench_web: {url}: {r['message']}")
    return r["status"] if isinstance(r["status"], dict) else json.loads(r["status"])


def main():
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--runs", type=int, default=5)
    ap.add_argument("--frames", type=int, default=240)
    ap.add_argument("--tau", type=float, default=0.5, help="τ of the turntable, pixels")
    ap.add_argument("--json", action="store_true")
    a = ap.parse_args()
    out = {}
    wasm = os.path.join(VIEWER, "relief_web_bg.wasm")
    raw = open(wasm, "rb").read()
    out["wasm_bytes"] = len(raw)
    out["wasm_gzip_bytes"] = len(gzip.compress(raw, 9))
    tmp = tempfile.mkdtemp(prefix="relief-bench-web-")
    terrain = os.path.join(tmp, "zurich.relief")
    subprocess.run(
        [RELIEF, "convert", os.path.join(ROOT, "data", "zurich_25m_i16.tif"), terrain, "--layout", "interleaved", "-q"],
        check=True,
        stdout=subprocess.DEVNULL,
    )
    out["terrain_bytes"] = os.path.getsize(terrain)
    view = "eye=6400,640,1126&look=6400,7680,393&tau=2&hud=0"
    for latency in (0, 50):
        server, base = serve(terrain, latency)
        try:
            runs = [page(base.split("#")[0] + "#zurich.relief&" + view, 960, 540) for _ in range(a.runs)]
        finally:
            server.kill()
        out[f"first_complete_ms_latency_{latency}"] = statistics.median(r["first_complete_ms"] for r in runs)
        out[f"first_complete_round_trips_latency_{latency}"] = statistics.median(
            r["first_complete_round_trips"] for r in runs
        )
        out[f"requests_latency_{latency}"] = statistics.median(r["requests"] for r in runs)
        out[f"bytes_latency_{latency}"] = statistics.median(r["bytes"] for r in runs)
    # The turntable: wasm in the page, then native on the same views.
    server, base = serve(terrain, 0)
    try:
        spin = page(
            base.split("#")[0] + f"#zurich.relief&spin=2&tau={a.tau}&hud=0",
            960,
            540,
            ready=f"window.relief && window.relief.status().frames >= {a.frames}",
        )
    finally:
        server.kill()
    out["turntable_tau_px"] = a.tau
    out["wasm_refine_ms_median"] = spin["refine_ms_median"]
    out["wasm_refine_ms_mean"] = spin["refine_ms_mean"]
    out["wasm_frame_ms_median"] = spin["frame_ms_median"]
    out["swiftshader_fps"] = spin["fps"]
    out["wasm_frames"] = spin["frames"]
    native = subprocess.run(
        ["cargo", "run", "-q", "--release", "-p", "relief-web", "--example", "refine_views", "--", terrain,
         str(spin["frames"]), "2", "960", "540", str(a.tau)],
        cwd=ROOT,
        check=True,
        capture_output=True,
        text=True,
    )
    n = json.loads(native.stdout)
    out["native_refine_ms_median"] = n["refine_ms_median"]
    out["native_refine_ms_mean"] = n["refine_ms_mean"]
    out["native_triangles_median"] = n["triangles_median"]
    out["wasm_over_native_refine_mean"] = out["wasm_refine_ms_mean"] / max(n["refine_ms_mean"], 1e-9)
    if a.json:
        print(json.dumps(out, indent=1))
        return
    for k, v in out.items():
        print(f"{k}: {v:.3f}" if isinstance(v, float) else f"{k}: {v}")


if __name__ == "__main__":
    main()

#!/usr/bin/env python3
"""The out-of-core experiments in time, on emulated devices (BENCHMARKS.md, "Device latency").

Every run reads its file through `--device-latency MS` (a FUSE file system of relief's own that
makes each read request the kernel sends wait MS milliseconds; needs root), cold, at the
published latencies of an NVMe drive (0.02 ms), this machine's virtual disk (0.1), a cloud block
volume (1), a 7200 rpm disk (8) and an object store's first byte (30).

    python3 tools/bench_device.py metanode TREE.rmn PATH.json [--tolerance PX] [--frames N]
        Virt (map) against Ext (pool) at 1/2, 1/4 and 1/8 of the tree, both under the same
        cgroup cap B + S + margin (S: the navigator's own anonymous memory, measured by an
        uncapped Virt flight), frames paced 40 ms apart: per-frame adaptation ms, Ext/Virt,
        miss %, device requests.
    python3 tools/bench_device.py layouts TERRAIN.relief PATH.json [--cap BYTES]
        relief layouts --os under the device: per layout, cold refinement ms per frame next to
        its major faults.
    python3 tools/bench_device.py pages FILE.rpg... PATH.json
        relief pages fly --cold-frames under the device: the fetch's read ms per frame.

Prints Markdown tables; raw JSON goes to --out (default /work/bench/device). With matplotlib
installed, `metanode` also draws Ext/Virt against latency (--plot OUT.png).
"""

import argparse
import json
import os
import subprocess
import sys
import threading
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parent.parent
RELIEF = ROOT / "target" / "release" / "relief"
LATENCIES = [0.02, 0.1, 1, 8, 30]
FRACTIONS = [(1, 2), (1, 4), (1, 8)]


def run(args, sample_anon=False):
    """Runs relief; returns (stdout, peak RssAnon bytes or None)."""
    p = subprocess.Popen([str(a) for a in args], stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
    peak = [0]

    def sample():
        status = f"/proc/{p.pid}/status"
        while p.poll() is None:
            try:
                for line in open(status):
                    if line.startswith("RssAnon:"):
                        peak[0] = max(peak[0], int(line.split()[1]) * 1024)
            except OSError:
                pass
            time.sleep(0.01)

    t = threading.Thread(target=sample) if sample_anon else None
    if t:
        t.start()
    out, err = p.communicate()
    if t:
        t.join()
    if p.returncode != 0:
        sys.exit(f"bench_device: {' '.join(map(str, args))}: exit {p.returncode}: {err.strip()}")
    return out, (peak[0] if sample_anon else None)


def fly(tree, path, mode, memory, cap, latency, tolerance, frames_out):
    args = [RELIEF, "mesh", "fly", tree, "--mode", mode, "--memory", memory, "--cold", "--path", path,
            "--no-render", "--pace", "40", "--tolerance", tolerance, "--json", "--quiet"]
    if cap:
        args += ["--cap", str(cap)]
    if latency is not None:
        args += ["--device-latency", str(latency)]
    out, _ = run(args)
    frames_out.write_text(out)
    s = json.loads(out)["summary"]
    return {
        "update_ms": s["update_ms"]["mean"],
        "miss_pct": s["miss_pct"],
        "triangles": s["triangles"]["mean"],
        "device_requests": s["device_requests"]["total"],
        "device_ms": s["device_ms"]["total"],
        "major_faults": s["major_faults"]["total"],
        "pages_read": s["pages_read"]["total"],
    }


def metanode(a):
    tree, path = Path(a.files[0]), Path(a.files[1])
    out = Path(a.out)
    out.mkdir(parents=True, exist_ok=True)
    size = tree.stat().st_size
    # S: the navigator's own anonymous memory, from an uncapped, device-free Virt flight.
    args = [RELIEF, "mesh", "fly", tree, "--mode", "virt", "--path", path, "--no-render", "--json", "--quiet",
            "--tolerance", a.tolerance]
    _, s_bytes = run(args, sample_anon=True)
    margin = int(a.margin_mb * 2**20)
    rows = []
    print(f"{tree.name}: {size / 1e6:.1f} MB, S = {s_bytes / 2**20:.1f} MiB, margin {a.margin_mb} MiB",
          file=sys.stderr)
    for num, den in FRACTIONS:
        b = size * num // den
        cap = b + s_bytes + margin
        for latency in LATENCIES:
            r = {"fraction": f"{num}/{den}", "budget": b, "cap": cap, "latency_ms": latency}
            for mode in ["virt", "ext"]:
                tag = f"{tree.stem}-{num}_{den}-{latency}-{mode}.json"
                r[mode] = fly(tree, path, mode, str(b), cap, latency, a.tolerance, out / tag)
            r["ext_over_virt_speed"] = r["virt"]["update_ms"] / max(r["ext"]["update_ms"], 1e-9)
            rows.append(r)
            print(f"  {num}/{den} {latency} ms: virt {r['virt']['update_ms']:.1f} ms, ext "
                  f"{r['ext']['update_ms']:.1f} ms ({r['ext']['miss_pct']:.1f}% misses)", file=sys.stderr)
    (out / f"{tree.stem}-metanode.json").write_text(json.dumps({"tree_bytes": size, "s_bytes": s_bytes,
                                                               "rows": rows}, indent=1))
    print(f"| memory | device ms | Virt ms | Virt faults | Ext ms | Ext miss % | Ext tris / Virt tris | "
          f"Ext requests | Virt / Ext |")
    print("|---|---:|---:|---:|---:|---:|---:|---:|---:|")
    for r in rows:
        v, e = r["virt"], r["ext"]
        print(f"| {r['fraction']} ({r['budget'] / 1e6:.1f} MB) | {r['latency_ms']} | {v['update_ms']:.1f} | "
              f"{v['major_faults']:.0f} | {e['update_ms']:.1f} | {e['miss_pct']:.1f} | "
              f"{e['triangles'] / max(v['triangles'], 1):.2f} | {e['device_requests']:.0f} | "
              f"{r['ext_over_virt_speed']:.2f} |")
    if a.plot:
        plot(rows, tree.stem, a.plot)


def plot(rows, name, png):
    try:
        import matplotlib
        matplotlib.use("Agg")
        import matplotlib.pyplot as plt
    except ImportError:
        print("bench_device: no matplotlib, no plot", file=sys.stderr)
        return
    fig, ax = plt.subplots(figsize=(7, 4.5))
    for num, den in FRACTIONS:
        f = f"{num}/{den}"
        pts = [(r["latency_ms"], r["ext_over_virt_speed"]) for r in rows if r["fraction"] == f]
        ax.plot([p[0] for p in pts], [p[1] for p in pts], marker="o", label=f"memory {f} of the tree")
    ax.axhline(1, color="grey", lw=0.8)
    ax.axhspan(4.4, 4.73, color="orange", alpha=0.2, label="El-Sana & Chiang, Table 2 (4.4–4.73×)")
    ax.set_xscale("log")
    ax.set_xlabel("emulated device latency per read request, ms")
    ax.set_ylabel("Ext speed / Virt speed (Virt ms ÷ Ext ms)")
    ax.set_title(f"{name}: meta-node trees, Ext against Virt")
    ax.legend()
    fig.tight_layout()
    fig.savefig(png, dpi=110)


def layouts(a):
    terrain, path = Path(a.files[0]), Path(a.files[1])
    out = Path(a.out)
    out.mkdir(parents=True, exist_ok=True)
    table = {}
    for latency in LATENCIES:
        args = [RELIEF, "layouts", terrain, "--path", path, "--memory", "1/16", "--tolerance", a.tolerance, "--os",
                "--json", "--quiet", "--device-latency", str(latency), "--cache-dir", out / "layouts-cache"]
        if a.cap:
            args += ["--os-cap", a.cap]
        text, _ = run(args)
        (out / f"{terrain.stem}-layouts-{latency}.json").write_text(text)
        for r in json.loads(text)["runs"]:
            table.setdefault(r["layout"], {})[latency] = (r["os"]["ms_per_frame_mean"], r["os"]["major_per_frame_mean"])
        print(f"  {latency} ms done", file=sys.stderr)
    print("| layout | major faults / frame | " + " | ".join(f"ms / frame at {l} ms" for l in LATENCIES) + " |")
    print("|---|---:|" + "---:|" * len(LATENCIES))
    for layout, by in table.items():
        faults = by[LATENCIES[0]][1]
        print(f"| {layout} | {faults:.1f} | " + " | ".join(f"{by[l][0]:.1f}" for l in LATENCIES) + " |")


def pages(a):
    *files, path = [Path(f) for f in a.files]
    out = Path(a.out)
    out.mkdir(parents=True, exist_ok=True)
    print("| page file | pages / frame | requests / frame | " +
          " | ".join(f"read ms / frame at {l} ms" for l in LATENCIES) + " |")
    print("|---|---:|---:|" + "---:|" * len(LATENCIES))
    for f in files:
        cells, pages_pf, req_pf = [], 0, 0
        for latency in LATENCIES:
            text, _ = run([RELIEF, "pages", "fly", f, "--cold-frames", "--path", path, "--no-render", "--json",
                           "--quiet", "--device-latency", str(latency)])
            (out / f"{f.stem}-pages-{latency}.json").write_text(text)
            s = json.loads(text)["summary"]
            cells.append(f"{s['read_ms']['mean']:.1f}")
            pages_pf, req_pf = s["pages_requested"]["mean"], s["device_requests"]["mean"]
        print(f"| {f.name} | {pages_pf:.1f} | {req_pf:.1f} | " + " | ".join(cells) + " |")


def main():
    p = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("what", choices=["metanode", "layouts", "pages"])
    p.add_argument("files", nargs="+")
    p.add_argument("--tolerance", default="8")
    p.add_argument("--margin-mb", type=float, default=4.0)
    p.add_argument("--cap", help="layouts: --os-cap BYTES")
    p.add_argument("--out", default="/work/bench/device")
    p.add_argument("--plot")
    a = p.parse_args()
    if os.geteuid() != 0:
        sys.exit("bench_device: the emulated device needs root (a FUSE mount)")
    {"metanode": metanode, "layouts": layouts, "pages": pages}[a.what](a)


if __name__ == "__main__":
    main()

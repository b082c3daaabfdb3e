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
        miss %, device requests. [--converge SECONDS] converges the first view before frame 0
        (and tabulates it); [--coalesce BYTES] [--io-threads N] [--prefetch P] set Ext's reads;
        [--ext-extra-mb M] gives Ext's pool B + M MiB under the same cap (equal memory: Virt's page
        cache may use the cap's margin).
    python3 tools/bench_device.py layouts TERRAIN.relief PATH.json [--cap BYTES]
        relief layouts --os under the device: per layout, cold refinement ms per frame next to
        its major faults.
    python3 tools/bench_device.py pages FILE.rpg... PATH.json
        relief pages fly --cold-frames under the device: the fetch's read ms per frame.
    python3 tools/bench_device.py plot TREE.rmn... --plot OUT.png
        Two panels from the saved flights of every tree: Virt's time over Ext's (frames after the
        cold first one) and Ext's triangles over Virt's (last ten frames), against latency.
    python3 tools/bench_device.py converged TREE.rmn... [--out DIR,DIR] [--ext-extra-mb M]
        From saved `metanode --converge` sweeps: each mode's convergence of the first view, its
        frames after, and Virt's whole flight (converge + frames) over Ext's.
    python3 tools/bench_device.py report TREE.rmn
        The metanode table again from the saved flights, split into the cold first frame and
        the frames after it (the steady state), with Ext's triangles against Virt's over the
        last ten frames (has Ext's pool caught up?).

Prints Markdown tables; raw JSON goes to --out (default /work/bench/device). With matplotlib
installed, `metanode` and `plot` draw Ext/Virt against latency (--plot OUT.png).
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


def fly(tree, path, mode, memory, cap, latency, tolerance, frames_out, a=None):
    args = [RELIEF, "mesh", "fly", tree, "--mode", mode, "--memory", memory, "--cold", "--path", path,
            "--no-render", "--pace", "40", "--tolerance", tolerance, "--json", "--quiet"]
    if cap:
        args += ["--cap", str(cap)]
    if latency is not None:
        args += ["--device-latency", str(latency)]
    if a is not None and a.converge:
        args += ["--converge", str(a.converge)]
    else:
        # mesh fly converges the first view by default (issue 23); the sweeps measure frame 0 as
        # the navigation's first update unless --converge is asked for.
        args += ["--no-converge"]
    if a is not None and mode == "ext":
        args += ["--coalesce", a.coalesce, "--io-threads", str(a.io_threads), "--prefetch", a.prefetch]
    out, _ = run(args)
    frames_out.write_text(out)
    s = json.loads(out)["summary"]
    c = s.get("converge") or {}
    return {
        "converge_ms": c.get("ms"),
        "converge_end": c.get("end"),
        "converge_triangles": c.get("triangles"),
        "converge_requests": c.get("device_requests"),
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
                memory = b + int(a.ext_extra_mb * 2**20) if mode == "ext" else b
                r[mode] = fly(tree, path, mode, str(memory), cap, latency, a.tolerance, out / tag, a)
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
    if a.converge:
        print()
        converged_table([tree], [out], a.ext_extra_mb)
    if a.plot:
        plot_all(a, [tree])


def layouts(a):
    terrain, path = Path(a.files[0]), Path(a.files[1])
    out = Path(a.out)
    out.mkdir(parents=True, exist_ok=True)
    table = {}
    for latency in LATENCIES:
        args = [RELIEF, "layouts", terrain, "--path", path, "--memory", a.memory, "--tolerance", a.tolerance, "--os",
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


def frames_of(path):
    return json.loads(Path(path).read_text())["frames"]


def report(a):
    tree = Path(a.files[0])
    out = Path(a.out)
    saved = json.loads((out / f"{tree.stem}-metanode.json").read_text())
    print("| memory | device ms | Virt first frame ms | Virt ms after | Virt faults after / frame | "
          "Ext ms after | Ext miss % | Ext tris / Virt tris (all, last 10) | Virt / Ext after |")
    print("|---|---:|---:|---:|---:|---:|---:|---:|---:|")
    for r in saved["rows"]:
        tag = f"{tree.stem}-{r['fraction'].replace('/', '_')}-{r['latency_ms']}"
        v, e = frames_of(out / f"{tag}-virt.json"), frames_of(out / f"{tag}-ext.json")
        after = lambda fr, k: sum(f[k] for f in fr[1:]) / max(len(fr) - 1, 1)
        tris = lambda fr, n: sum(f["triangles"] for f in fr[-n:])
        v_after, e_after = after(v, "update_ms"), after(e, "update_ms")
        print(f"| {r['fraction']} ({r['budget'] / 1e6:.1f} MB) | {r['latency_ms']} | {v[0]['update_ms']:.0f} | "
              f"{v_after:.1f} | {after(v, 'major_faults'):.1f} | {e_after:.2f} | {r['ext']['miss_pct']:.1f} | "
              f"{tris(e, len(e)) / max(tris(v, len(v)), 1):.2f}, {tris(e, 10) / max(tris(v, 10), 1):.2f} | "
              f"{v_after / max(e_after, 1e-9):.1f} |")


def converged(a):
    """The converged-first-view table from saved `metanode --converge` sweeps (several --out
    directories, comma-separated, are merged: e.g. fast and slow latencies run apart)."""
    converged_table([Path(f) for f in a.files], [Path(d) for d in a.out.split(",")], a.ext_extra_mb)


def frame_ms(doc):
    """Per frame: its update and, where its camera jumped (the flight converged before it,
    `summary.jumps`), that convergence: the time the frame took."""
    jumps = {j["frame"]: j["convergence"]["ms"] for j in doc["summary"].get("jumps") or []}
    return [(f["update_ms"] or 0.0) + jumps.get(f["frame"], 0.0) for f in doc["frames"]]


def converged_table(trees, outs, ext_extra_mb):
    print("| tree | memory (Ext pool) | device ms | Virt converge s | Ext converge s (end) | "
          "Ext / Virt converged triangles | jumps | Virt ms / frame | Ext ms / frame | Ext miss % | "
          "Ext / Virt triangles | Virt / Ext per frame | Virt / Ext flight |")
    print("|---|---|---:|---:|---:|---:|---:|---:|---:|---:|---:|---:|---:|")
    for tree in trees:
        rows = []
        for d in outs:
            saved = d / f"{tree.stem}-metanode.json"
            if saved.exists():
                rows += [(d, r) for r in json.loads(saved.read_text())["rows"]]
        order = {f"{n}/{d}": i for i, (n, d) in enumerate([(1, 2), (1, 4), (1, 8)])}
        rows.sort(key=lambda dr: (order.get(dr[1]["fraction"], 9), dr[1]["latency_ms"]))
        for d, r in rows:
            v, e = r["virt"], r["ext"]
            if v.get("converge_ms") is None or e.get("converge_ms") is None:
                continue
            tag = f"{tree.stem}-{r['fraction'].replace('/', '_')}-{r['latency_ms']}"
            docs = {m: json.loads((d / f"{tag}-{m}.json").read_text()) for m in ["virt", "ext"]}
            # Frames whose camera jumped were converged first: their time counts (frame_ms).
            ms = {m: frame_ms(doc) for m, doc in docs.items()}
            per = {m: sum(x) / max(len(x), 1) for m, x in ms.items()}
            jumps = len(docs["virt"]["summary"].get("jumps") or [])
            flight = {m: docs[m]["summary"]["converge"]["ms"] + sum(ms[m]) for m in ms}
            pool = r["budget"] + int(ext_extra_mb * 2**20)
            print(f"| {tree.stem} | {r['fraction']} ({pool / 1e6:.1f} MB) | {r['latency_ms']:g} | "
                  f"{v['converge_ms'] / 1e3:.2f} | {e['converge_ms'] / 1e3:.2f} ({e['converge_end']}) | "
                  f"{e['converge_triangles'] / max(v['converge_triangles'], 1):.2f} | {jumps} | {per['virt']:.1f} | "
                  f"{per['ext']:.2f} | {e['miss_pct']:.1f} | {e['triangles'] / max(v['triangles'], 1):.2f} | "
                  f"{per['virt'] / max(per['ext'], 1e-9):.1f} | {flight['virt'] / max(flight['ext'], 1e-9):.2f} |")


def plot_all(a, trees=None):
    import matplotlib
    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
    out = Path(a.out)
    fig, (speed, quality) = plt.subplots(1, 2, figsize=(12, 4.8))
    styles = {"1/2": "-", "1/4": "--", "1/8": ":"}
    for n, f in enumerate(trees or a.files):
        tree = Path(f)
        saved = json.loads((out / f"{tree.stem}-metanode.json").read_text())
        colour = f"C{n}"
        for fraction, style in styles.items():
            xs, sp, q = [], [], []
            for r in saved["rows"]:
                if r["fraction"] != fraction:
                    continue
                tag = f"{tree.stem}-{fraction.replace('/', '_')}-{r['latency_ms']}"
                vd, ed = (json.loads((out / f"{tag}-{m}.json").read_text()) for m in ["virt", "ext"])
                v, e = vd["frames"], ed["frames"]
                # After frame 0; a frame whose camera jumped counts its convergence (frame_ms).
                after = lambda doc: sum(frame_ms(doc)[1:]) / max(len(doc["frames"]) - 1, 1)
                xs.append(r["latency_ms"])
                sp.append(after(vd) / max(after(ed), 1e-9))
                q.append(sum(x["triangles"] for x in e[-10:]) / max(sum(x["triangles"] for x in v[-10:]), 1))
            label = f"{tree.stem}, memory {fraction} of the tree"
            speed.plot(xs, sp, style, color=colour, marker="o", label=label)
            quality.plot(xs, q, style, color=colour, marker="o", label=label)
    speed.axhspan(4.4, 4.73, color="orange", alpha=0.3, label="El-Sana & Chiang, Table 2")
    speed.axhline(1, color="grey", lw=0.8)
    for ax in (speed, quality):
        ax.set_xscale("log")
        ax.set_xlabel("emulated device latency per read request, ms (queue depth 1)")
    speed.set_yscale("log")
    speed.set_ylabel("Virt ms / Ext ms per frame (after the cold first frame)")
    speed.set_title("Ext's speed-up over Virt")
    quality.set_ylabel("Ext triangles / Virt triangles (last 10 frames)")
    quality.set_ylim(0, 1.05)
    quality.set_title("what Ext draws meanwhile")
    quality.legend(fontsize=7, loc="lower left")
    speed.legend(fontsize=7, loc="upper left")
    fig.tight_layout()
    fig.savefig(a.plot, dpi=100)


def main():
    p = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("what", choices=["metanode", "layouts", "pages", "report", "plot", "converged"])
    p.add_argument("files", nargs="+")
    p.add_argument("--tolerance", default="8")
    p.add_argument("--margin-mb", type=float, default=4.0)
    p.add_argument("--cap", help="layouts: --os-cap BYTES")
    p.add_argument("--memory", default="1/16", help="layouts: the model's --memory")
    p.add_argument("--out", default="/work/bench/device")
    p.add_argument("--plot")
    p.add_argument("--latencies", help="comma-separated ms (default 0.02,0.1,1,8,30)")
    p.add_argument("--fractions", help="metanode: comma-separated budgets as fractions of the tree (default 1/2,1/4,1/8)")
    p.add_argument("--converge", type=float, help="metanode: converge the first view for at most SECONDS before frame 0")
    p.add_argument("--coalesce", default="0", help="metanode: Ext's --coalesce BYTES")
    p.add_argument("--io-threads", type=int, default=1, help="metanode: Ext's --io-threads N")
    p.add_argument("--prefetch", default="frontier", help="metanode: Ext's --prefetch paper|parent|frontier")
    p.add_argument("--ext-extra-mb", type=float, default=0.0,
                   help="metanode: Ext's pool is B + this many MiB (Virt's page cache may use the cap's margin)")
    a = p.parse_args()
    if a.fractions:
        FRACTIONS[:] = [tuple(int(x) for x in f.split("/")) for f in a.fractions.split(",")]
    if a.latencies:
        LATENCIES[:] = [float(x) for x in a.latencies.split(",")]
    if a.what == "report":
        return report(a)
    if a.what == "plot":
        return plot_all(a)
    if a.what == "converged":
        return converged(a)
    if os.geteuid() != 0:
        sys.exit("bench_device: the emulated device needs root (a FUSE mount)")
    {"metanode": metanode, "layouts": layouts, "pages": pages}[a.what](a)


if __name__ == "__main__":
    main()

#!/usr/bin/env python3
"""Sharded `relief convert` on Dask: plans N shards, runs `relief convert --shard I/N` as Dask
tasks (retried when they fail), then `relief convert --merge` into a file or an s3:// object.

    python3 tools/dask_convert.py DEM... --out OUT [--shards N] [--workers W | --scheduler ADDR]

Without --scheduler a LocalCluster of --workers single-threaded workers runs on this machine
(its dashboard address is printed). With --scheduler tcp://HOST:8786 the tasks run on that
cluster; every worker then needs the `relief` binary (--relief) and the inputs at the same
paths, and --work-dir must be a directory all workers and this machine share (shard files are
written there). OUT may be s3://bucket/key: the merge uploads it in parts to the endpoint of
AWS_ENDPOINT_URL_S3 (AWS itself when unset), signed with AWS_ACCESS_KEY_ID/_SECRET_ACCESS_KEY.

--json prints per-shard figures (seconds, vertices/s, peak anonymous memory) and the merge's.
"""
import argparse
import json
import os
import shutil
import subprocess
import sys
import tempfile
import time


def run_shard(relief, inputs, layout, shard, shards, out, threads):
    """One Dask task: a shard's conversion in its own process; raises on failure (Dask retries)."""
    cmd = [relief, "convert", "--quiet", "--json", "--layout", layout, "--threads", str(threads),
           *inputs, out, "--shard", f"{shard}/{shards}"]
    started = time.time()
    p = subprocess.run(cmd, capture_output=True, text=True)
    if p.returncode != 0:
        raise RuntimeError(f"shard {shard}/{shards}: {p.stderr.strip() or 'exit ' + str(p.returncode)}")
    report = json.loads(p.stdout)
    report["wall_seconds"] = time.time() - started
    return report


def run_merge(relief, files, out):
    p = subprocess.run([relief, "convert", "--quiet", "--json", "--merge", *files, out], capture_output=True, text=True)
    if p.returncode != 0:
        raise RuntimeError(f"merge: {p.stderr.strip()}")
    return json.loads(p.stdout)


def main():
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("inputs", nargs="+", help="DEM files or directories of tiles (one mosaic)")
    ap.add_argument("--out", required=True, help="terrain file to write, or s3://bucket/key")
    ap.add_argument("--shards", type=int, default=4)
    ap.add_argument("--workers", type=int, default=2, help="LocalCluster workers (without --scheduler)")
    ap.add_argument("--threads", type=int, default=1, help="threads per shard process")
    ap.add_argument("--scheduler", help="address of a running Dask scheduler")
    ap.add_argument("--layout", default="interleaved")
    ap.add_argument("--relief", default=shutil.which("relief") or "target/release/relief")
    ap.add_argument("--work-dir", help="shared directory for shard files (default: a temporary one)")
    ap.add_argument("--retries", type=int, default=2)
    ap.add_argument("--json", action="store_true")
    a = ap.parse_args()
    if a.shards < 1:
        sys.exit("dask_convert: --shards must be at least 1")
    try:
        from dask.distributed import Client, LocalCluster, progress
    except ImportError:
        sys.exit("dask_convert: needs dask.distributed (pip install 'dask[distributed]')")
    relief = os.path.abspath(a.relief)
    inputs = [os.path.abspath(i) for i in a.inputs]
    work = a.work_dir or tempfile.mkdtemp(prefix="relief-shards-")
    os.makedirs(work, exist_ok=True)
    cluster = None
    if a.scheduler:
        client = Client(a.scheduler)
    else:
        cluster = LocalCluster(n_workers=a.workers, threads_per_worker=1, processes=True,
                               dashboard_address=":0", silence_logs=40)
        client = Client(cluster)
    print(f"dask_convert: {a.shards} shards on {len(client.scheduler_info()['workers'])} workers; "
          f"dashboard {client.dashboard_link}", file=sys.stderr)
    started = time.time()
    files = [os.path.join(work, f"shard_{i}_of_{a.shards}.shard") for i in range(a.shards)]
    futures = [client.submit(run_shard, relief, inputs, a.layout, i, a.shards, files[i], a.threads,
                             key=f"relief-shard-{i}-of-{a.shards}", retries=a.retries, pure=False)
               for i in range(a.shards)]
    if sys.stderr.isatty() and not a.json:
        progress(futures)
    try:
        reports = client.gather(futures)
    except Exception as e:  # the task's own message, after its retries
        sys.exit(f"dask_convert: {e}")
    shard_seconds = time.time() - started
    merge = client.submit(run_merge, relief, files, a.out, pure=False, retries=a.retries)
    try:
        merged = merge.result()
    except Exception as e:
        sys.exit(f"dask_convert: {e}")
    total = time.time() - started
    client.close()
    if cluster:
        cluster.close()
    if not a.work_dir:
        shutil.rmtree(work, ignore_errors=True)
    vertices = sum(r["vertices"] for r in reports) + merged["coarse_vertices"]
    summary = {
        "shards": a.shards, "workers": a.workers if not a.scheduler else None, "seconds": total,
        "shard_seconds": shard_seconds, "merge_seconds": merged["seconds"],
        "vertices": vertices, "vertices_per_s": vertices / total,
        "peak_rss_anon_bytes_per_shard": max(r["peak_rss_anon_bytes"] for r in reports),
        "merge_peak_rss_anon_bytes": merged["peak_rss_anon_bytes"],
        "shard_reports": reports, "merge": merged,
    }
    if a.json:
        print(json.dumps(summary, indent=1))
    else:
        print(f"{a.out}: {vertices} vertices in {total:.2f} s ({vertices / total / 1e6:.1f} M vertices/s), "
              f"{a.shards} shards, merge {merged['seconds']:.2f} s")


if __name__ == "__main__":
    main()

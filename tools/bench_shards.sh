#!/usr/bin/env bash
# Issue 46 benchmark: single process --threads 1|2 vs tools/dask_convert.py on 2 workers, on a SYNTHETIC 4097 grid
# (run where synthetic_4097.tif is: target/release/relief-synth synthetic_4097.tif --size 4097).
R=${RELIEF:-target/release/relief}; T=$(dirname "$0")
for run in 1 2 3; do
  for t in 1 2; do $R convert --quiet --json --threads $t synthetic_4097.tif t$t.relief | python3 -c "import json,sys; d=json.load(sys.stdin); print('threads$t', round(d['seconds'],3), round(d['vertices_per_s']/1e6,2), d['peak_rss_anon_bytes']>>20)"; done
  python3 $T/dask_convert.py --relief $R synthetic_4097.tif --out dask.relief --shards 4 --workers 2 --json 2>/dev/null | python3 -c "import json,sys; d=json.load(sys.stdin); print('dask2x4', round(d['seconds'],3), round(d['vertices_per_s']/1e6,2), d['peak_rss_anon_bytes_per_shard']>>20, round(d['merge_seconds'],3), round(d['shard_seconds'],3), [round(r['seconds'],3) for r in d['shard_reports']])"
  python3 $T/dask_convert.py --relief $R synthetic_4097.tif --out dask16.relief --shards 16 --workers 2 --json 2>/dev/null | python3 -c "import json,sys; d=json.load(sys.stdin); print('dask2x16', round(d['seconds'],3), round(d['vertices_per_s']/1e6,2), d['peak_rss_anon_bytes_per_shard']>>20, round(d['merge_seconds'],3), round(d['shard_seconds'],3), round(sum(r['seconds'] for r in d['shard_reports']),3), sum(r['vertices'] for r in d['shard_reports']))"
done
cmp dask.relief t1.relief && cmp dask16.relief t2.relief && echo IDENT

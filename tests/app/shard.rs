//! Sharded conversion end to end: `relief convert --shard I/N` then `--merge` gives the file one
//! process writes, byte for byte, on a real mosaic and a SYNTHETIC grid no shard holds whole; a
//! shard killed mid-way is rerun; bad shard sets are one-line errors that write nothing.

use crate::common::{dem, fails_with, relief, stderr_of};
use std::ffi::OsStr;
use std::path::{Path, PathBuf};
use std::process::Command;

const LAYOUTS: [&str; 5] = ["interleaved", "hz", "row-major", "tiled", "embedded"];

fn run_ok(cmd: &mut Command) -> String {
    let o = cmd.output().unwrap();
    assert!(o.status.success(), "{cmd:?}: {}", stderr_of(&o));
    String::from_utf8(o.stdout).unwrap()
}

/// Converts `inputs` in `n` shards into `dir`, returning the shard files and their reports.
fn shards(inputs: &[PathBuf], layout: &str, n: u32, dir: &Path) -> (Vec<PathBuf>, Vec<serde_json::Value>) {
    let (mut files, mut reports) = (Vec::new(), Vec::new());
    for i in 0..n {
        let out = dir.join(format!("{layout}_{i}_of_{n}.shard"));
        let json = run_ok(
            relief()
                .args(["convert", "--quiet", "--json", "--layout", layout])
                .args(inputs)
                .arg(&out)
                .args(["--shard", &format!("{i}/{n}")]),
        );
        reports.push(serde_json::from_str(&json).unwrap());
        files.push(out);
    }
    (files, reports)
}

fn merge(files: &[PathBuf], out: &Path) {
    run_ok(relief().args(["convert", "--quiet", "--merge"]).args(files).arg(out));
}

fn single(inputs: &[PathBuf], layout: &str, out: &Path) {
    run_ok(relief().args(["convert", "--quiet", "--layout", layout]).args(inputs).arg(out));
}

/// ETOPO (real, 1081 × 540) cut into 3 × 2 georeferenced tiles sharing their edge posts.
fn etopo_tiles(dir: &Path) -> Vec<PathBuf> {
    let src = dem("etopo20_world.tif");
    let mut tiles = Vec::new();
    for r in 0..2 {
        for c in 0..3 {
            let (x, y) = (360 * c, 270 * r);
            let (w, h) = (361.min(1081 - x), 271.min(540 - y));
            let win = [x, y, w, h].map(|v| v.to_string());
            let out = dir.join(format!("tile_{r}_{c}.tif"));
            let o = Command::new("gdal_translate")
                .args(["-q", "-srcwin", &win[0], &win[1], &win[2], &win[3]])
                .arg(&src)
                .arg(&out)
                .output()
                .expect("Debian's gdal-bin");
            assert!(o.status.success(), "{}", stderr_of(&o));
            tiles.push(out);
        }
    }
    tiles
}

#[test]
fn shards_of_a_real_mosaic_merge_to_the_single_process_file_in_every_layout() {
    let dir = tempfile::tempdir().unwrap();
    let tiles = etopo_tiles(dir.path());
    for layout in LAYOUTS {
        let want = dir.path().join(format!("{layout}.relief"));
        single(&tiles, layout, &want);
        let want = std::fs::read(&want).unwrap();
        for n in [1, 4, 16] {
            let (files, reports) = shards(&tiles, layout, n, dir.path());
            // Every shard did a share of the work (balanced to within a factor of 3 at 16).
            let v: Vec<u64> = reports.iter().map(|r| r["vertices"].as_u64().unwrap()).collect();
            let (lo, hi) = (*v.iter().min().unwrap(), *v.iter().max().unwrap());
            assert!(lo > 0 && hi <= 3 * lo, "{layout} {n}: {v:?}");
            let got = dir.path().join(format!("{layout}_{n}.relief"));
            // Shards in any order.
            let mut files = files;
            files.reverse();
            merge(&files, &got);
            assert!(std::fs::read(&got).unwrap() == want, "{layout}, {n} shards: not the single-process bytes");
            for f in files {
                std::fs::remove_file(f).unwrap();
            }
        }
    }
}

#[test]
fn shards_of_a_synthetic_grid_none_holds_whole_merge_to_the_single_process_file() {
    let dir = tempfile::tempdir().unwrap();
    let synthetic = dir.path().join("synthetic_2049.tif");
    run_ok(Command::new(env!("CARGO_BIN_EXE_relief-synth")).arg(&synthetic).args(["--size", "2049", "--seed", "46"]));
    let inputs = [synthetic];
    let want = dir.path().join("single.relief");
    single(&inputs, "interleaved", &want);
    for n in [4, 16] {
        let (files, reports) = shards(&inputs, "interleaved", n, dir.path());
        for r in &reports {
            let (held, all) = (r["window_posts"].as_u64().unwrap(), r["dem_posts"].as_u64().unwrap());
            // A shard holds its blocks and their reach: well under the whole grid.
            assert!(held * n as u64 <= all * 2 && held < all, "{n} shards: {r}");
        }
        let got = dir.path().join(format!("merged_{n}.relief"));
        merge(&files, &got);
        assert!(std::fs::read(&got).unwrap() == std::fs::read(&want).unwrap(), "{n} shards");
    }
}

#[test]
fn a_shard_killed_mid_way_is_rerun_and_the_merge_is_unchanged() {
    let dir = tempfile::tempdir().unwrap();
    let input = [dem("zurich_25m_i16.tif")];
    let want = dir.path().join("single.relief");
    single(&input, "interleaved", &want);
    let (files, _) = shards(&input, "interleaved", 4, dir.path());
    std::fs::remove_file(&files[2]).unwrap();
    // Killed after its first batch of blocks: no shard file.
    let o = relief()
        .env("RELIEF_TEST_KILL_SHARD_AFTER", "1")
        .args(["convert", "--quiet", "--threads", "1"])
        .args(&input)
        .arg(&files[2])
        .args(["--shard", "2/4"])
        .output()
        .unwrap();
    assert!(!o.status.success());
    assert!(!files[2].exists());
    let out = dir.path().join("merged.relief");
    let mut args: Vec<&OsStr> = vec!["convert".as_ref(), "--merge".as_ref()];
    args.extend(files.iter().filter(|f| f.exists()).map(|f| f.as_os_str()));
    args.push(out.as_os_str());
    fails_with(&args, "shard 2/4 is missing");
    assert!(!out.exists());
    // The rerun: the same file as before.
    run_ok(relief().args(["convert", "--quiet"]).args(&input).arg(&files[2]).args(["--shard", "2/4"]));
    merge(&files, &out);
    assert!(std::fs::read(&out).unwrap() == std::fs::read(&want).unwrap());
}

#[test]
fn wrong_shards_are_one_line_errors_and_write_nothing() {
    let dir = tempfile::tempdir().unwrap();
    let input = [dem("zurich_25m_i16.tif")];
    let (files, _) = shards(&input, "interleaved", 4, dir.path());
    let (other, _) = shards(&input, "hz", 4, dir.path());
    let out = dir.path().join("out.relief");
    let merge_of = |set: &[&Path], needle: &str| {
        let mut args: Vec<&OsStr> = vec!["convert".as_ref(), "--merge".as_ref()];
        args.extend(set.iter().map(|f| f.as_os_str()));
        args.push(out.as_os_str());
        fails_with(&args, needle);
        assert!(!out.exists(), "{needle}: output left");
    };
    let f: Vec<&Path> = files.iter().map(|p| p.as_path()).collect();
    // Another conversion's shard (another layout), named.
    merge_of(&[f[0], f[1], other[2].as_path(), f[3]], "hz_2_of_4.shard: a shard of another conversion");
    // Twice the same shard.
    merge_of(&[f[0], f[1], f[1], f[3]], "are both shard 1/4");
    // Damaged: one byte of its records flipped.
    let damaged = dir.path().join("damaged.shard");
    let mut bytes = std::fs::read(f[3]).unwrap();
    bytes[600] ^= 0x40;
    std::fs::write(&damaged, bytes).unwrap();
    merge_of(&[f[0], f[1], f[2], &damaged], "damaged.shard");
    // Not a shard at all.
    let terrain = dir.path().join("t.relief");
    single(&input, "interleaved", &terrain);
    merge_of(&[f[0], f[1], f[2], &terrain], "t.relief");
    // Bad --shard values, and a DEM with nodata posts.
    let shard = dir.path().join("x.shard");
    for spec in ["4/4", "1", "a/b", "0/0"] {
        let mut args: Vec<&OsStr> = vec!["convert".as_ref(), input[0].as_os_str(), shard.as_os_str()];
        args.extend(["--shard".as_ref(), OsStr::new(spec)]);
        fails_with(&args, "--shard: expected I/N");
    }
    let hugo = dem("hugo_site_nodata.asc");
    let args: Vec<&OsStr> =
        vec!["convert".as_ref(), hugo.as_os_str(), shard.as_os_str(), "--shard".as_ref(), "0/1".as_ref()];
    fails_with(&args, "sharded conversion needs a DEM without nodata");
    assert!(!shard.exists());
}

#[test]
fn the_dask_driver_converts_a_mosaic_into_the_test_bucket_and_fly_reads_it_there() {
    use relief::pager::serve::{ServeOptions, Server};
    let dir = tempfile::tempdir().unwrap();
    let tiles = etopo_tiles(dir.path());
    let want = dir.path().join("single.relief");
    single(&tiles, "interleaved", &want);
    let bucket = dir.path().join("bucket");
    std::fs::create_dir(&bucket).unwrap();
    let options = ServeOptions { uploads: Some(bucket.clone()), ..Default::default() };
    let server = Server::start(vec![], "127.0.0.1:0".parse().unwrap(), options).unwrap();
    let endpoint = server.url("").trim_end_matches('/').to_string();
    let python = std::env::var("RELIEF_PYTHON").unwrap_or_else(|_| "python3".into());
    let driver = Path::new(env!("CARGO_MANIFEST_DIR")).join("tools/dask_convert.py");
    let o = Command::new(&python)
        .arg(&driver)
        .args(&tiles)
        .args(["--out", "s3://dem/etopo.relief", "--shards", "4", "--workers", "2", "--json", "--relief"])
        .arg(env!("CARGO_BIN_EXE_relief"))
        .env("AWS_ENDPOINT_URL_S3", &endpoint)
        .output()
        .unwrap();
    assert!(o.status.success(), "{}", stderr_of(&o));
    let summary: serde_json::Value = serde_json::from_slice(&o.stdout).unwrap();
    assert_eq!(summary["shard_reports"].as_array().unwrap().len(), 4, "{summary}");
    // Assembled in the bucket by a multipart upload: the single-process bytes.
    assert!(std::fs::read(bucket.join("dem/etopo.relief")).unwrap() == std::fs::read(&want).unwrap());
    assert!(!bucket.join(".uploads").read_dir().unwrap().any(|_| true), "parts left behind");
    // `relief fly` reads it from the bucket and ends on the local strip.
    let path = dir.path().join("path.json");
    crate::common::make_path("flyover", &want, 20, &path);
    let fly = |target: &str| -> serde_json::Value {
        let json = run_ok(
            relief()
                .env("AWS_ENDPOINT_URL_S3", &endpoint)
                .env("RELIEF_CACHE_DIR", dir.path().join("cache"))
                .args(["fly", target, "--no-render", "--tolerance", "2", "--json", "--path"])
                .arg(&path),
        );
        serde_json::from_str(&json).unwrap()
    };
    let (here, there) = (fly(want.to_str().unwrap()), fly("s3://dem/etopo.relief"));
    assert_eq!(there["summary"]["final_digest"], here["summary"]["final_digest"]);
    assert!(server.log().iter().any(|l| l.name == "dem/etopo.relief" && l.method == "GET"));
}

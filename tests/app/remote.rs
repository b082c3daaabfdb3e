//! The terrain commands over a terrain file served on loopback (relief's own range server, with
//! injected latency): a headless flight never waits and ends on the local file's strip, `info`
//! and the page-fault experiment read it like the local file.

use std::path::{Path, PathBuf};
use std::process::Command;
use std::time::Duration;

use relief::layout::LayoutKind;
use relief::pager::serve::{ServeOptions, Server};
use relief::preprocess::convert::{convert, ConvertOptions};

use crate::common;

fn zurich(dir: &Path) -> PathBuf {
    let out = dir.join("zurich.relief");
    convert(&common::dem("zurich_25m_i16.tif"), &out, &ConvertOptions::new(LayoutKind::Interleaved)).unwrap();
    out
}

fn serve(file: &Path, latency_ms: u64) -> Server {
    let options = ServeOptions { latency: Duration::from_millis(latency_ms), ..Default::default() };
    Server::start(vec![("zurich.relief".into(), file.to_path_buf())], "127.0.0.1:0".parse().unwrap(), options).unwrap()
}

/// relief with its remote cache in `dir` (never the user's).
fn relief(dir: &Path) -> Command {
    let mut c = common::relief();
    c.env("RELIEF_CACHE_DIR", dir.join("cache"));
    c
}

fn json_of(c: &mut Command) -> serde_json::Value {
    let o = c.output().unwrap();
    assert!(o.status.success(), "{}", common::stderr_of(&o));
    serde_json::from_slice(&o.stdout).unwrap()
}

#[test]
fn a_headless_flight_over_a_served_terrain_never_waits_and_ends_on_the_local_strip() {
    let dir = tempfile::tempdir().unwrap();
    let local = zurich(dir.path());
    let server = serve(&local, 20);
    let path = dir.path().join("path.json");
    common::make_path("flyover", &local, 40, &path);
    // The fly-over's middle view, held for 40 frames: how many round trips the first complete
    // frame waits for then depends on the data alone, not on how far the camera got meanwhile.
    let flyover: serde_json::Value = serde_json::from_slice(&std::fs::read(&path).unwrap()).unwrap();
    let held = serde_json::Value::Array(vec![flyover[20].clone(); 40]);
    std::fs::write(&path, serde_json::to_vec(&held).unwrap()).unwrap();
    let fly = |target: &str| {
        json_of(
            relief(dir.path())
                .args(["fly", target, "--no-render", "--tolerance", "2", "--pace", "5", "--json"])
                .arg("--path")
                .arg(&path),
        )
    };
    let here = fly(local.to_str().unwrap());
    let there = fly(&server.url("zurich.relief"));
    let (h, t) = (&here["summary"], &there["summary"]);
    assert_eq!(t["final_digest"], h["final_digest"], "the final strip is the local one");
    assert_eq!(t["final_triangles"], h["final_triangles"]);
    assert!(h["settle_updates"].is_null() && t["settle_updates"].as_u64().unwrap() >= 1);
    assert_eq!(h["requests"], 0);
    // At least one request after the opening one (the file, 2.3 MB without its padding, is barely
    // larger than the opening range).
    assert!(t["requests"].as_u64().unwrap() >= 1 && t["net_bytes"].as_u64().unwrap() > 1 << 20, "{t}");
    // The first frame is drawn from the opening request alone: it did not wait.
    let first = &there["frames"][0];
    assert_eq!((first["coarse"].as_bool(), first["round_trips"].as_u64()), (Some(true), Some(1)), "{first}");
    assert!(t["coarse_frames"].as_u64().unwrap() >= 1);
    let rounds = t["first_complete_round_trips"].as_u64().expect("a complete frame during the flight");
    assert!((2..=6).contains(&rounds), "{t}");
}

#[test]
fn info_and_the_fault_experiment_read_a_served_terrain_like_the_local_file() {
    let dir = tempfile::tempdir().unwrap();
    let local = zurich(dir.path());
    let server = serve(&local, 0);
    let url = server.url("zurich.relief");
    let mut here = json_of(relief(dir.path()).args(["info", "--json"]).arg(&local));
    let mut there = json_of(relief(dir.path()).args(["info", "--json", &url]));
    for v in [&mut here, &mut there] {
        v.as_object_mut().unwrap().remove("file");
    }
    assert_eq!(here, there);
    let path = dir.path().join("path.json");
    common::make_path("flyover", &local, 8, &path);
    let layouts = |input: &str, cache: &str| {
        let mut c = relief(dir.path());
        c.args(["layouts", input, "--memory", "1/16", "--layouts", "interleaved,row-major", "--quiet", "--json"])
            .arg("--path")
            .arg(&path)
            .arg("--cache-dir")
            .arg(dir.path().join(cache));
        json_of(&mut c)
    };
    let (mut a, mut b) = (layouts(local.to_str().unwrap(), "a"), layouts(&url, "b"));
    for runs in [&mut a["runs"], &mut b["runs"]] {
        for run in runs.as_array_mut().unwrap() {
            // Timing is the one figure that may differ.
            run.as_object_mut().unwrap().remove("update_ms_per_frame");
        }
    }
    assert_eq!(a["runs"], b["runs"], "the same faults from the served file (laid out locally)");
}

//! A large terrain end to end (issue 8): a SYNTHETIC 16385² DEM generated, converted, flown over
//! headless and rendered, then flown again under a cgroup memory cap of about a third of the
//! file. Minutes and ~7 GB of disk, so not part of CI:
//!
//!     cargo test --test large_terrain -- --ignored --nocapture
//!
//! Figures from a run are in BENCHMARKS.md ("Hardening").

mod common;

use std::path::Path;
use std::process::Command;
use std::time::Instant;

fn run(cmd: &mut Command) -> (std::process::Output, f64) {
    let t0 = Instant::now();
    let o = cmd.output().unwrap();
    (o, t0.elapsed().as_secs_f64())
}

fn drop_cache(path: &Path) {
    relief::pager::drop_from_page_cache(path).unwrap();
}

#[test]
#[ignore = "minutes and ~7 GB of disk: cargo test --test large_terrain -- --ignored"]
fn a_16385_square_synthetic_terrain_converts_flies_and_renders_under_a_memory_cap() {
    let dir = tempfile::tempdir_in(env!("CARGO_TARGET_TMPDIR")).unwrap();
    let d = dir.path();
    let dem = d.join("synthetic_16385.tif");
    let (o, s) =
        run(Command::new(env!("CARGO_BIN_EXE_relief-synth")).arg(&dem).args(["--size", "16385", "--seed", "1"]));
    assert!(o.status.success(), "{}", common::stderr_of(&o));
    eprintln!("generated in {s:.1} s");
    let terrain = d.join("s16k.relief");
    let (o, s) = run(common::relief().arg("convert").arg(&dem).arg(&terrain).args(["--quiet", "--json"]));
    assert!(o.status.success(), "{}", common::stderr_of(&o));
    let report: serde_json::Value = serde_json::from_slice(&o.stdout).unwrap();
    eprintln!("converted in {s:.1} s: {report}");
    std::fs::remove_file(&dem).unwrap();
    let file_bytes = std::fs::metadata(&terrain).unwrap().len();
    let path = d.join("fly.json");
    let (o, _) = run(common::relief()
        .args(["path", "flyover"])
        .arg(&terrain)
        .args(["--frames", "300", "--clearance", "100", "--out"])
        .arg(&path));
    assert!(o.status.success(), "{}", common::stderr_of(&o));
    let fly = |cap: Option<u64>| {
        drop_cache(&terrain);
        let mut c = match cap {
            Some(bytes) => {
                let mut c = Command::new(Path::new(env!("CARGO_MANIFEST_DIR")).join("../shared/tools/memlimit.sh"));
                c.arg(format!("{}M", bytes >> 20)).arg(env!("CARGO_BIN_EXE_relief"));
                c.env("XDG_RUNTIME_DIR", std::env::var_os("XDG_RUNTIME_DIR").unwrap_or_default());
                c
            }
            None => common::relief(),
        };
        c.arg("fly")
            .arg(&terrain)
            .arg("--path")
            .arg(&path)
            .args(["--width", "640", "--height", "360", "--quiet", "--json"]);
        let (o, s) = run(&mut c);
        assert!(o.status.success(), "cap {cap:?}: {}", common::stderr_of(&o));
        let r: serde_json::Value = serde_json::from_slice(&o.stdout).unwrap();
        assert_eq!(r["frames"], 300);
        assert!(r["triangles_mean"].as_f64().unwrap() > 100.0, "{r}");
        eprintln!("fly (cap {cap:?}) {s:.1} s: {r}");
        s
    };
    let free = fly(None);
    // A third of the file (the heights texture, about a fifth of it, must stay resident).
    let capped = fly(Some(file_bytes / 3));
    eprintln!("capped / free wall time: {:.2}", capped / free);
}

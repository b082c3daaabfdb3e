//! The command line as a user meets it: every `--json` output is strict JSON (no key twice),
//! negative numbers are taken where they mean something, outputs are checked before the work
//! starts, new files get the umask's mode, SIGTERM cleans up `mesh build` as Ctrl-C does, and
//! errors keep their whole cause on one line.

use crate::common;

use std::path::{Path, PathBuf};
use std::process::Output;

use crate::json::strict;
use common::{dem, mesh, relief, stderr_of};

fn ok(o: Output, what: &str) -> Output {
    assert!(o.status.success(), "{what}: {}", stderr_of(&o));
    o
}

/// One line on stderr, exit status 1, no panic; returns the line.
fn fails(o: Output, what: &str) -> String {
    let e = stderr_of(&o);
    assert_eq!(o.status.code(), Some(1), "{what}: {e}");
    assert_eq!(e.trim_end().lines().count(), 1, "{what}: {e}");
    assert!(!e.contains("panicked"), "{what}: {e}");
    e
}

fn run(args: &[&std::ffi::OsStr]) -> Output {
    relief().args(args).output().unwrap()
}

macro_rules! args {
    ($($a:expr),* $(,)?) => { &[$(std::ffi::OsStr::new($a)),*] };
}

/// Small inputs for every command: the Zürich DEM converted, a path over it, the bunny, its
/// meta-node trees and page file.
struct Inputs {
    _dir: tempfile::TempDir,
    dir: PathBuf,
}

impl Inputs {
    fn new() -> Inputs {
        let dir = tempfile::tempdir().unwrap();
        let d = dir.path().to_path_buf();
        Inputs { _dir: dir, dir: d }
    }
    fn p(&self, name: &str) -> PathBuf {
        self.dir.join(name)
    }
    fn s(&self, name: &str) -> String {
        self.p(name).display().to_string()
    }
}

#[test]
fn every_json_output_is_strict_json() {
    let i = Inputs::new();
    let zurich = dem("zurich_25m_i16.tif").display().to_string();
    let bunny = mesh("bunny.off").display().to_string();
    let (t, p, mp, rmn, rpg) = (i.s("z.relief"), i.s("p.json"), i.s("mp.json"), i.s("b.rmn"), i.s("b.rpg"));
    let earth = Path::new(env!("CARGO_MANIFEST_DIR")).join("data/imagery/earth_2048.jpg").display().to_string();
    let rimg = i.s("earth.rimg");
    let commands: Vec<Vec<String>> = [
        vec!["convert", &zurich, &t, "--quiet", "--json"],
        vec!["info", &t, "--json"],
        vec!["verify", &t, "--json", "--quiet"],
        vec!["path", "flyover", &t, "--frames", "4", "--out", &p, "--json"],
        vec!["path", "orbit", &t, "--frames", "4", "--out", &i.s("o.json"), "--json"],
        vec![
            "refine",
            &t,
            "--eye",
            "6000,-2000,2500",
            "--look",
            "6400,6400,400",
            "--check",
            "--compare-minimal",
            "--json",
        ],
        vec![
            "render",
            &t,
            "--eye",
            "6000,-2000,2500",
            "--look",
            "6400,6400,400",
            "--width",
            "64",
            "--height",
            "40",
            "--out",
            &i.s("r.png"),
            "--json",
        ],
        vec!["fly", &t, "--path", &p, "--width", "64", "--height", "40", "--json", "--quiet"],
        vec!["fly", &t, "--path", &p, "--no-render", "--access", "pool", "--json", "--quiet"],
        vec![
            "layouts",
            &t,
            "--path",
            &p,
            "--memory",
            "1/16",
            "--tolerance",
            "1,4",
            "--backends",
            "all",
            "--mesh-step",
            "8",
            "--cache-dir",
            &i.s("cache"),
            "--json",
            "--quiet",
        ],
        vec!["mesh", "info", &bunny, "--json"],
        vec!["mesh", "build", &bunny, &rmn, "--memory", "1/2", "--json", "--quiet"],
        vec!["path", "orbit", &rmn, "--frames", "3", "--out", &mp, "--json"],
        vec!["mesh", "view", &bunny, "--path", &mp, "--width", "48", "--height", "32", "--json", "--quiet"],
        vec!["mesh", "fly", &rmn, "--path", &mp, "--no-render", "--json", "--quiet"],
        vec!["pages", "build", &bunny, &rpg, "--json", "--quiet"],
        vec!["pages", "fly", &rpg, "--path", &mp, "--no-render", "--json", "--quiet"],
        vec!["imagery", &earth, &rimg, "--json", "--quiet"],
        vec!["info", &rimg, "--json"],
        vec!["verify", &rimg, "--json"],
    ]
    .into_iter()
    .map(|c| c.into_iter().map(String::from).collect())
    .collect();
    let mut layouts = None;
    for c in &commands {
        let o = ok(relief().args(c).output().unwrap(), &c.join(" "));
        let v = strict(&o.stdout).unwrap_or_else(|e| panic!("relief {}: {e}", c.join(" ")));
        assert!(v.is_object(), "relief {}: {v}", c.join(" "));
        if c[0] == "layouts" {
            layouts = Some(v);
        }
    }
    // The fault table has every backend's rows: five terrain layouts, meta-node virt and ext,
    // three page layouts, at two tolerances.
    let v = layouts.unwrap();
    let runs = v["runs"].as_array().unwrap();
    let rows: Vec<(String, String)> = runs
        .iter()
        .filter(|r| r["tolerance"] == 1.0)
        .map(|r| (r["backend"].as_str().unwrap().to_string(), r["layout"].as_str().unwrap().to_string()))
        .collect();
    let want = [
        ("terrain", "row-major"),
        ("terrain", "tiled"),
        ("terrain", "interleaved"),
        ("terrain", "embedded"),
        ("terrain", "hz"),
        ("meta-node", "virt"),
        ("meta-node", "ext"),
        ("pages", "raster"),
        ("pages", "2factor"),
        ("pages", "hilbert"),
    ];
    assert_eq!(rows, want.map(|(a, b)| (a.to_string(), b.to_string())));
    for r in runs {
        assert!(r["faults"].as_u64().unwrap() > 0, "{r}");
        assert!(r["lower_bound"].as_u64().unwrap() <= r["distinct_pages"].as_u64().unwrap(), "{r}");
        assert_eq!(r["faults_per_frame"].as_array().unwrap().len(), 4);
    }
    assert_eq!(v["mesh"]["step"], 8);
}

#[test]
fn negative_numbers_are_taken_as_values() {
    let i = Inputs::new();
    let hugo = dem("hugo_site_nodata.asc").display().to_string();
    // Space-separated, as the README writes them.
    let o = ok(
        run(args!["convert", &hugo, &i.s("h.relief"), "--z-offset", "-30", "--z-scale", "-1", "--json", "--quiet"]),
        "convert",
    );
    let r = strict(&o.stdout).unwrap();
    // Heights of 1,660–1,711 m, negated and lowered by 30 m.
    assert!(r["z_max"].as_f64().unwrap() < -1600.0, "{r}");
    let info = strict(&ok(run(args!["info", &i.s("h.relief"), "--json"]), "info").stdout).unwrap();
    assert_eq!((info["z_offset"].as_f64(), info["z_scale"].as_f64()), (Some(-30.0), Some(-1.0)));
    // A negative value where none makes sense is the library's clean refusal, not the parser's.
    let e = fails(run(args!["convert", &hugo, &i.s("x.relief"), "--z-scale", "0"]), "zero scale");
    assert!(e.contains("--z-scale"), "{e}");
    let e =
        fails(run(args!["refine", &i.s("h.relief"), "--eye", "1,2,3", "--look", "4,5,6", "--tolerance", "-2"]), "τ");
    assert!(e.contains("--tolerance: expected a positive number of pixels, got -2"), "{e}");
    assert!(!i.p("x.relief").exists());
}

#[test]
fn output_paths_are_checked_before_the_work() {
    let i = Inputs::new();
    let zurich = dem("zurich_25m_i16.tif").display().to_string();
    let t = i.s("z.relief");
    ok(run(args!["convert", &zurich, &t, "--quiet"]), "convert");
    ok(run(args!["path", "flyover", &t, "--frames", "200", "--out", &i.s("p.json")]), "path");
    let nodir = i.s("nodir/s.json");
    let started = std::time::Instant::now();
    let e = fails(
        run(args!["fly", &t, "--path", &i.s("p.json"), "--stats", &nodir, "--frames-out", &i.s("frames")]),
        "--stats",
    );
    assert!(e.contains("--stats") && e.contains("nodir") && e.contains("does not exist"), "{e}");
    assert!(!i.p("frames").exists(), "frames were drawn before the output was checked");
    assert!(started.elapsed().as_secs_f64() < 20.0, "the flight ran before the check");
    let e = fails(run(args!["convert", &zurich, &i.s("nodir/z.relief")]), "convert");
    assert!(e.contains("nodir") && e.contains("does not exist"), "{e}");
    let e =
        fails(run(args!["render", &t, "--eye", "1,2,3000", "--look", "4,5,6", "--out", &i.s("nodir/r.png")]), "render");
    assert!(e.contains("--out") && e.contains("does not exist"), "{e}");
    let e =
        fails(run(args!["path", "orbit", &t, "--frames", "3", "--out", &i.dir.display().to_string()]), "a directory");
    assert!(e.contains("is a directory"), "{e}");
    let e = fails(
        run(args!["mesh", "build", &mesh("bunny.off").display().to_string(), &i.s("nodir/b.rmn"), "--memory", "1M"]),
        "build",
    );
    assert!(e.contains("does not exist"), "{e}");
}

#[test]
fn new_files_get_the_umask_mode() {
    use std::os::unix::fs::PermissionsExt;
    let i = Inputs::new();
    let zurich = dem("zurich_25m_i16.tif").display().to_string();
    for (umask, want) in [("022", 0o644), ("027", 0o640), ("002", 0o664)] {
        let t = i.s(&format!("z{umask}.relief"));
        let p = i.s(&format!("p{umask}.json"));
        let script = format!("umask {umask} && \"$0\" convert '{zurich}' '{t}' --quiet && \"$0\" path orbit '{t}' --frames 2 --out '{p}'");
        let o = std::process::Command::new("sh")
            .args(["-c", &script, env!("CARGO_BIN_EXE_relief")])
            .env("XDG_RUNTIME_DIR", std::env::temp_dir())
            .output()
            .unwrap();
        ok(o, "umask");
        for f in [&t, &p] {
            let mode = std::fs::metadata(f).unwrap().permissions().mode() & 0o777;
            assert_eq!(mode, want, "{f} under umask {umask}: {mode:o}");
        }
    }
}

/// `mesh build` killed with SIGTERM (what `timeout` sends) or SIGHUP removes its scratch folder and
/// writes no output, as after Ctrl-C.
#[test]
fn mesh_build_cleans_up_on_sigterm_and_sighup() {
    let i = Inputs::new();
    let armadillo = mesh("armadillo.off");
    for signal in [libc::SIGTERM, libc::SIGHUP, libc::SIGINT] {
        let out = i.p("a.rmn");
        let child = relief()
            .args(["mesh", "build"])
            .arg(&armadillo)
            .arg(&out)
            .args(["--memory", "1/16", "--quiet"])
            .spawn()
            .unwrap();
        std::thread::sleep(std::time::Duration::from_millis(700));
        // SAFETY: kill(2) on our own child's pid; no memory is involved.
        unsafe { libc::kill(child.id() as i32, signal) };
        let o = child.wait_with_output().unwrap();
        let left: Vec<String> =
            std::fs::read_dir(&i.dir).unwrap().map(|e| e.unwrap().file_name().to_string_lossy().into_owned()).collect();
        if o.status.success() {
            // The build won the race: a whole file and nothing else.
            assert_eq!(left, ["a.rmn"], "signal {signal}");
            std::fs::remove_file(&out).unwrap();
        } else {
            assert_eq!(o.status.code(), Some(1), "signal {signal}: not handled ({:?})", o.status);
            assert!(left.is_empty(), "signal {signal}: left behind {left:?}");
        }
    }
}

#[test]
fn a_bad_display_is_one_line_without_source_paths() {
    let i = Inputs::new();
    let t = i.s("h.relief");
    ok(run(args!["convert", &dem("hugo_site_nodata.asc").display().to_string(), &t, "--quiet"]), "convert");
    let o = relief().args(["fly", &t]).env("DISPLAY", ":97531").output().unwrap();
    let e = fails(o, "bad display");
    assert!(e.contains("cannot open a window") && e.contains("DISPLAY=:97531"), "{e}");
    assert!(!e.contains(".cargo") && !e.contains(".rs:"), "{e}");
}

/// Reading a file that is not there: the cause is said once, on the one line.
#[test]
fn causes_are_said_once() {
    let i = Inputs::new();
    let e = fails(run(args!["info", &i.s("missing.relief")]), "missing");
    assert_eq!(e.matches("No such file or directory").count(), 1, "{e}");
    let _ = Path::new("");
}

/// Output piped into a reader that stops early (`| head`): relief ends quietly, without a panic.
#[test]
fn a_closed_stdout_pipe_ends_quietly() {
    use std::io::Read;
    use std::process::Stdio;
    let dir = tempfile::tempdir().unwrap();
    let t = dir.path().join("t.relief");
    ok(run(&["convert".as_ref(), dem("zurich_25m_i16.tif").as_os_str(), t.as_os_str()]), "convert");
    let mut child =
        relief().args(["info", "--json"]).arg(&t).stdout(Stdio::piped()).stderr(Stdio::piped()).spawn().unwrap();
    // The reader goes before relief writes (it is still starting).
    drop(child.stdout.take());
    let mut err = String::new();
    child.stderr.take().unwrap().read_to_string(&mut err).unwrap();
    child.wait().unwrap();
    assert!(!err.contains("panicked"), "{err}");
}

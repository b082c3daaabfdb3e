//! `relief serve`: terrain files over HTTP/1.1 with byte ranges, so that a terrain can be read
//! remotely (`http://…` in place of a FILE) and remote reading benchmarked, optionally with an
//! emulated round trip; with `--viewer`, the web viewer beside them (src/web, built by
//! tools/web.sh), so a browser flies them. The server is the library's ([`relief::pager::serve`]).

use std::net::{IpAddr, SocketAddr};
use std::path::PathBuf;
use std::process::ExitCode;
use std::time::Duration;

use anyhow::bail;
use relief::pager::serve::{ServeOptions, Server};

use super::fmt_bytes;

#[derive(clap::Args)]
pub struct Args {
    /// Files to serve, each under its file name (http://HOST:PORT/NAME); each request re-reads
    /// the file, so a file replaced on disk is served anew (with a new ETag). With --viewer and
    /// no FILE: the bundled terrain (data/zurich_25m_i16.tif, converted on first use).
    #[arg(required_unless_present = "viewer", value_name = "FILE")]
    pub files: Vec<PathBuf>,
    /// Address to listen on (0.0.0.0 or :: for every interface).
    #[arg(long, value_name = "IP", default_value = "127.0.0.1")]
    pub bind: IpAddr,
    /// TCP port to listen on (0: any free port; the URLs printed say which).
    #[arg(long, default_value_t = 8080)]
    pub port: u16,
    /// Latency added before each response, milliseconds, to emulate a remote store (every
    /// request costs it once; concurrent requests wait concurrently).
    #[arg(long, value_name = "MS", default_value_t = 0.0)]
    pub latency_ms: f64,
    /// Also serve the web viewer (index.html and its wasm, built by tools/web.sh) at `/`, and print
    /// a link that opens each terrain in it (http://HOST:PORT/#NAME).
    #[arg(long)]
    pub viewer: bool,
    /// Also take S3-style uploads (PUT, multipart) of bucket/key into this directory, and serve
    /// what is uploaded: a stand-in bucket for tests (no authentication; keep it on loopback).
    #[arg(long, value_name = "DIR")]
    pub uploads: Option<PathBuf>,
    /// Where the built viewer is (default: $RELIEF_VIEWER_DIR, else target/viewer beside the
    /// build of this binary, where tools/web.sh puts it).
    #[arg(long, value_name = "DIR", requires = "viewer")]
    pub viewer_dir: Option<PathBuf>,
}

/// The viewer's files: what tools/web.sh builds.
pub const VIEWER_FILES: [&str; 3] = ["index.html", "relief_web.js", "relief_web_bg.wasm"];

/// Where the built viewer is: `given`, else $RELIEF_VIEWER_DIR, else `target/viewer` (the
/// binary is `target/<profile>/relief`).
pub fn viewer_dir(given: Option<PathBuf>) -> anyhow::Result<PathBuf> {
    let dir = match given.or_else(|| std::env::var_os("RELIEF_VIEWER_DIR").map(PathBuf::from)) {
        Some(d) => d,
        None => {
            let exe = std::env::current_exe()?;
            let target = exe.parent().and_then(|p| p.parent()).map(|p| p.join("viewer"));
            target.ok_or_else(|| anyhow::anyhow!("{}: cannot tell where target/ is", exe.display()))?
        }
    };
    for f in VIEWER_FILES {
        if !dir.join(f).is_file() {
            bail!("{}: no {f} (the web viewer is not built there); build it with `bash tools/web.sh`", dir.display());
        }
    }
    Ok(dir)
}

pub fn run(a: Args) -> anyhow::Result<ExitCode> {
    if !(a.latency_ms >= 0.0 && a.latency_ms.is_finite() && a.latency_ms < 1e9) {
        bail!("--latency-ms: expected milliseconds ≥ 0, got {}", a.latency_ms);
    }
    let given =
        if a.files.is_empty() { vec![relief::bundled_terrain(super::progress(false))?] } else { a.files.clone() };
    let mut files = Vec::with_capacity(given.len());
    for path in &given {
        let Some(name) = path.file_name().and_then(|n| n.to_str()) else {
            bail!("{}: no file name (or not UTF-8) to serve it under", path.display());
        };
        if let Some((_, other)) = files.iter().find(|(n, _): &&(String, PathBuf)| n == name) {
            bail!(
                "{} and {}: two files named {name}; serve them from separate commands",
                other.display(),
                path.display()
            );
        }
        files.push((name.to_string(), path.clone()));
    }
    let names: Vec<String> = files.iter().map(|(n, _)| n.clone()).collect();
    if a.viewer {
        let dir = viewer_dir(a.viewer_dir.clone())?;
        for f in VIEWER_FILES {
            if names.iter().any(|n| n == f) {
                bail!("{f}: a served file has the name of one of the viewer's");
            }
            files.push((f.to_string(), dir.join(f)));
        }
    }
    if let Some(d) = &a.uploads {
        if !d.is_dir() {
            bail!("--uploads: {}: no such directory", d.display());
        }
    }
    let options = ServeOptions {
        latency: Duration::from_secs_f64(a.latency_ms / 1000.0),
        uploads: a.uploads.clone(),
        ..Default::default()
    };
    let server = Server::start(files, SocketAddr::new(a.bind, a.port), options)?;
    for name in &names {
        if a.viewer {
            // The page reads the name after '#' relative to itself.
            println!("{}#{}", server.url(""), name);
        } else {
            println!("{}", server.url(name));
        }
    }
    if a.bind.is_unspecified() {
        eprintln!("listening on every interface, port {}; Ctrl-C to stop", server.addr().port());
    } else {
        eprintln!("listening on {}; Ctrl-C to stop", server.addr());
    }
    // Ctrl-C, SIGTERM and SIGHUP raise the cancellation flag (main's handler); serve until then.
    while relief::sys::cancel::check().is_ok() {
        std::thread::sleep(Duration::from_millis(100));
    }
    let (requests, bytes) = (server.requests(), server.bytes_sent());
    server.stop();
    eprintln!("stopped after {requests} requests, {} sent", fmt_bytes(bytes));
    Ok(ExitCode::SUCCESS)
}

//! Remote terrains: a terrain file served on loopback by the project's own range server
//! (`pager::serve`), read with range requests through the local cache; every fault the server can
//! inject ends in a retry that succeeds or a one-line error, and nothing half-written is cached.

use std::path::Path;
use std::sync::atomic::Ordering;
use std::time::Duration;

use glam::DVec3;
use relief_core::camera::Camera;
use relief_core::format::terrain::TerrainFile;
use relief_core::layout::LayoutKind;
use relief_core::pager::remote::{RemoteFile, RemoteOptions};
use relief_core::pager::serve::{ServeOptions, Server};
use relief_core::pager::source::Source;
use relief_core::pager::Access;
use relief_core::preprocess::convert::{convert, ConvertOptions};
use relief_core::refine::{RefineOptions, Refiner, Strip};

use super::common;

fn zurich(dir: &Path) -> std::path::PathBuf {
    let out = dir.join("zurich.relief");
    convert(&common::dem("zurich_25m_i16.tif"), &out, &ConvertOptions::new(LayoutKind::Interleaved)).unwrap();
    out
}

fn serve(file: &Path, latency_ms: u64) -> Server {
    let options = ServeOptions { latency: Duration::from_millis(latency_ms), ..Default::default() };
    Server::start(vec![("zurich.relief".into(), file.to_path_buf())], "127.0.0.1:0".parse().unwrap(), options).unwrap()
}

fn options(cache: &Path) -> RemoteOptions {
    RemoteOptions { cache_dir: Some(cache.to_path_buf()), backoff: Duration::from_millis(2), ..Default::default() }
}

/// The view every test here flies: over Zürich from its southern edge, looking north.
fn view() -> Camera {
    Camera::new(DVec3::new(6400.0, 640.0, 1126.0), DVec3::new(6400.0, 7680.0, 393.0), DVec3::Z, 60.0, 800, 450).unwrap()
}

fn strip_of(t: &TerrainFile) -> Strip {
    let cam = view();
    let mut strip = Strip::new();
    Refiner::new(1)
        .unwrap()
        .refine_file(t, &cam, &RefineOptions { tolerance_px: 2.0, ..Default::default() }, &mut strip)
        .unwrap();
    strip
}

#[test]
fn a_served_terrain_refines_to_the_local_strip_and_is_cached_for_the_next_open() {
    let dir = tempfile::tempdir().unwrap();
    let local = zurich(dir.path());
    let server = serve(&local, 0);
    let url = server.url("zurich.relief");
    let cache = dir.path().join("cache");
    let remote = TerrainFile::open_remote(&url, options(&cache), Access::Map).unwrap();
    let opened = remote.pager().network().unwrap();
    assert_eq!(opened.requests, 1, "opening costs one request");
    let (h, l) = (remote.header(), TerrainFile::open(&local).unwrap().header().clone());
    assert_eq!((h.records, h.payload_checksum, h.n), (l.records, l.payload_checksum, l.n));
    let want = strip_of(&TerrainFile::open(&local).unwrap());
    assert_eq!(strip_of(&remote).vertices, want.vertices);
    let fetched = remote.pager().network().unwrap();
    assert!(fetched.requests > 1 && fetched.bytes > opened.bytes);
    drop(remote);
    // A second open (another process would see the same) reads the pages from the cache.
    let again = TerrainFile::open_remote(&url, options(&cache), Access::Read).unwrap();
    assert_eq!(strip_of(&again).vertices, want.vertices);
    let s = again.pager().network().unwrap();
    assert_eq!(s.requests, 1, "only the open goes to the network: {s:?}");
    assert!(s.cache_hit_pages > 0);
}

#[test]
fn dropped_connections_5xx_and_short_answers_are_retried() {
    let dir = tempfile::tempdir().unwrap();
    let local = zurich(dir.path());
    let bytes = std::fs::read(&local).unwrap();
    let server = serve(&local, 0);
    let url = server.url("zurich.relief");
    let f = RemoteFile::open(&url, RemoteOptions { first_range: 4096, ..options(&dir.path().join("c")) }).unwrap();
    for (k, fault) in
        [&server.faults().drop_next, &server.faults().error_next, &server.faults().short_next].into_iter().enumerate()
    {
        fault.store(2, Ordering::SeqCst);
        let at = 1_000_000 + k as u64 * 100_000;
        let mut buf = vec![0u8; 50_000];
        f.read_at(at, &mut buf).unwrap();
        assert_eq!(&buf[..], &bytes[at as usize..at as usize + 50_000], "fault {k}");
        assert_eq!(fault.load(Ordering::SeqCst), 0);
    }
    assert!(f.stats().retries >= 6, "{:?}", f.stats());
}

#[test]
fn faults_that_do_not_heal_are_one_line_errors_and_leave_nothing_cached() {
    let dir = tempfile::tempdir().unwrap();
    let local = zurich(dir.path());
    let server = serve(&local, 0);
    let url = server.url("zurich.relief");
    let cache = dir.path().join("c");
    let f = RemoteFile::open(&url, RemoteOptions { first_range: 4096, attempts: 3, ..options(&cache) }).unwrap();
    let mut buf = vec![0u8; 8192];

    server.faults().error_next.store(10, Ordering::SeqCst);
    let e = f.read_at(200_000, &mut buf).unwrap_err().to_string();
    assert_eq!(e, format!("{url}: server answered 503 (gave up after 3 attempts)"));
    server.faults().error_next.store(0, Ordering::SeqCst);

    server.faults().short_next.store(10, Ordering::SeqCst);
    let e = f.read_at(300_000, &mut buf).unwrap_err().to_string();
    assert!(e.starts_with(&format!("{url}: short answer")) && !e.contains('\n'), "{e}");
    server.faults().short_next.store(0, Ordering::SeqCst);
    assert!(!f.cache().has(200_000 / 4096).unwrap() && !f.cache().has(300_000 / 4096).unwrap());

    server.faults().ignore_range.store(true, Ordering::SeqCst);
    let e = f.read_at(400_000, &mut buf).unwrap_err().to_string();
    assert!(e.starts_with(&format!("{url}: the server ignores Range requests")), "{e}");
    let e = RemoteFile::open(&url, options(&dir.path().join("d"))).err().unwrap().to_string();
    assert!(e.contains("ignores Range"), "{e}");
    server.faults().ignore_range.store(false, Ordering::SeqCst);

    // The file replaced on the server mid-flight (a new ETag): an error, never mixed bytes.
    let tmp = dir.path().join("new.relief");
    let mut other = std::fs::read(&local).unwrap();
    other[5000] ^= 1;
    std::fs::write(&tmp, &other).unwrap();
    std::fs::rename(&tmp, &local).unwrap();
    let e = f.read_at(500_000, &mut buf).unwrap_err().to_string();
    assert!(e.starts_with(&format!("{url}: changed on the server while being read")), "{e}");
    assert!(!f.cache().has(500_000 / 4096).unwrap());

    let missing = server.url("nothing.relief");
    let e = RemoteFile::open(&missing, options(&cache)).err().unwrap().to_string();
    assert_eq!(e, format!("{missing}: not found on the server (404)"));
}

#[test]
fn a_cache_of_another_version_is_replaced_and_the_bound_is_kept() {
    let dir = tempfile::tempdir().unwrap();
    let local = zurich(dir.path());
    let server = serve(&local, 0);
    let url = server.url("zurich.relief");
    let cache = dir.path().join("c");
    let f = RemoteFile::open(&url, options(&cache)).unwrap();
    let cached = f.cache().present_pages();
    assert_eq!(cached, 256, "the first MiB");
    drop(f);
    let mut other = std::fs::read(&local).unwrap();
    other.push(0);
    std::fs::write(&local, &other).unwrap();
    let f = RemoteFile::open(&url, options(&cache)).unwrap();
    assert_eq!(f.len(), other.len() as u64);
    let mut buf = vec![0u8; 100];
    f.read_at(f.len() - 100, &mut buf).unwrap();
    assert_eq!(&buf[..], &other[other.len() - 100..], "pages of the old version are not served");
    // A bound below what is cached: nothing more is stored, reads still work.
    drop(f);
    let small = RemoteOptions { cache_bytes: 64 << 10, ..options(&cache) };
    let f = RemoteFile::open(&url, small).unwrap();
    f.read_at(2_000_000, &mut buf).unwrap();
    assert_eq!(&buf[..], &other[2_000_000..2_000_100]);
    assert!(!f.cache().has(2_000_000 / 4096).unwrap());
}

/// Flies one view of a served terrain frame by frame: no update waits for the network (the first
/// frame is drawn from the opening request alone), every frame is a conforming mesh, and once
/// the fetches are in, the strip is the local file's.
fn progressive_flight(layout: LayoutKind) {
    use relief_core::flight::frame::{Frame, FrameSource};
    use relief_core::flight::terrain::TerrainSource;
    use relief_core::refine::check::check_strip;
    use std::collections::HashSet;
    use std::sync::Arc;

    let dir = tempfile::tempdir().unwrap();
    let local = dir.path().join("zurich.relief");
    convert(&common::dem("zurich_25m_i16.tif"), &local, &ConvertOptions::new(layout)).unwrap();
    let server = serve(&local, 20);
    let url = server.url("zurich.relief");
    let remote = Arc::new(TerrainFile::open_remote(&url, options(&dir.path().join("cache")), Access::Read).unwrap());
    let grid = remote.grid();
    let refine = RefineOptions { tolerance_px: 2.0, ..Default::default() };
    let mut source = TerrainSource::new(remote.clone(), refine, 1, false).unwrap();
    let cam = view();
    let conforming = |s: &TerrainSource| {
        let Frame::Strip(strip) = s.frame() else { unreachable!() };
        let inserted: HashSet<(u32, u32)> = strip.vertices.iter().map(|v| (v.x, v.y)).collect();
        let check = check_strip(grid, strip, |x, y| inserted.contains(&(x, y)));
        assert!(check.crack_free, "{layout}: {check:?}");
        strip.vertices.clone()
    };
    let first = source.update(&cam, 2.0).unwrap();
    assert!(first.coarse, "{layout}: the first frame cannot have everything yet: {first:?}");
    assert_eq!(first.round_trips, 1, "{layout}: the first frame is drawn from the opening request alone");
    conforming(&source);
    let mut frames = 1;
    let mut last = first;
    while last.coarse && frames < 2000 {
        std::thread::sleep(Duration::from_millis(5));
        last = source.update(&cam, 2.0).unwrap();
        conforming(&source);
        frames += 1;
    }
    assert!(!last.coarse, "{layout}: still coarse after {frames} frames: {last:?}");
    assert!(frames > 2, "{layout}: frames were drawn while the data arrived");
    let want = strip_of(&TerrainFile::open(&local).unwrap());
    assert_eq!(conforming(&source), want.vertices, "{layout}: converged to the local strip");
    let stats = remote.pager().network().unwrap();
    eprintln!(
        "{layout}: complete after {frames} frames, {} round trips, {} requests, {} bytes",
        last.round_trips, stats.requests, stats.bytes
    );
    assert!(last.round_trips >= 2 && last.round_trips <= 12, "{layout}: {last:?}");
}

#[test]
fn a_remote_flight_never_waits_never_cracks_and_converges_to_the_local_strip() {
    progressive_flight(LayoutKind::Interleaved);
    progressive_flight(LayoutKind::RowMajor);
}

#[test]
fn an_s3_location_with_credentials_is_read_with_signed_requests_from_its_endpoint() {
    use relief_core::pager::remote::S3Config;
    let dir = tempfile::tempdir().unwrap();
    let local = zurich(dir.path());
    // A bucket endpoint in path style: the object `terrains/zurich.relief` of bucket `dem`.
    let server = Server::start(
        vec![("dem/terrains/zurich.relief".into(), local.clone())],
        "127.0.0.1:0".parse().unwrap(),
        ServeOptions::default(),
    )
    .unwrap();
    let endpoint = server.url("").trim_end_matches('/').to_string();
    let mut o = options(&dir.path().join("cache"));
    o.s3 = S3Config {
        endpoint: Some(endpoint),
        region: "eu-central-2".into(),
        credentials: Some(("AKIDEXAMPLE".into(), "wJalrXUtnFEMI".into(), None)),
    };
    let remote = TerrainFile::open_remote("s3://dem/terrains/zurich.relief", o, Access::Read).unwrap();
    assert_eq!(strip_of(&remote).vertices, strip_of(&TerrainFile::open(&local).unwrap()).vertices);
    let stats = remote.pager().network().unwrap();
    assert!(stats.requests > 1 && stats.retries == 0, "{stats:?}");
    let mut o = options(&dir.path().join("c2"));
    o.s3 = S3Config { endpoint: Some(server.url("").trim_end_matches('/').to_string()), ..Default::default() };
    let e = TerrainFile::open_remote("s3://dem/terrains/nope.relief", o, Access::Read).err().unwrap().to_string();
    assert!(e.contains("s3://dem/terrains/nope.relief") && e.contains("404"), "{e}");
}

/// A server that goes away mid-flight: the fetches fail after their retries, and the next update
/// says so in one line naming the location (the frames before it were drawn without waiting).
#[test]
fn a_server_gone_mid_flight_ends_the_flight_with_a_one_line_error() {
    use relief_core::flight::frame::FrameSource;
    use relief_core::flight::terrain::TerrainSource;
    use std::sync::Arc;
    let dir = tempfile::tempdir().unwrap();
    let local = zurich(dir.path());
    let server = serve(&local, 0);
    let url = server.url("zurich.relief");
    let mut o = options(&dir.path().join("cache"));
    o.attempts = 2;
    let remote = Arc::new(TerrainFile::open_remote(&url, o, Access::Read).unwrap());
    server.stop();
    let mut source =
        TerrainSource::new(remote, RefineOptions { tolerance_px: 2.0, ..Default::default() }, 1, false).unwrap();
    let cam = view();
    let first = source.update(&cam, 2.0).unwrap();
    assert!(first.coarse, "drawn from the opening request: {first:?}");
    let mut error = None;
    for _ in 0..400 {
        std::thread::sleep(Duration::from_millis(5));
        if let Err(e) = source.update(&cam, 2.0) {
            error = Some(e.to_string());
            break;
        }
    }
    let e = error.expect("the failed fetch is reported");
    assert!(e.contains(&url) && e.lines().count() == 1, "{e}");
}

/// A reader going through the file in order gets ever larger requests (read-ahead), not one per
/// read; a random reader gets no more than it asks for.
#[test]
fn sequential_reads_are_served_by_growing_read_ahead() {
    let dir = tempfile::tempdir().unwrap();
    let local = zurich(dir.path());
    let bytes = std::fs::read(&local).unwrap();
    let server = serve(&local, 0);
    let remote = RemoteFile::open(&server.url("zurich.relief"), options(&dir.path().join("cache"))).unwrap();
    let mut got = vec![0u8; bytes.len()];
    for (k, chunk) in got.chunks_mut(12 << 10).enumerate() {
        remote.read_at((k * (12 << 10)) as u64, chunk).unwrap();
    }
    assert!(got == bytes, "the same bytes");
    let reads = bytes.len().div_ceil(12 << 10);
    let s = remote.stats();
    assert!(s.requests < 20, "{} requests for {reads} sequential reads: {s:?}", s.requests);
    assert!(s.bytes <= bytes.len() as u64, "nothing fetched twice: {s:?}");
    // Random reads (backwards) fetch only their own pages.
    let other = RemoteFile::open(&server.url("zurich.relief"), options(&dir.path().join("cache2"))).unwrap();
    let mut one = vec![0u8; 100];
    // Past the opening range (the first MiB), going backwards, each read within one page.
    let step = ((bytes.len() as u64 - (1 << 20) - 8192) / 5) & !4095;
    assert!(step >= 4096, "the file is large enough");
    for k in (0..5u64).rev() {
        other.read_at((1 << 20) + 4096 + k * step, &mut one).unwrap();
    }
    let s = other.stats();
    assert_eq!(s.requests, 1 + 5, "the open and one request per read: {s:?}");
    assert_eq!(s.bytes, (1 << 20) + 5 * 4096, "one page each: {s:?}");
}

/// Records every byte range a pager reports (the observer a page-fault experiment attaches).
#[derive(Default)]
struct Recorder(std::sync::Mutex<Vec<(u64, u64)>>);

impl relief_core::pager::PageObserver for Recorder {
    fn read(&self, offset: u64, len: u64) {
        self.0.lock().unwrap().push((offset, len));
    }
}

/// A remote flight's reads go through the pager like a local flight's: the same observer,
/// attached the same way, sees them; every block the local refinement read was fetched, none
/// twice, and the pager's read counts say the same as the observer.
#[test]
fn a_remote_flight_reads_are_seen_by_the_observer_a_local_flight_reports_to() {
    use relief_core::flight::frame::FrameSource;
    use relief_core::flight::terrain::TerrainSource;
    use std::collections::HashSet;
    use std::sync::Arc;

    let dir = tempfile::tempdir().unwrap();
    let local_path = zurich(dir.path());
    let server = serve(&local_path, 5);
    let url = server.url("zurich.relief");
    let refine = RefineOptions { tolerance_px: 2.0, ..Default::default() };
    let cam = view();
    let fly = |terrain: Arc<TerrainFile>| {
        let seen = Arc::new(Recorder::default());
        terrain.pager().observe(seen.clone()).unwrap();
        let mut source = TerrainSource::new(terrain.clone(), refine, 1, false).unwrap();
        let mut frames = 0;
        loop {
            let f = source.update(&cam, 2.0).unwrap();
            frames += 1;
            if !f.coarse || frames == 2000 {
                assert!(!f.coarse, "still coarse after {frames} frames");
                break;
            }
            std::thread::sleep(Duration::from_millis(2));
        }
        let reads: Vec<(u64, u64)> = seen.0.lock().unwrap().clone();
        (reads, terrain.pager().reads())
    };
    let local = Arc::new(TerrainFile::open_with(&local_path, Access::Read).unwrap());
    let (local_reads, _) = fly(local);
    let remote = Arc::new(TerrainFile::open_remote(&url, options(&dir.path().join("cache")), Access::Read).unwrap());
    let (remote_reads, remote_stats) = fly(remote.clone());
    assert!(!local_reads.is_empty() && !remote_reads.is_empty());
    let remote_blocks: HashSet<(u64, u64)> = remote_reads.iter().copied().collect();
    assert_eq!(remote_blocks.len(), remote_reads.len(), "a remote block is read once");
    let local_blocks: HashSet<(u64, u64)> = local_reads.iter().copied().collect();
    let missing: Vec<_> = local_blocks.difference(&remote_blocks).collect();
    assert!(missing.is_empty(), "blocks the local flight read that the remote one never did: {missing:?}");
    assert_eq!(remote_stats.blocks, remote_reads.len() as u64);
    assert_eq!(remote_stats.bytes, remote_reads.iter().map(|r| r.1).sum::<u64>());
    let net = remote.pager().network().unwrap();
    assert!(net.requests > 1 && net.bytes > 0, "{net:?}");
}

/// The web viewer's way (`pager::hosted`, `Progressive::hosted`): no thread, the host fetches
/// the ranges each request names and delivers them. Every frame is conforming, the flight
/// converges to the local strip within a few rounds, and no byte is fetched twice.
#[test]
fn a_hosted_flight_fetches_each_byte_once_and_converges_to_the_local_strip() {
    use relief_core::pager::hosted::HostedFile;
    use relief_core::refine::check::check_strip;
    use relief_core::refine::progressive::{Progressive, ProgressiveOptions};
    use std::collections::HashSet;
    use std::sync::Arc;

    let dir = tempfile::tempdir().unwrap();
    let local = zurich(dir.path());
    let bytes = std::fs::read(&local).unwrap();
    let name = Path::new("http://127.0.0.1/zurich.relief");
    let hosted = Arc::new(HostedFile::new(name, bytes.len() as u64));
    // The opening request: the header and the coarsest levels (64 KiB; the viewer asks more).
    let first = bytes.len().min(64 << 10);
    hosted.insert(0, &bytes[..first]).unwrap();
    let mut fetched: Vec<(u64, u64)> = vec![(0, first as u64)];
    let terrain = Arc::new(TerrainFile::from_source(name, hosted.clone(), Access::Read).unwrap());
    assert!(terrain.is_remote());
    let mut progressive = Progressive::hosted(terrain.clone(), ProgressiveOptions::default()).unwrap();
    let (mut refiner, cam) = (Refiner::new(1).unwrap(), view());
    let refine = RefineOptions { tolerance_px: 2.0, ..Default::default() };
    let grid = terrain.grid();
    let mut strip = Strip::new();
    let mut frames = 0;
    let last = loop {
        let frame = progressive.refine(&mut refiner, &cam, &refine, &mut strip).unwrap();
        let inserted: HashSet<(u32, u32)> = strip.vertices.iter().map(|v| (v.x, v.y)).collect();
        let check = check_strip(grid, &strip, |x, y| inserted.contains(&(x, y)));
        assert!(check.crack_free, "frame {frames}: {check:?}");
        frames += 1;
        if frame.complete() || frames > 100 {
            break frame;
        }
        // The host: fetch every range of the request (each byte once), insert, deliver.
        while let Some(request) = progressive.take_request().unwrap() {
            for &(a, b) in &request.ranges {
                assert!(fetched.iter().all(|&(c, d)| b <= c || d <= a), "{a}..{b} fetched again: {fetched:?}");
                fetched.push((a, b));
                hosted.insert(a, &bytes[a as usize..b as usize]).unwrap();
            }
            progressive.deliver(request).unwrap();
        }
    };
    assert!(last.complete(), "still coarse after {frames} frames: {last:?}");
    assert!(frames >= 2, "the first frame, from the opening range alone, is coarse");
    assert!((2..=6).contains(&last.round_trips), "complete within a few round trips: {last:?}");
    assert_eq!(strip.vertices, strip_of(&TerrainFile::open(&local).unwrap()).vertices, "converged to the local strip");
    let stats = terrain.pager().network().unwrap();
    assert_eq!(
        stats.bytes,
        fetched.iter().map(|&(a, b)| b - a).sum::<u64>(),
        "the source counted what the host fetched"
    );
    assert!(stats.bytes < bytes.len() as u64, "a view fetches part of the file");
    eprintln!(
        "hosted: complete after {frames} frames, {} rounds, {} ranges, {} of {} bytes",
        last.round_trips,
        fetched.len(),
        stats.bytes,
        bytes.len()
    );
}

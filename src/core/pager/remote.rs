//! Files read over the network with HTTP range requests (RFC 9110 §14): a [`RemoteFile`] is a
//! [`Source`] whose bytes come from a web server or an object store's HTTP endpoint, through a
//! local on-disk cache of fetched pages ([`DiskCache`]).
//!
//! - **Opening costs one request**: a range of the file's first [`RemoteOptions::first_range`]
//!   bytes, which tells the length and the ETag and holds the header and, in a hierarchical
//!   layout, the coarse levels (ARCHITECTURE.md, "Remote terrains").
//! - **Every answer is validated**: a 206 whose `Content-Range` is exactly the range asked for, of
//!   a file of the length and ETag seen at the open (and `If-Match` sent, so a server that knows
//!   answers 412). A file that changes under us is an error, never a mixed frame.
//! - **Failures are retried** with exponential backoff (dropped connections, 5xx, 429, short
//!   bodies); a 4xx or a server that ignores `Range` is a one-line error.
//! - **Requests are coalesced and bounded in flight**: [`RemoteFile::fetch_runs`] merges page runs
//!   closer than [`RemoteOptions::coalesce_gap`] and runs at most
//!   [`RemoteOptions::max_in_flight`] requests at once.
//!
//! `s3://bucket/key` is read through the bucket's endpoint (`AWS_ENDPOINT_URL_S3` or
//! `AWS_ENDPOINT_URL` in path style, else the virtual-hosted AWS one for `AWS_REGION`). With
//! `AWS_ACCESS_KEY_ID` and `AWS_SECRET_ACCESS_KEY` (and `AWS_SESSION_TOKEN`) in the environment
//! every request is signed (AWS Signature V4 as a presigned URL, by `rusty-s3`, fresh for each
//! request); without them the object must be public.

#[cfg(feature = "native")]
use std::fs::File;
#[cfg(feature = "native")]
use std::io::Read;
#[cfg(feature = "native")]
use std::os::unix::fs::FileExt;
use std::path::Path;
#[cfg(feature = "native")]
use std::path::PathBuf;
#[cfg(feature = "native")]
use std::sync::atomic::{AtomicU64, Ordering};
#[cfg(feature = "native")]
use std::time::Duration;

pub use super::source::RemoteStats;
/// The cache's granule: pages of this many bytes, fetched and kept whole.
pub use super::source::PAGE_BYTES;
#[cfg(feature = "native")]
use super::source::{check_range, Source, SourceKind};
#[cfg(feature = "native")]
use crate::error::IoContext;
use crate::error::{Error, Result};

/// Whether `path` names a remote file (`http://`, `https://` or `s3://`).
pub fn is_remote(path: &Path) -> bool {
    let s = path.to_string_lossy();
    s.starts_with("http://") || s.starts_with("https://") || s.starts_with("s3://")
}

#[cfg(feature = "native")]
/// The unsigned HTTP(S) address of a remote location (`s3://bucket/key` through its endpoint, as
/// `s3` says).
pub fn http_url(location: &str, s3: &S3Config) -> Result<String> {
    if location.starts_with("http://") || location.starts_with("https://") {
        return Ok(location.to_string());
    }
    let Some((bucket, key)) = s3_parts(location)? else {
        return Err(Error::remote(location, "not an http://, https:// or s3:// address"));
    };
    Ok(match &s3.endpoint {
        // A custom endpoint (MinIO, Ceph, R2, …) in path style, as their users configure it.
        Some(endpoint) => format!("{}/{bucket}/{key}", endpoint.trim_end_matches('/')),
        None => format!("https://{bucket}.s3.{}.amazonaws.com/{key}", s3.region),
    })
}

#[cfg(feature = "native")]
/// How a remote file is read.
#[derive(Clone, Debug)]
pub struct RemoteOptions {
    /// Bytes asked for by the opening request (the header and the coarse levels).
    pub first_range: u64,
    /// Requests in flight at once.
    pub max_in_flight: usize,
    /// Page runs closer than this many bytes are fetched in one request (the gap with them).
    pub coalesce_gap: u64,
    /// The largest single request.
    pub max_request: u64,
    /// Attempts per request before its error is returned.
    pub attempts: u32,
    /// The first retry's delay (doubled each time).
    pub backoff: Duration,
    /// Timeout of one request, from connect to the last body byte.
    pub timeout: Duration,
    /// Where fetched pages are kept (`None`: a temporary cache, removed when the file is closed).
    pub cache_dir: Option<PathBuf>,
    /// The cache's size bound, bytes (every cached file together).
    pub cache_bytes: u64,
    /// How `s3://` locations are reached and signed (from the environment by default).
    pub s3: S3Config,
}

#[cfg(feature = "native")]
/// Where and as whom `s3://` locations are read.
#[derive(Clone, Default, PartialEq, Eq)]
pub struct S3Config {
    /// A custom endpoint (MinIO, Ceph, R2, …), addressed in path style; `None`: AWS itself, in
    /// virtual-host style for `region`.
    pub endpoint: Option<String>,
    pub region: String,
    /// Access key id, secret and session token; `None`: unsigned requests (public objects).
    pub credentials: Option<(String, String, Option<String>)>,
}

#[cfg(feature = "native")]
impl std::fmt::Debug for S3Config {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        // The secret stays out of logs and error messages.
        f.debug_struct("S3Config")
            .field("endpoint", &self.endpoint)
            .field("region", &self.region)
            .field("access_key_id", &self.credentials.as_ref().map(|c| &c.0))
            .finish()
    }
}

#[cfg(feature = "native")]
impl S3Config {
    /// From `AWS_ENDPOINT_URL_S3` / `AWS_ENDPOINT_URL`, `AWS_REGION` / `AWS_DEFAULT_REGION`
    /// (default `us-east-1`), `AWS_ACCESS_KEY_ID`, `AWS_SECRET_ACCESS_KEY`, `AWS_SESSION_TOKEN`.
    pub fn from_env() -> Result<S3Config> {
        let var = |n: &str| std::env::var(n).ok().filter(|v| !v.is_empty());
        let endpoint = var("AWS_ENDPOINT_URL_S3").or_else(|| var("AWS_ENDPOINT_URL"));
        let region = var("AWS_REGION").or_else(|| var("AWS_DEFAULT_REGION")).unwrap_or_else(|| "us-east-1".into());
        let credentials = match (var("AWS_ACCESS_KEY_ID"), var("AWS_SECRET_ACCESS_KEY")) {
            (Some(k), Some(s)) => Some((k, s, var("AWS_SESSION_TOKEN"))),
            (None, None) => None,
            (Some(_), None) => {
                return Err(Error::InvalidArgument("AWS_ACCESS_KEY_ID is set but AWS_SECRET_ACCESS_KEY is not".into()))
            }
            (None, Some(_)) => {
                return Err(Error::InvalidArgument("AWS_SECRET_ACCESS_KEY is set but AWS_ACCESS_KEY_ID is not".into()))
            }
        };
        Ok(S3Config { endpoint, region, credentials })
    }
}

#[cfg(feature = "native")]
/// Signs the requests of one S3 object.
struct S3Signer {
    bucket: rusty_s3::Bucket,
    key: String,
    credentials: rusty_s3::Credentials,
}

#[cfg(feature = "native")]
impl S3Signer {
    /// A presigned GET of the object, valid for 15 minutes (made again for every request).
    fn url(&self) -> String {
        use rusty_s3::S3Action as _;
        rusty_s3::actions::GetObject::new(&self.bucket, Some(&self.credentials), &self.key)
            .sign(Duration::from_secs(900))
            .to_string()
    }
}

#[cfg(feature = "native")]
/// `s3://BUCKET/KEY` as its bucket and key.
pub(crate) fn s3_parts(location: &str) -> Result<Option<(&str, &str)>> {
    let Some(rest) = location.strip_prefix("s3://") else { return Ok(None) };
    match rest.split_once('/').filter(|(b, k)| !b.is_empty() && !k.is_empty()) {
        Some(parts) => Ok(Some(parts)),
        None => Err(Error::remote(location, "expected s3://BUCKET/KEY")),
    }
}

#[cfg(feature = "native")]
/// The signer of `location` (an `s3://` one, with credentials), else `None`.
fn s3_signer(location: &str, s3: &S3Config) -> Result<Option<S3Signer>> {
    let (Some((bucket, key)), Some((id, secret, token))) = (s3_parts(location)?, &s3.credentials) else {
        return Ok(None);
    };
    let (endpoint, style) = match &s3.endpoint {
        Some(e) => (e.clone(), rusty_s3::UrlStyle::Path),
        None => (format!("https://s3.{}.amazonaws.com", s3.region), rusty_s3::UrlStyle::VirtualHost),
    };
    let url = endpoint.parse().map_err(|e| Error::remote(location, format!("bad S3 endpoint {endpoint:?}: {e}")))?;
    let bucket = rusty_s3::Bucket::new(url, style, bucket.to_string(), s3.region.clone())
        .map_err(|e| Error::remote(location, format!("bad S3 endpoint {endpoint:?}: {e}")))?;
    let credentials = match token {
        Some(t) => rusty_s3::Credentials::new_with_token(id.clone(), secret.clone(), t.clone()),
        None => rusty_s3::Credentials::new(id.clone(), secret.clone()),
    };
    Ok(Some(S3Signer { bucket, key: key.to_string(), credentials }))
}

#[cfg(feature = "native")]
impl RemoteOptions {
    /// The defaults, with what the environment sets: `RELIEF_REMOTE_IN_FLIGHT` (requests at
    /// once), `RELIEF_REMOTE_COALESCE_KIB` (gap merged into one request, KiB) and
    /// `RELIEF_REMOTE_MAX_REQUEST_KIB` (largest request, KiB); the cache as
    /// [`default_cache_dir`] says.
    pub fn from_env() -> Result<RemoteOptions> {
        let mut o = RemoteOptions::default();
        if let Some(v) = env_number("RELIEF_REMOTE_IN_FLIGHT")? {
            o.max_in_flight = v.max(1) as usize;
        }
        if let Some(v) = env_number("RELIEF_REMOTE_COALESCE_KIB")? {
            o.coalesce_gap = v << 10;
        }
        if let Some(v) = env_number("RELIEF_REMOTE_MAX_REQUEST_KIB")? {
            o.max_request = (v << 10).max(PAGE_BYTES);
        }
        o.s3 = S3Config::from_env()?;
        Ok(o)
    }
}

/// A whole number from environment variable `name`, if it is set.
pub fn env_number(name: &str) -> Result<Option<u64>> {
    match std::env::var(name) {
        Err(_) => Ok(None),
        Ok(v) => v
            .trim()
            .parse::<u64>()
            .map(Some)
            .map_err(|_| Error::InvalidArgument(format!("environment variable {name}={v:?} is not a whole number"))),
    }
}

#[cfg(feature = "native")]
impl Default for RemoteOptions {
    fn default() -> Self {
        RemoteOptions {
            first_range: 1 << 20,
            max_in_flight: 16,
            coalesce_gap: 1 << 20,
            max_request: 4 << 20,
            attempts: 6,
            backoff: Duration::from_millis(20),
            timeout: Duration::from_secs(30),
            cache_dir: default_cache_dir(),
            cache_bytes: 8 << 30,
            s3: S3Config { region: "us-east-1".into(), ..Default::default() },
        }
    }
}

#[cfg(feature = "native")]
/// `$RELIEF_CACHE_DIR`, else `$XDG_CACHE_HOME/relief`, else `~/.cache/relief`.
pub fn default_cache_dir() -> Option<PathBuf> {
    if let Some(d) = std::env::var_os("RELIEF_CACHE_DIR") {
        return Some(PathBuf::from(d));
    }
    if let Some(d) = std::env::var_os("XDG_CACHE_HOME") {
        return Some(PathBuf::from(d).join("relief"));
    }
    std::env::var_os("HOME").map(|h| PathBuf::from(h).join(".cache/relief"))
}

#[cfg(feature = "native")]
#[derive(Default)]
struct Counters {
    requests: AtomicU64,
    bytes: AtomicU64,
    retries: AtomicU64,
    cache_hit_pages: AtomicU64,
}

#[cfg(feature = "native")]
/// A remote file of fixed length and ETag, read with range requests through a page cache.
pub struct RemoteFile {
    client: Client,
    path: PathBuf,
    cache: DiskCache,
    /// Sequential reads ([`Source::read_at`]): where the last one ended, and the pages fetched
    /// ahead of the next (doubled while reads stay sequential, up to one largest request).
    next_offset: AtomicU64,
    readahead_pages: AtomicU64,
    /// The end of the pages fetched ahead (page number): the next window is fetched when a read
    /// passes it.
    readahead_end: AtomicU64,
}

#[cfg(feature = "native")]
/// The requests of one remote file: where it is, how to ask, what it was when opened.
struct Client {
    location: String,
    url: String,
    /// Signs every request (an `s3://` location with credentials).
    signer: Option<S3Signer>,
    len: u64,
    etag: Option<String>,
    agent: ureq::Agent,
    options: RemoteOptions,
    counters: Counters,
}

#[cfg(feature = "native")]
/// Why one attempt failed: worth retrying or not.
enum Attempt {
    Retry(String),
    Fatal(Error),
}

#[cfg(feature = "native")]
impl RemoteFile {
    /// Opens `location` with one request for its first bytes, which are cached.
    pub fn open(location: &str, options: RemoteOptions) -> Result<RemoteFile> {
        let url = http_url(location, &options.s3)?;
        let signer = s3_signer(location, &options.s3)?;
        let agent: ureq::Agent = ureq::Agent::config_builder()
            .timeout_global(Some(options.timeout))
            .http_status_as_error(false)
            .max_idle_connections_per_host(options.max_in_flight.max(1) * 2)
            .build()
            .into();
        let mut client = Client {
            location: location.to_string(),
            url,
            signer,
            len: 0,
            etag: None,
            agent,
            options,
            counters: Counters::default(),
        };
        let want = client.options.first_range.max(PAGE_BYTES);
        let (first, len, etag) = client.with_retries(|c| c.attempt_open(want))?;
        client.len = len;
        client.etag = etag;
        let cache = match &client.options.cache_dir {
            Some(dir) => DiskCache::open(dir, location, len, client.etag.as_deref(), client.options.cache_bytes)?,
            None => DiskCache::temporary(location, len)?,
        };
        cache.put(0, &first)?;
        Ok(RemoteFile {
            client,
            path: PathBuf::from(location),
            cache,
            next_offset: AtomicU64::new(u64::MAX),
            readahead_pages: AtomicU64::new(0),
            readahead_end: AtomicU64::new(0),
        })
    }

    /// The location as given (`http://…`, `s3://…`).
    pub fn location(&self) -> &str {
        &self.client.location
    }

    pub fn etag(&self) -> Option<&str> {
        self.client.etag.as_deref()
    }

    pub fn options(&self) -> &RemoteOptions {
        &self.client.options
    }

    pub fn stats(&self) -> RemoteStats {
        let c = &self.client.counters;
        RemoteStats {
            requests: c.requests.load(Ordering::Relaxed),
            bytes: c.bytes.load(Ordering::Relaxed),
            retries: c.retries.load(Ordering::Relaxed),
            cache_hit_pages: c.cache_hit_pages.load(Ordering::Relaxed),
        }
    }

    /// The local cache.
    pub fn cache(&self) -> &DiskCache {
        &self.cache
    }

    /// The whole pages `first..end` (page numbers), from the cache where present, else fetched
    /// (coalesced runs, bounded in flight) and cached. Calls `got(page, bytes)` for every run of
    /// pages it has, in no particular order; the bytes are whole pages except at the file's end.
    pub fn fetch_runs(&self, runs: &[(u64, u64)], got: impl FnMut(u64, &[u8]) -> Result<()>) -> Result<()> {
        self.fetch(runs, true, got)
    }

    /// [`Self::fetch_runs`], reading the pages already cached only when `read_cached`.
    fn fetch(
        &self,
        runs: &[(u64, u64)],
        read_cached: bool,
        mut got: impl FnMut(u64, &[u8]) -> Result<()>,
    ) -> Result<()> {
        let mut missing = Vec::new();
        for &(first, end) in runs {
            let present = self.cache.present(first, end)?;
            let mut p = first;
            while p < end {
                let here = present[(p - first) as usize];
                let mut q = p + 1;
                while q < end && present[(q - first) as usize] == here {
                    q += 1;
                }
                if here && read_cached {
                    let bytes = self.cache.get(p * PAGE_BYTES, (q * PAGE_BYTES).min(self.client.len))?;
                    self.client.counters.cache_hit_pages.fetch_add(q - p, Ordering::Relaxed);
                    got(p, &bytes)?;
                } else if !here {
                    missing.push((p, q));
                }
                p = q;
            }
        }
        let options = &self.client.options;
        let requests = coalesce(&mut missing, options.coalesce_gap / PAGE_BYTES, options.max_request / PAGE_BYTES);
        let results = std::sync::Mutex::new(Vec::with_capacity(requests.len()));
        let next = AtomicU64::new(0);
        let workers = options.max_in_flight.clamp(1, requests.len().max(1));
        std::thread::scope(|s| {
            for _ in 0..workers {
                s.spawn(|| loop {
                    let k = next.fetch_add(1, Ordering::Relaxed) as usize;
                    let Some(&(p, q)) = requests.get(k) else { break };
                    let r = self.client.fetch(p * PAGE_BYTES, (q * PAGE_BYTES).min(self.client.len));
                    let failed = r.is_err();
                    results.lock().unwrap_or_else(|e| e.into_inner()).push((p, r));
                    if failed {
                        break;
                    }
                });
            }
        });
        for (p, r) in results.into_inner().unwrap_or_else(|e| e.into_inner()) {
            let bytes = r?;
            self.cache.put(p * PAGE_BYTES, &bytes)?;
            got(p, &bytes)?;
        }
        Ok(())
    }
}

#[cfg(feature = "native")]
impl Client {
    fn with_retries<T>(&self, mut f: impl FnMut(&Self) -> std::result::Result<T, Attempt>) -> Result<T> {
        let mut delay = self.options.backoff;
        let attempts = self.options.attempts.max(1);
        for k in 1..=attempts {
            match f(self) {
                Ok(v) => return Ok(v),
                Err(Attempt::Fatal(e)) => return Err(e),
                Err(Attempt::Retry(why)) if k == attempts => {
                    return Err(Error::remote(&self.location, format!("{why} (gave up after {attempts} attempts)")))
                }
                Err(Attempt::Retry(_)) => {
                    self.counters.retries.fetch_add(1, Ordering::Relaxed);
                    std::thread::sleep(delay);
                    delay = (delay * 2).min(Duration::from_secs(2));
                }
            }
        }
        unreachable!("the last attempt returns")
    }

    fn request(&self, range: &str) -> std::result::Result<ureq::http::Response<ureq::Body>, Attempt> {
        let url = match &self.signer {
            Some(s) => s.url(),
            None => self.url.clone(),
        };
        let mut req = self.agent.get(&url).header("Range", range);
        if let Some(etag) = &self.etag {
            req = req.header("If-Match", etag);
        }
        self.counters.requests.fetch_add(1, Ordering::Relaxed);
        let resp = req.call().map_err(|e| match e {
            ureq::Error::Io(_) | ureq::Error::Timeout(_) | ureq::Error::ConnectionFailed | ureq::Error::Protocol(_) => {
                Attempt::Retry(format!("request failed: {e}"))
            }
            ureq::Error::HostNotFound => Attempt::Fatal(Error::remote(&self.location, "host not found")),
            e => Attempt::Fatal(Error::remote(&self.location, format!("request failed: {e}"))),
        })?;
        let status = resp.status().as_u16();
        match status {
            200 | 206 => Ok(resp),
            412 => Err(Attempt::Fatal(self.changed("the server refused the open-time ETag (412)"))),
            408 | 429 | 500..=599 => Err(Attempt::Retry(format!("server answered {status}"))),
            404 => Err(Attempt::Fatal(Error::remote(&self.location, "not found on the server (404)"))),
            _ => Err(Attempt::Fatal(Error::remote(&self.location, format!("server answered {status}")))),
        }
    }

    fn changed(&self, why: &str) -> Error {
        Error::remote(&self.location, format!("changed on the server while being read: {why}"))
    }

    fn check_etag(&self, resp: &ureq::http::Response<ureq::Body>) -> std::result::Result<(), Attempt> {
        let now = header(resp, "etag");
        match (&self.etag, now) {
            (Some(then), Some(now)) if *then != now => {
                Err(Attempt::Fatal(self.changed(&format!("ETag {then}, now {now}"))))
            }
            (Some(_), None) => Err(Attempt::Fatal(self.changed("the ETag disappeared"))),
            _ => Ok(()),
        }
    }

    fn attempt_open(&self, want: u64) -> std::result::Result<(Vec<u8>, u64, Option<String>), Attempt> {
        let resp = self.request(&format!("bytes=0-{}", want - 1))?;
        let etag = header(&resp, "etag");
        let status = resp.status().as_u16();
        let (len, body_len) = if status == 206 {
            let (a, b, total) =
                content_range(&resp).ok_or_else(|| self.bad_answer("206 without a valid Content-Range"))?;
            if a != 0 || b + 1 > total || (b + 1 != want.min(total)) {
                return Err(Attempt::Fatal(self.bad_range(0, want.min(total), a, b)));
            }
            (total, b + 1)
        } else {
            // 200: the whole file, acceptable only when it is no longer than what was asked.
            let n = content_length(&resp).ok_or_else(|| self.bad_answer("200 without Content-Length"))?;
            if n > want {
                return Err(Attempt::Fatal(self.ignores_range()));
            }
            (n, n)
        };
        let body = self.read_body(resp, body_len)?;
        Ok((body, len, etag))
    }

    fn bad_answer(&self, why: &str) -> Attempt {
        Attempt::Fatal(Error::remote(&self.location, format!("bad answer from the server: {why}")))
    }

    fn bad_range(&self, start: u64, end: u64, a: u64, b: u64) -> Error {
        Error::remote(
            &self.location,
            format!("the server sent bytes {a}-{b} for the range {start}-{}", end.saturating_sub(1)),
        )
    }

    fn ignores_range(&self) -> Error {
        Error::remote(
            &self.location,
            "the server ignores Range requests (answered 200 with the whole file); serve it with one that \
             supports byte ranges (e.g. `relief serve`)",
        )
    }

    fn read_body(&self, resp: ureq::http::Response<ureq::Body>, n: u64) -> std::result::Result<Vec<u8>, Attempt> {
        let mut body = vec![0u8; n as usize];
        let mut reader = resp.into_body().into_with_config().limit(n.saturating_add(1)).reader();
        let mut got = 0usize;
        while got < body.len() {
            match reader.read(&mut body[got..]) {
                Ok(0) => break,
                Ok(k) => got += k,
                Err(e) => {
                    self.counters.bytes.fetch_add(got as u64, Ordering::Relaxed);
                    return Err(Attempt::Retry(format!("short answer: {got} of {n} bytes ({e})")));
                }
            }
        }
        self.counters.bytes.fetch_add(got as u64, Ordering::Relaxed);
        if got < body.len() {
            return Err(Attempt::Retry(format!("short answer: {got} of {n} bytes")));
        }
        Ok(body)
    }

    /// Bytes `start..end` in one request (retried), validated.
    fn fetch(&self, start: u64, end: u64) -> Result<Vec<u8>> {
        if start >= end || end > self.len {
            return Err(Error::Truncated { path: PathBuf::from(&self.location), expected: end, found: self.len });
        }
        self.with_retries(|f| {
            let resp = f.request(&format!("bytes={start}-{}", end - 1))?;
            f.check_etag(&resp)?;
            if resp.status().as_u16() == 200 {
                if start == 0 && end == f.len {
                    let body = f.read_body(resp, end)?;
                    return Ok(body);
                }
                return Err(Attempt::Fatal(f.ignores_range()));
            }
            let (a, b, total) =
                content_range(&resp).ok_or_else(|| f.bad_answer("206 without a valid Content-Range"))?;
            if total != f.len {
                return Err(Attempt::Fatal(f.changed(&format!("length {} bytes, now {total}", f.len))));
            }
            if a != start || b + 1 != end {
                return Err(Attempt::Fatal(f.bad_range(start, end, a, b)));
            }
            let body = f.read_body(resp, end - start)?;
            Ok(body)
        })
    }
}

/// Merges sorted-or-not page runs into requests: runs closer than `gap` pages join (the pages
/// between them are fetched too), no request longer than `max` pages.
pub fn coalesce(runs: &mut [(u64, u64)], gap: u64, max: u64) -> Vec<(u64, u64)> {
    runs.sort_unstable();
    let mut out: Vec<(u64, u64)> = Vec::new();
    for &(a, b) in runs.iter() {
        match out.last_mut() {
            Some(last) if a <= last.1 + gap && b.max(last.1) - last.0 <= max.max(1) => last.1 = last.1.max(b),
            _ => out.push((a, b)),
        }
    }
    out
}

#[cfg(feature = "native")]
fn header(resp: &ureq::http::Response<ureq::Body>, name: &str) -> Option<String> {
    resp.headers().get(name).and_then(|v| v.to_str().ok()).map(str::to_string)
}

#[cfg(feature = "native")]
fn content_length(resp: &ureq::http::Response<ureq::Body>) -> Option<u64> {
    header(resp, "content-length")?.trim().parse().ok()
}

#[cfg(feature = "native")]
/// `Content-Range: bytes a-b/len` → (a, b, len).
fn content_range(resp: &ureq::http::Response<ureq::Body>) -> Option<(u64, u64, u64)> {
    let v = header(resp, "content-range")?;
    let rest = v.trim().strip_prefix("bytes ")?;
    let (range, total) = rest.split_once('/')?;
    let (a, b) = range.split_once('-')?;
    let (a, b, total) = (a.trim().parse().ok()?, b.trim().parse().ok()?, total.trim().parse().ok()?);
    (a <= b && b < total).then_some((a, b, total))
}

#[cfg(feature = "native")]
impl Source for RemoteFile {
    fn path(&self) -> &Path {
        &self.path
    }

    fn len(&self) -> u64 {
        self.client.len
    }

    fn kind(&self) -> SourceKind {
        SourceKind::Read
    }

    fn read_at(&self, offset: u64, buf: &mut [u8]) -> Result<()> {
        check_range(&self.path, self.client.len, offset, buf.len())?;
        let end = offset + buf.len() as u64;
        if buf.is_empty() {
            return Ok(());
        }
        let (first, last) = (offset / PAGE_BYTES, (end - 1) / PAGE_BYTES);
        // A reader going through the file in order (a whole-file pass, re-laying out) gets the
        // pages after its read too, in ever larger requests, instead of one request per read.
        let sequential = self.next_offset.swap(end, Ordering::Relaxed) == offset;
        if !sequential {
            self.readahead_pages.store(0, Ordering::Relaxed);
        } else if last + 1 > self.readahead_end.load(Ordering::Relaxed) {
            // Past the window fetched ahead: the read's pages and the next window (twice the
            // last, at most one largest request), missing ones only, in one round of requests.
            let max = (self.client.options.max_request / PAGE_BYTES).max(1);
            let ahead = (self.readahead_pages.load(Ordering::Relaxed) * 2).clamp(4, max);
            self.readahead_pages.store(ahead, Ordering::Relaxed);
            let end_page = (last + 1 + ahead).min(self.client.len.div_ceil(PAGE_BYTES));
            self.readahead_end.store(end_page, Ordering::Relaxed);
            self.fetch(&[(first, end_page)], false, |_, _| Ok(()))?;
        }
        self.fetch_runs(&[(first, last + 1)], |p, bytes| {
            // Copy the overlap of the run [p·page, p·page + len) with [offset, end).
            let run_start = p * PAGE_BYTES;
            let (a, b) = (offset.max(run_start), end.min(run_start + bytes.len() as u64));
            if a < b {
                buf[(a - offset) as usize..(b - offset) as usize]
                    .copy_from_slice(&bytes[(a - run_start) as usize..(b - run_start) as usize]);
            }
            Ok(())
        })
    }

    fn advise_random(&self) -> Result<()> {
        Ok(())
    }

    fn resident_pages(&self, first: u64, end: u64) -> Result<Vec<bool>> {
        self.cache.present(first, end)
    }

    fn read_page_runs(&self, runs: &[(u64, u64)], got: &mut dyn FnMut(u64, &[u8]) -> Result<()>) -> Result<()> {
        self.fetch_runs(runs, got)
    }

    fn network(&self) -> Option<RemoteStats> {
        Some(self.stats())
    }

    /// Drops nothing: the local cache is what makes a remote file cheap to read again.
    fn evict(&self) -> Result<()> {
        Ok(())
    }
}

#[cfg(feature = "native")]
/// The local cache of a remote file's pages: a sparse file of the remote file's length (pages at
/// their own offsets) and a map of one byte per page (1: present), in a directory named by the
/// location's hash, with the length and ETag it holds pages of.
///
/// Safe to share between processes: a page is written, synced, and only then marked present, and
/// two processes write the same bytes for the same page (same length and ETag). A cache for
/// another version of the file is replaced whole (a new directory renamed into place). The bound
/// is kept by removing the least recently opened files' caches when one is opened, and by no
/// longer caching (only fetching) once this file alone would pass it.
pub struct DiskCache {
    dir: PathBuf,
    data: File,
    have: File,
    pages: u64,
    limit: u64,
    written: AtomicU64,
    _temp: Option<tempfile::TempDir>,
}

#[cfg(feature = "native")]
#[derive(serde::Serialize, serde::Deserialize, PartialEq, Debug)]
struct CacheMeta {
    location: String,
    len: u64,
    etag: Option<String>,
}

#[cfg(feature = "native")]
impl DiskCache {
    /// A cache of a `len`-byte file in a temporary directory, removed with it.
    fn temporary(location: &str, len: u64) -> Result<DiskCache> {
        let temp = tempfile::Builder::new()
            .prefix("relief-remote-")
            .tempdir()
            .map_err(|e| Error::remote(location, format!("cannot make a temporary cache: {e}")))?;
        let dir = temp.path().to_path_buf();
        let (data, have) = Self::files(&dir, true)?;
        data.set_len(len).at(&dir.join("data"))?;
        have.set_len(len.div_ceil(PAGE_BYTES)).at(&dir.join("have"))?;
        Ok(DiskCache {
            dir,
            data,
            have,
            pages: len.div_ceil(PAGE_BYTES),
            limit: u64::MAX,
            written: AtomicU64::new(0),
            _temp: Some(temp),
        })
    }

    fn files(dir: &Path, create: bool) -> Result<(File, File)> {
        let open = |name: &str| {
            let p = dir.join(name);
            std::fs::OpenOptions::new().read(true).write(true).create(create).truncate(false).open(&p).at(&p)
        };
        Ok((open("data")?, open("have")?))
    }

    /// The cache of `location` (of `len` bytes and `etag`) under `root`, made or replaced as needed.
    pub fn open(root: &Path, location: &str, len: u64, etag: Option<&str>, limit: u64) -> Result<DiskCache> {
        std::fs::create_dir_all(root).at(root)?;
        let key = format!("{:016x}", xxhash_rust::xxh3::xxh3_64(location.as_bytes()));
        let dir = root.join(&key);
        let meta = CacheMeta { location: location.into(), len, etag: etag.map(str::to_string) };
        let current =
            std::fs::read(dir.join("meta.json")).ok().and_then(|b| serde_json::from_slice::<CacheMeta>(&b).ok());
        if current.as_ref() != Some(&meta) {
            // Build the new cache beside it and rename it into place, so a reader never sees a
            // meta of one version with pages of another.
            let tmp = root.join(format!("{key}.new-{}", std::process::id()));
            let _ = std::fs::remove_dir_all(&tmp);
            std::fs::create_dir_all(&tmp).at(&tmp)?;
            let (data, have) = Self::files(&tmp, true)?;
            data.set_len(len).at(&tmp.join("data"))?;
            have.set_len(len.div_ceil(PAGE_BYTES)).at(&tmp.join("have"))?;
            let m = serde_json::to_vec(&meta).map_err(|e| Error::remote(location, format!("cache meta: {e}")))?;
            std::fs::write(tmp.join("meta.json"), m).at(&tmp.join("meta.json"))?;
            if dir.exists() {
                let old = root.join(format!("{key}.old-{}", std::process::id()));
                let _ = std::fs::rename(&dir, &old);
                let _ = std::fs::remove_dir_all(&old);
            }
            if std::fs::rename(&tmp, &dir).is_err() {
                // Another process put its cache there first: use it if it is of this version.
                let _ = std::fs::remove_dir_all(&tmp);
                let theirs = std::fs::read(dir.join("meta.json"))
                    .ok()
                    .and_then(|b| serde_json::from_slice::<CacheMeta>(&b).ok());
                if theirs.as_ref() != Some(&meta) {
                    return Err(Error::remote(
                        location,
                        format!("cache {} is in use by another version", dir.display()),
                    ));
                }
            }
        } else {
            // Mark as recently used (the bound removes the least recently opened first).
            let _ =
                std::fs::File::open(dir.join("meta.json")).and_then(|f| f.set_modified(std::time::SystemTime::now()));
        }
        let (data, have) = Self::files(&dir, false)?;
        Self::keep_bound(root, &key, limit);
        let written = have_count(&have) * PAGE_BYTES;
        Ok(DiskCache {
            dir,
            data,
            have,
            pages: len.div_ceil(PAGE_BYTES),
            limit,
            written: AtomicU64::new(written),
            _temp: None,
        })
    }

    /// Removes the least recently opened caches under `root` (never `keep`) while they hold more
    /// than `limit` bytes together.
    fn keep_bound(root: &Path, keep: &str, limit: u64) {
        let Ok(entries) = std::fs::read_dir(root) else { return };
        let mut caches: Vec<(std::time::SystemTime, PathBuf, u64)> = entries
            .flatten()
            .filter(|e| e.file_name().to_string_lossy().len() == 16)
            .filter_map(|e| {
                let dir = e.path();
                let used = std::fs::metadata(dir.join("meta.json")).and_then(|m| m.modified()).ok()?;
                let have = File::open(dir.join("have")).ok()?;
                Some((used, dir, have_count(&have) * PAGE_BYTES))
            })
            .collect();
        let mut total: u64 = caches.iter().map(|c| c.2).sum();
        caches.sort();
        for (_, dir, bytes) in caches {
            if total <= limit {
                break;
            }
            if dir.file_name().is_some_and(|n| n.to_string_lossy() == keep) {
                continue;
            }
            if std::fs::remove_dir_all(&dir).is_ok() {
                total -= bytes;
            }
        }
    }

    /// The cache's directory.
    pub fn dir(&self) -> &Path {
        &self.dir
    }

    /// Whether page `p` is present.
    pub fn has(&self, p: u64) -> Result<bool> {
        Ok(self.present(p, p + 1)?[0])
    }

    /// Which of pages `first..end` are present (read from the map each time, in one read, so
    /// pages another process fetched count); pages past the file's end are not.
    pub fn present(&self, first: u64, end: u64) -> Result<Vec<bool>> {
        let mut map = vec![0u8; end.saturating_sub(first) as usize];
        let known = self.pages.clamp(first, end.max(first)) - first;
        self.have.read_exact_at(&mut map[..known as usize], first).at(&self.dir.join("have"))?;
        Ok(map.iter().map(|&b| b == 1).collect())
    }

    /// Bytes `start..end` (present pages).
    pub fn get(&self, start: u64, end: u64) -> Result<Vec<u8>> {
        let mut v = vec![0u8; (end - start) as usize];
        self.data.read_exact_at(&mut v, start).at(&self.dir.join("data"))?;
        Ok(v)
    }

    /// Stores whole pages from `start` (page-aligned): written and synced before they are marked
    /// present. Past the bound nothing more is stored.
    fn put(&self, start: u64, bytes: &[u8]) -> Result<()> {
        debug_assert_eq!(start % PAGE_BYTES, 0);
        if bytes.is_empty() || self.written.load(Ordering::Relaxed) + bytes.len() as u64 > self.limit {
            return Ok(());
        }
        let data = self.dir.join("data");
        self.data.write_all_at(bytes, start).at(&data)?;
        self.data.sync_data().at(&data)?;
        let pages = (bytes.len() as u64).div_ceil(PAGE_BYTES);
        self.have.write_all_at(&vec![1u8; pages as usize], start / PAGE_BYTES).at(&self.dir.join("have"))?;
        self.written.fetch_add(pages * PAGE_BYTES, Ordering::Relaxed);
        Ok(())
    }

    /// Pages present.
    pub fn present_pages(&self) -> u64 {
        have_count(&self.have)
    }
}

#[cfg(feature = "native")]
fn have_count(have: &File) -> u64 {
    let mut buf = vec![0u8; 1 << 16];
    let (mut at, mut n) = (0u64, 0u64);
    while let Ok(k) = have.read_at(&mut buf, at) {
        if k == 0 {
            break;
        }
        n += buf[..k].iter().filter(|&&b| b == 1).count() as u64;
        at += k as u64;
    }
    n
}

#[cfg(all(test, feature = "native"))]
mod tests {
    use super::*;

    #[test]
    fn coalescing_merges_close_runs_up_to_the_cap() {
        let mut runs = vec![(10, 12), (0, 2), (3, 5), (40, 41)];
        assert_eq!(coalesce(&mut runs, 1, 100), vec![(0, 5), (10, 12), (40, 41)]);
        let mut runs = vec![(0, 2), (3, 5), (6, 9)];
        assert_eq!(coalesce(&mut runs, 1, 6), vec![(0, 5), (6, 9)]);
        assert!(coalesce(&mut [], 1, 6).is_empty());
    }

    #[test]
    fn s3_locations_go_through_their_endpoint() {
        let aws = S3Config { region: "eu-west-1".into(), ..Default::default() };
        let minio = S3Config { endpoint: Some("http://127.0.0.1:9000/".into()), ..aws.clone() };
        assert_eq!(http_url("http://h/x", &aws).unwrap(), "http://h/x");
        assert_eq!(http_url("s3://b/dir/t.relief", &aws).unwrap(), "https://b.s3.eu-west-1.amazonaws.com/dir/t.relief");
        assert_eq!(http_url("s3://b/t.relief", &minio).unwrap(), "http://127.0.0.1:9000/b/t.relief");
        assert!(http_url("s3://bucket", &aws).unwrap_err().to_string().contains("s3://BUCKET/KEY"));
        assert!(http_url("ftp://x", &aws).is_err());
        assert!(is_remote(Path::new("https://a/b")) && !is_remote(Path::new("/tmp/http:/x")));
    }

    #[test]
    fn s3_requests_are_presigned_only_with_credentials() {
        let mut s3 =
            S3Config { endpoint: Some("http://127.0.0.1:9000".into()), region: "eu-west-1".into(), credentials: None };
        assert!(s3_signer("s3://b/t.relief", &s3).unwrap().is_none(), "no credentials: unsigned");
        s3.credentials = Some(("AKIDEXAMPLE".into(), "secret".into(), None));
        assert!(s3_signer("http://h/t.relief", &s3).unwrap().is_none(), "only s3:// is signed");
        let url = s3_signer("s3://b/t.relief", &s3).unwrap().unwrap().url();
        assert!(url.starts_with("http://127.0.0.1:9000/b/t.relief?"), "{url}");
        for part in [
            "X-Amz-Algorithm=AWS4-HMAC-SHA256",
            "X-Amz-Credential=AKIDEXAMPLE%2F",
            "%2Feu-west-1%2Fs3%2Faws4_request",
            "X-Amz-Expires=900",
            "X-Amz-Signature=",
        ] {
            assert!(url.contains(part), "{part} in {url}");
        }
        assert!(!url.contains("secret"), "the secret never travels");
        s3.credentials = Some(("AKIDEXAMPLE".into(), "secret".into(), Some("TOKEN".into())));
        assert!(s3_signer("s3://b/t.relief", &s3).unwrap().unwrap().url().contains("X-Amz-Security-Token=TOKEN"));
        assert!(!format!("{s3:?}").contains("secret"), "Debug leaves the secret out");
    }
}

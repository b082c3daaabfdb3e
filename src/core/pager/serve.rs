//! A small static file server over HTTP/1.1 with byte ranges (RFC 9110 §14), built on `std::net`
//! and one thread per connection. It exists for two reasons:
//!
//! - **the test suite** reads remote terrains ([`super::remote`]) from it on the loopback, with an
//!   injected per-request latency and injected faults ([`Faults`]: dropped connections, 503s,
//!   short bodies, a server that ignores `Range`), so retries, validation and coalescing are
//!   tested against a real socket and without the network;
//! - **`relief serve`** serves terrain files to users and benchmarks, with `--latency-ms` to
//!   emulate an object store's round trip.
//!
//! What it answers:
//!
//! - `GET` and `HEAD` of the configured names; another path is 404, another method 405.
//! - Every request opens and stats the file anew, so a file replaced on disk (renamed over) is
//!   served with its new length and ETag from the next request on. The ETag is the quoted hex of
//!   xxh3 over the length, the modification time in nanoseconds and the inode: it changes
//!   whenever the file is replaced. Answers carry `Content-Length`, `ETag`, `Accept-Ranges: bytes`
//!   and `Last-Modified`.
//! - `Range: bytes=a-b`, `bytes=a-` and `bytes=-n`: a satisfiable range is a 206 with
//!   `Content-Range: bytes a-b/len`; a range set none of whose ranges is satisfiable is a 416 with
//!   `Content-Range: bytes */len`. Of several ranges (`bytes=0-9,20-29`) only the first
//!   satisfiable one is sent, as a single-part 206 (no `multipart/byteranges`): its
//!   `Content-Range` says which. A `Range` of another unit or of invalid syntax is ignored (200,
//!   the whole file), as is a `Range` on a `HEAD` (ranges are defined for `GET` only) and one
//!   whose `If-Range` is not the current ETag.
//! - Browsers (the web viewer, `src/web`): every answer allows any origin to read it and its
//!   `Content-Range`, `Content-Length` and `ETag` (CORS); an `OPTIONS` preflight is a 204 that
//!   allows `GET`/`HEAD` with `Range`, `If-Match` and `If-Range`. `Content-Type` follows the
//!   name's extension (`.html`, `.js`, `.wasm`, `.png`, `.json`; else octets); `/` is
//!   `index.html` where one is served.
//! - Every `GET` and `HEAD` is logged ([`Server::log`]: name, status, byte range), for tests that
//!   check what a client asked.
//! - `If-Match`: when present and none of its tags is the current ETag (strong comparison), 412.
//! - Keep-alive: requests are read one after another on a connection (pipelining works) until
//!   the client closes or asks `Connection: close` (HTTP/1.0: unless it asks `keep-alive`).
//! - A request head over 16 KiB is a 431, a malformed one a 400; both close the connection.
//! - With [`ServeOptions::uploads`] (`relief serve --uploads DIR`), S3-style uploads into that
//!   directory (a single `PUT`, or a multipart upload; see [`upload`]): a stand-in bucket for
//!   sharded conversion's tests. Uploaded objects are then served like the configured names.
//!
//! Bodies are read with positioned reads in chunks of at most 1 MiB, never the whole file. The
//! latency is slept after a request is read and before its answer is written, in the connection's
//! own thread: every request costs one latency, and concurrent connections wait concurrently.
//!
//! Not a production server: no TLS, no idle timeout (a connection lasts until its client closes
//! it or the server stops), no limit on connections.

use std::collections::HashMap;
use std::fs::File;
use std::io::{self, BufRead, BufReader, Read, Write};
use std::net::{IpAddr, Ipv4Addr, Ipv6Addr, Shutdown, SocketAddr, TcpListener, TcpStream};
use std::os::unix::fs::{FileExt, MetadataExt};
use std::path::PathBuf;
use std::sync::atomic::{AtomicBool, AtomicU32, AtomicU64, Ordering};
use std::sync::{Arc, Mutex, MutexGuard};
use std::thread::JoinHandle;
use std::time::{Duration, SystemTime, UNIX_EPOCH};

use crate::error::{Error, Result};

/// The longest request head (request line and headers) read: 16 KiB.
pub const MAX_HEAD_BYTES: usize = 16 * 1024;

/// Bytes read from the file and written to the socket at a time, at most.
const CHUNK_BYTES: u64 = 1 << 20;

/// A request body (`Content-Length`) read and discarded to keep a connection; a longer one, or a
/// chunked one, is answered and the connection closed.
const MAX_DISCARDED_BODY: u64 = 64 * 1024;

/// The largest upload body taken (an object or one part of a multipart upload).
const MAX_UPLOAD_BODY: u64 = 64 << 20;

/// Faults to inject, shared with the server while it runs ([`Server::faults`]). The counts are
/// "the next N requests": each `GET` or `HEAD` takes at most one fault, trying `drop_next`, then
/// `error_next`, then `short_next`, and decrements the one it takes (atomically, so concurrent
/// requests never take more than were asked).
#[derive(Debug, Default)]
pub struct Faults {
    /// Read the request, then close the connection without any response.
    pub drop_next: AtomicU32,
    /// Answer `503 Service Unavailable` with `Content-Length: 0`.
    pub error_next: AtomicU32,
    /// Send the headers of the answer (a 206, or a 200 without `Range`), which promise the whole
    /// body, then only half of it, and close the connection. Taken only by an answer with a body
    /// (a `GET` of one byte or more).
    pub short_next: AtomicU32,
    /// While set, answer every `GET` with 200 and the whole file, ignoring `Range`.
    pub ignore_range: AtomicBool,
}

impl Faults {
    /// Takes one fault from `counter`: decrements it and says true if it was above zero.
    fn take(counter: &AtomicU32) -> bool {
        counter.fetch_update(Ordering::SeqCst, Ordering::SeqCst, |n| n.checked_sub(1)).is_ok()
    }
}

/// How a [`Server`] answers.
#[derive(Debug, Clone, Default)]
pub struct ServeOptions {
    /// Slept before each response (after its request is read), per request.
    pub latency: Duration,
    /// Faults to inject; keep a clone of the `Arc` (or use [`Server::faults`]) to set them.
    pub faults: Arc<Faults>,
    /// A directory taking uploads in the S3 style (see [`upload`]): `PUT` of an object, and the
    /// multipart upload (create, parts, complete, abort); objects uploaded there are served.
    pub uploads: Option<PathBuf>,
}

/// A running server; stops when dropped ([`Server::stop`]).
pub struct Server {
    addr: SocketAddr,
    shared: Arc<Shared>,
    accept: Option<JoinHandle<()>>,
}

/// What the accept thread, the connections and the handle share.
struct Shared {
    files: HashMap<String, PathBuf>,
    uploads: Option<PathBuf>,
    upload_ids: AtomicU64,
    latency: Duration,
    faults: Arc<Faults>,
    requests: AtomicU64,
    bytes_sent: AtomicU64,
    connections: AtomicU64,
    stop: AtomicBool,
    /// The open connections: a handle on each socket (to shut it down on stop) and its thread.
    open: Mutex<HashMap<u64, (TcpStream, JoinHandle<()>)>>,
    log: Mutex<Vec<Logged>>,
}

/// One `GET` or `HEAD` as answered.
#[derive(Clone, Debug, PartialEq, Eq)]
pub struct Logged {
    /// The name asked for (`""` for `/`).
    pub name: String,
    pub method: String,
    pub status: u16,
    /// Body bytes `[start, end)` of the file sent (`None`: no body from the file).
    pub range: Option<(u64, u64)>,
}

impl Shared {
    fn note(&self, req: &Request, status: u16, range: Option<(u64, u64)>) {
        let entry = Logged { name: req.name.clone(), method: req.method.clone(), status, range };
        self.log.lock().unwrap_or_else(|e| e.into_inner()).push(entry);
    }

    fn open(&self) -> MutexGuard<'_, HashMap<u64, (TcpStream, JoinHandle<()>)>> {
        // A panic while holding the lock leaves the map usable: take it anyway.
        self.open.lock().unwrap_or_else(|e| e.into_inner())
    }
}

impl Server {
    /// Serves `files` (URL path name without leading slash -> file on disk) on `bind` (port 0 =
    /// any free port). Each file must be a readable regular file now; it is opened anew for
    /// every request. Names may hold `/`; other characters outside `A-Za-z0-9-._~` are
    /// percent-encoded in URLs ([`Server::url`]) and decoded from requests.
    pub fn start(files: Vec<(String, PathBuf)>, bind: SocketAddr, options: ServeOptions) -> Result<Server> {
        let mut map = HashMap::with_capacity(files.len());
        for (name, path) in files {
            if name.is_empty() || name.starts_with('/') {
                return Err(Error::InvalidArgument(format!(
                    "serve: the name for {} must be non-empty and without a leading '/', got '{name}'",
                    path.display()
                )));
            }
            let meta = std::fs::metadata(&path).map_err(|e| Error::io(&path, e))?;
            if !meta.is_file() {
                return Err(Error::InvalidArgument(format!("serve: {} is not a regular file", path.display())));
            }
            File::open(&path).map_err(|e| Error::io(&path, e))?;
            if let Some(other) = map.insert(name.clone(), path) {
                return Err(Error::InvalidArgument(format!(
                    "serve: two files under the name '{name}' (one is {})",
                    other.display()
                )));
            }
        }
        // An address is what failed to bind: it stands where the error type wants a path.
        let listener = TcpListener::bind(bind).map_err(|e| Error::io(bind.to_string(), e))?;
        let addr = listener.local_addr().map_err(|e| Error::io(bind.to_string(), e))?;
        let shared = Arc::new(Shared {
            files: map,
            uploads: options.uploads,
            upload_ids: AtomicU64::new(0),
            latency: options.latency,
            faults: options.faults,
            requests: AtomicU64::new(0),
            bytes_sent: AtomicU64::new(0),
            connections: AtomicU64::new(0),
            stop: AtomicBool::new(false),
            open: Mutex::new(HashMap::new()),
            log: Mutex::new(Vec::new()),
        });
        let s = shared.clone();
        let accept = std::thread::Builder::new()
            .name("relief-serve".into())
            .spawn(move || accept_loop(listener, s))
            .map_err(|e| Error::io(addr.to_string(), e))?;
        Ok(Server { addr, shared, accept: Some(accept) })
    }

    /// The address listened on (with the port chosen when `bind` asked for port 0).
    pub fn addr(&self) -> SocketAddr {
        self.addr
    }

    /// The URL of `name`: `http://127.0.0.1:PORT/name` (the loopback when listening on every
    /// interface), with `name` percent-encoded.
    pub fn url(&self, name: &str) -> String {
        format!("http://{}/{}", connect_addr(self.addr), percent_encode(name))
    }

    /// `GET` and `HEAD` requests answered or faulted so far (malformed requests and other methods
    /// are not counted). Counted before the answer is written: a client that has its answer sees
    /// it counted.
    pub fn requests(&self) -> u64 {
        self.shared.requests.load(Ordering::SeqCst)
    }

    /// Bytes of file content sent in bodies so far (headers and error messages not counted).
    /// Counted as each chunk is handed to the socket, before it is written.
    pub fn bytes_sent(&self) -> u64 {
        self.shared.bytes_sent.load(Ordering::SeqCst)
    }

    /// Connections accepted so far (keep-alive reuse shows as fewer connections than requests).
    pub fn connections(&self) -> u64 {
        self.shared.connections.load(Ordering::SeqCst)
    }

    /// Every `GET` and `HEAD` answered so far, in the order answered (faulted ones too, with
    /// the status sent, or 0 for a dropped connection).
    pub fn log(&self) -> Vec<Logged> {
        self.shared.log.lock().unwrap_or_else(|e| e.into_inner()).clone()
    }

    /// The faults to inject, shared with the running server.
    pub fn faults(&self) -> &Arc<Faults> {
        &self.shared.faults
    }

    /// Stops: no more connections are accepted, the open ones are shut down, and the threads are
    /// joined. Dropping the server does the same.
    pub fn stop(self) {
        drop(self)
    }

    fn shutdown(&mut self) {
        let Some(accept) = self.accept.take() else { return };
        self.shared.stop.store(true, Ordering::SeqCst);
        // Wake the accept thread, blocked in accept(), with a connection of our own.
        let woken = TcpStream::connect_timeout(&connect_addr(self.addr), Duration::from_secs(1)).is_ok();
        if woken {
            let _ = accept.join();
        }
        // Otherwise it stays blocked (detached) and ends at the next connection it gets.
        let open = std::mem::take(&mut *self.shared.open());
        for (stream, _) in open.values() {
            let _ = stream.shutdown(Shutdown::Both);
        }
        for (_, (_, thread)) in open {
            let _ = thread.join();
        }
    }
}

impl Drop for Server {
    fn drop(&mut self) {
        self.shutdown();
    }
}

impl std::fmt::Debug for Server {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("Server")
            .field("addr", &self.addr)
            .field("files", &self.shared.files.len())
            .field("requests", &self.requests())
            .finish()
    }
}

/// Where to connect to reach a server listening on `addr`: the loopback for an unspecified
/// address.
fn connect_addr(addr: SocketAddr) -> SocketAddr {
    match addr.ip() {
        IpAddr::V4(ip) if ip.is_unspecified() => SocketAddr::new(Ipv4Addr::LOCALHOST.into(), addr.port()),
        IpAddr::V6(ip) if ip.is_unspecified() => SocketAddr::new(Ipv6Addr::LOCALHOST.into(), addr.port()),
        _ => addr,
    }
}

fn accept_loop(listener: TcpListener, shared: Arc<Shared>) {
    let mut next_id = 0u64;
    loop {
        let conn = listener.accept();
        if shared.stop.load(Ordering::SeqCst) {
            return;
        }
        match conn {
            Ok((stream, _)) => {
                shared.connections.fetch_add(1, Ordering::SeqCst);
                next_id += 1;
                spawn_connection(&shared, stream, next_id);
            }
            Err(e) => match e.kind() {
                io::ErrorKind::ConnectionAborted | io::ErrorKind::Interrupted | io::ErrorKind::ConnectionReset => {}
                // Out of descriptors or memory: wait for connections to end rather than spin.
                _ => std::thread::sleep(Duration::from_millis(10)),
            },
        }
    }
}

fn spawn_connection(shared: &Arc<Shared>, stream: TcpStream, id: u64) {
    let Ok(handle) = stream.try_clone() else { return };
    // Held across the spawn, so the thread's own removal comes after its insertion.
    let mut open = shared.open();
    let s = shared.clone();
    let spawned = std::thread::Builder::new().name("relief-serve-conn".into()).spawn(move || {
        serve_connection(&s, &stream);
        s.open().remove(&id);
    });
    if let Ok(thread) = spawned {
        open.insert(id, (handle, thread));
    }
}

/// What to do with a connection after an answer.
enum Next {
    KeepAlive,
    /// Close after the answer: shut down our side and drain what the client still sends.
    Close,
    /// Close at once (a dropped-connection fault).
    Drop,
}

fn serve_connection(shared: &Shared, stream: &TcpStream) {
    let _ = stream.set_nodelay(true);
    let mut reader = BufReader::new(stream);
    let mut out = stream;
    loop {
        let req = match read_request(&mut reader) {
            Ok(Some(req)) => req,
            Ok(None) | Err(HeadError::Io) => return,
            Err(HeadError::TooLarge) => {
                let _ =
                    simple(&mut out, 431, "Request Header Fields Too Large", false, false, "request head over 16 KiB");
                return close(stream);
            }
            Err(HeadError::Bad(why)) => {
                let _ = simple(&mut out, 400, "Bad Request", false, false, why);
                return close(stream);
            }
        };
        let mut keep = req.keep_alive();
        if let (Some(dir), "PUT" | "POST" | "DELETE") = (&shared.uploads, req.method.as_str()) {
            // An upload: its body, whole (parts are a few MiB).
            let n = match req.header("content-length").map(|v| v.trim().parse::<u64>()) {
                None => 0,
                Some(Ok(n)) if n <= MAX_UPLOAD_BODY => n,
                _ => {
                    let _ = simple(
                        &mut out,
                        413,
                        "Content Too Large",
                        false,
                        false,
                        "upload bodies need a Content-Length of at most 64 MiB",
                    );
                    return close(stream);
                }
            };
            let mut body = Vec::with_capacity(n as usize);
            match io::copy(&mut (&mut reader).take(n), &mut body) {
                Ok(got) if got == n => {}
                _ => return,
            }
            if upload(shared, dir, &req, &body, keep, &mut out).is_err() {
                return;
            }
            if !keep {
                return close(stream);
            }
            continue;
        }
        // The body of a request we do not use: read past it to keep the connection in step.
        if req.header("transfer-encoding").is_some() {
            keep = false;
        } else if let Some(v) = req.header("content-length") {
            match v.trim().parse::<u64>() {
                Ok(0) => {}
                Ok(n) if n <= MAX_DISCARDED_BODY => match io::copy(&mut (&mut reader).take(n), &mut io::sink()) {
                    Ok(got) if got == n => {}
                    _ => return,
                },
                Ok(_) => keep = false,
                Err(_) => {
                    let _ = simple(&mut out, 400, "Bad Request", false, false, "invalid Content-Length");
                    return close(stream);
                }
            }
        }
        if !shared.latency.is_zero() {
            std::thread::sleep(shared.latency);
        }
        match answer(shared, &req, keep, &mut out) {
            Ok(Next::KeepAlive) => {}
            Ok(Next::Close) => return close(stream),
            Ok(Next::Drop) => {
                let _ = stream.shutdown(Shutdown::Both);
                return;
            }
            Err(_) => return,
        }
    }
}

/// Closes our side and reads (briefly) what the client still sends, so that unread bytes do not
/// turn the close into a reset that could destroy the answer before the client reads it.
fn close(stream: &TcpStream) {
    let _ = stream.shutdown(Shutdown::Write);
    let _ = stream.set_read_timeout(Some(Duration::from_millis(200)));
    let mut buf = [0u8; 4096];
    let mut left = 64 * 1024;
    let mut s = stream;
    while left > 0 {
        match s.read(&mut buf) {
            Ok(0) | Err(_) => break,
            Ok(n) => left -= n.min(left),
        }
    }
}

/// A parsed request head.
#[derive(Debug)]
struct Request {
    method: String,
    /// The decoded path without its leading '/' (and without a query).
    name: String,
    /// The query, undecoded, without its '?'.
    query: String,
    /// The minor version of HTTP/1.x.
    minor: u8,
    /// Names lower-cased, values trimmed.
    headers: Vec<(String, String)>,
}

impl Request {
    fn header(&self, name: &str) -> Option<&str> {
        self.headers.iter().find(|(n, _)| n == name).map(|(_, v)| v.as_str())
    }

    /// Whether the client keeps the connection: HTTP/1.1 unless `Connection: close`, HTTP/1.0
    /// only with `Connection: keep-alive`.
    fn keep_alive(&self) -> bool {
        let has = |token: &str| {
            self.headers
                .iter()
                .filter(|(n, _)| n == "connection")
                .any(|(_, v)| v.split(',').any(|t| t.trim().eq_ignore_ascii_case(token)))
        };
        if self.minor >= 1 {
            !has("close")
        } else {
            has("keep-alive")
        }
    }
}

#[derive(Debug)]
enum HeadError {
    /// The connection failed or ended inside a head.
    Io,
    TooLarge,
    Bad(&'static str),
}

/// Reads one request head; `None` when the connection is closed before its first byte.
fn read_request(reader: &mut impl BufRead) -> Result<Option<Request>, HeadError> {
    let mut lines: Vec<Vec<u8>> = Vec::new();
    let mut total = 0usize;
    loop {
        let mut line = Vec::new();
        let limit = (MAX_HEAD_BYTES - total) as u64;
        let n = reader.take(limit).read_until(b'\n', &mut line).map_err(|_| HeadError::Io)?;
        total += n;
        if !line.ends_with(b"\n") {
            if total >= MAX_HEAD_BYTES {
                return Err(HeadError::TooLarge);
            }
            if total == 0 {
                return Ok(None);
            }
            return Err(HeadError::Io);
        }
        line.pop();
        if line.last() == Some(&b'\r') {
            line.pop();
        }
        if line.is_empty() {
            // Empty lines before the request line are ignored (RFC 9112 §2.2).
            if lines.is_empty() {
                continue;
            }
            return parse_head(&lines).map(Some);
        }
        lines.push(line);
    }
}

fn is_tchar(b: u8) -> bool {
    b.is_ascii_alphanumeric() || b"!#$%&'*+-.^_`|~".contains(&b)
}

fn parse_head(lines: &[Vec<u8>]) -> Result<Request, HeadError> {
    let Some((first, rest)) = lines.split_first() else { return Err(HeadError::Bad("empty request")) };
    let first = std::str::from_utf8(first).map_err(|_| HeadError::Bad("request line is not ASCII"))?;
    let mut parts = first.split(' ');
    let (Some(method), Some(target), Some(version), None) = (parts.next(), parts.next(), parts.next(), parts.next())
    else {
        return Err(HeadError::Bad("expected 'METHOD TARGET HTTP/1.x'"));
    };
    if method.is_empty() || !method.bytes().all(is_tchar) {
        return Err(HeadError::Bad("invalid method"));
    }
    let minor = match version {
        "HTTP/1.1" => 1,
        "HTTP/1.0" => 0,
        _ => return Err(HeadError::Bad("only HTTP/1.0 and HTTP/1.1 are served")),
    };
    // Origin form (/name?query), or absolute form (http://host/name).
    let path = match target.find("://") {
        Some(i) if target[..i].eq_ignore_ascii_case("http") || target[..i].eq_ignore_ascii_case("https") => {
            let after = &target[i + 3..];
            after.find('/').map_or("/", |j| &after[j..])
        }
        _ => target,
    };
    let path = path.split('#').next().unwrap_or_default();
    let (path, query) = path.split_once('?').unwrap_or((path, ""));
    let name = match path.strip_prefix('/') {
        Some(p) => percent_decode(p).ok_or(HeadError::Bad("invalid percent-encoding in the path"))?,
        // '*' (OPTIONS) and the like: no file has such a name.
        None => String::new(),
    };
    let mut headers = Vec::with_capacity(rest.len());
    for line in rest {
        if line[0] == b' ' || line[0] == b'\t' {
            return Err(HeadError::Bad("obsolete line folding in a header"));
        }
        let Some(colon) = line.iter().position(|&b| b == b':') else {
            return Err(HeadError::Bad("header line without ':'"));
        };
        let (name, value) = (&line[..colon], &line[colon + 1..]);
        if name.is_empty() || !name.iter().copied().all(is_tchar) {
            return Err(HeadError::Bad("invalid header name"));
        }
        let name = String::from_utf8_lossy(name).to_ascii_lowercase();
        let value = String::from_utf8_lossy(value).trim_matches([' ', '\t']).to_string();
        headers.push((name, value));
    }
    Ok(Request { method: method.to_string(), name, query: query.to_string(), minor, headers })
}

/// Percent-decodes a path; `None` for a bad escape or bytes that are not UTF-8.
fn percent_decode(s: &str) -> Option<String> {
    let b = s.as_bytes();
    let mut out = Vec::with_capacity(b.len());
    let mut i = 0;
    while i < b.len() {
        if b[i] == b'%' {
            let hex = b.get(i + 1..i + 3)?;
            let hex = std::str::from_utf8(hex).ok()?;
            out.push(u8::from_str_radix(hex, 16).ok()?);
            i += 3;
        } else {
            out.push(b[i]);
            i += 1;
        }
    }
    String::from_utf8(out).ok()
}

/// Percent-encodes everything but unreserved characters and '/'.
fn percent_encode(s: &str) -> String {
    let mut out = String::with_capacity(s.len());
    for b in s.bytes() {
        if b.is_ascii_alphanumeric() || b"-._~/".contains(&b) {
            out.push(b as char);
        } else {
            out.push_str(&format!("%{b:02X}"));
        }
    }
    out
}

/// The first line and the headers every answer has.
fn status_head(status: u16, reason: &str) -> String {
    format!("HTTP/1.1 {status} {reason}\r\nDate: {}\r\nServer: relief\r\n{CORS}", http_date(SystemTime::now()))
}

/// On every answer: any page may read it, ranges and validators included (the web viewer reads
/// terrains from other origins, and needs `Content-Range` to learn a file's length).
const CORS: &str =
    "Access-Control-Allow-Origin: *\r\nAccess-Control-Expose-Headers: Content-Range, Content-Length, ETag, Accept-Ranges\r\n";

/// The media type of a served name, by its extension (a module script and `WebAssembly`'s
/// streaming compile insist on theirs).
fn content_type(name: &str) -> &'static str {
    let ext = name.rsplit_once('.').map(|(_, e)| e.to_ascii_lowercase()).unwrap_or_default();
    match ext.as_str() {
        "html" => "text/html; charset=utf-8",
        "js" => "text/javascript; charset=utf-8",
        "wasm" => "application/wasm",
        "png" => "image/png",
        "json" => "application/json",
        _ => "application/octet-stream",
    }
}

/// Ends a head: the connection header where it is not the version's default, the blank line.
fn end_head(head: &mut String, keep: bool, minor: u8) {
    if !keep {
        head.push_str("Connection: close\r\n");
    } else if minor == 0 {
        head.push_str("Connection: keep-alive\r\n");
    }
    head.push_str("\r\n");
}

/// A short plain-text answer (errors); the text is the body unless `head_only`.
fn simple(out: &mut impl Write, status: u16, reason: &str, keep: bool, head_only: bool, text: &str) -> io::Result<()> {
    let body = format!("{status} {reason}: {text}\n");
    let mut head = status_head(status, reason);
    head.push_str(&format!("Content-Type: text/plain; charset=utf-8\r\nContent-Length: {}\r\n", body.len()));
    end_head(&mut head, keep, 1);
    if !head_only {
        head.push_str(&body);
    }
    out.write_all(head.as_bytes())
}

/// A file's identity for this request: its length, ETag and modification time.
struct Stat {
    len: u64,
    etag: String,
    modified: Option<SystemTime>,
}

fn stat(meta: &std::fs::Metadata) -> Stat {
    let nanos = meta.mtime() as i128 * 1_000_000_000 + meta.mtime_nsec() as i128;
    let mut key = [0u8; 8 + 16 + 8];
    key[..8].copy_from_slice(&meta.len().to_le_bytes());
    key[8..24].copy_from_slice(&nanos.to_le_bytes());
    key[24..].copy_from_slice(&meta.ino().to_le_bytes());
    let hash = xxhash_rust::xxh3::xxh3_64(&key);
    Stat { len: meta.len(), etag: format!("\"{hash:016x}\""), modified: meta.modified().ok() }
}

/// Whether a list of entity tags (`If-Match`, `If-Range`) holds `etag` by strong comparison
/// (`*` matches any).
fn etag_listed(list: &str, etag: &str) -> bool {
    list.split(',').map(str::trim).any(|t| t == "*" || t == etag)
}

/// What a `Range` header asks of a file of `len` bytes.
#[derive(Debug, PartialEq, Eq)]
enum RangeAsk {
    /// No usable range: the whole file (200).
    Whole,
    /// Bytes `start..end` (206).
    Part(u64, u64),
    /// No range of the set is satisfiable (416).
    Unsatisfiable,
}

/// Parses `Range` (RFC 9110 §14.1.2): the first satisfiable range of the set, or why none.
fn parse_range(value: &str, len: u64) -> RangeAsk {
    let Some((unit, set)) = value.split_once('=') else { return RangeAsk::Whole };
    if !unit.trim().eq_ignore_ascii_case("bytes") {
        return RangeAsk::Whole;
    }
    // Saturating: a first byte past any file is simply unsatisfiable, a last one is clamped.
    let number = |s: &str| -> Option<u64> {
        (!s.is_empty() && s.bytes().all(|b| b.is_ascii_digit())).then(|| s.parse().unwrap_or(u64::MAX))
    };
    let mut any = false;
    let mut first = None;
    for spec in set.split(',').map(str::trim).filter(|s| !s.is_empty()) {
        let Some((a, b)) = spec.split_once('-') else { return RangeAsk::Whole };
        let part = if a.is_empty() {
            let Some(n) = number(b) else { return RangeAsk::Whole };
            (n > 0 && len > 0).then(|| (len - n.min(len), len))
        } else {
            let Some(start) = number(a) else { return RangeAsk::Whole };
            let last = if b.is_empty() { None } else { Some(number(b)) };
            let last = match last {
                None => None,
                Some(Some(l)) if l >= start => Some(l),
                Some(_) => return RangeAsk::Whole,
            };
            (start < len).then(|| (start, last.map_or(len, |l| l.min(len - 1) + 1)))
        };
        any = true;
        if first.is_none() {
            first = part;
        }
    }
    match first {
        Some((a, b)) => RangeAsk::Part(a, b),
        None if any => RangeAsk::Unsatisfiable,
        None => RangeAsk::Whole,
    }
}

fn answer(shared: &Shared, req: &Request, keep: bool, out: &mut impl Write) -> io::Result<Next> {
    let next = if keep { Next::KeepAlive } else { Next::Close };
    let head_only = match req.method.as_str() {
        "GET" => false,
        "HEAD" => true,
        "OPTIONS" => {
            // A CORS preflight (a page's `fetch` with a `Range` the browser does not count as
            // simple): allowed, and remembered for a day.
            let mut head = status_head(204, "No Content");
            head.push_str(
                "Access-Control-Allow-Methods: GET, HEAD, OPTIONS\r\nAccess-Control-Allow-Headers: Range, If-Match, If-Range\r\nAccess-Control-Max-Age: 86400\r\nContent-Length: 0\r\n",
            );
            end_head(&mut head, keep, req.minor);
            out.write_all(head.as_bytes())?;
            return Ok(next);
        }
        _ => {
            let mut head = status_head(405, "Method Not Allowed");
            let body = "405 Method Not Allowed: only GET and HEAD (and OPTIONS)\n";
            head.push_str(&format!(
                "Allow: GET, HEAD, OPTIONS\r\nContent-Type: text/plain; charset=utf-8\r\nContent-Length: {}\r\n",
                body.len()
            ));
            end_head(&mut head, keep, req.minor);
            head.push_str(body);
            out.write_all(head.as_bytes())?;
            return Ok(next);
        }
    };
    shared.requests.fetch_add(1, Ordering::SeqCst);
    let faults = &shared.faults;
    let note = |status: u16, range: Option<(u64, u64)>| shared.note(req, status, range);
    if Faults::take(&faults.drop_next) {
        note(0, None);
        return Ok(Next::Drop);
    }
    if Faults::take(&faults.error_next) {
        note(503, None);
        let mut head = status_head(503, "Service Unavailable");
        head.push_str("Content-Length: 0\r\n");
        end_head(&mut head, keep, req.minor);
        out.write_all(head.as_bytes())?;
        return Ok(next);
    }
    let name = if req.name.is_empty() && shared.files.contains_key("index.html") { "index.html" } else { &req.name };
    let uploaded = shared.uploads.as_ref().and_then(|d| object_path(d, name)).filter(|p| p.is_file());
    let Some(path) = shared.files.get(name).or(uploaded.as_ref()) else {
        note(404, None);
        simple(out, 404, "Not Found", keep, head_only, &format!("no file '/{}' here", req.name))?;
        return Ok(next);
    };
    // Opened and stated per request: a file renamed over is seen at once, and the bytes sent are
    // those of the file whose ETag is sent.
    let opened = File::open(path).and_then(|f| f.metadata().map(|m| (f, m)));
    let (file, meta) = match opened {
        Ok((f, m)) if m.is_file() => (f, m),
        Ok(_) => {
            note(404, None);
            simple(out, 404, "Not Found", keep, head_only, "not a regular file")?;
            return Ok(next);
        }
        Err(e) if e.kind() == io::ErrorKind::NotFound => {
            note(404, None);
            simple(out, 404, "Not Found", keep, head_only, "the file is gone")?;
            return Ok(next);
        }
        Err(e) => {
            note(500, None);
            simple(out, 500, "Internal Server Error", keep, head_only, &e.to_string())?;
            return Ok(next);
        }
    };
    let st = stat(&meta);
    let mut fields = format!("ETag: {}\r\nAccept-Ranges: bytes\r\n", st.etag);
    if let Some(t) = st.modified {
        fields.push_str(&format!("Last-Modified: {}\r\n", http_date(t)));
    }
    if let Some(list) = req.header("if-match") {
        if !etag_listed(list, &st.etag) {
            note(412, None);
            let mut head = status_head(412, "Precondition Failed");
            head.push_str(&fields);
            head.push_str("Content-Length: 0\r\n");
            end_head(&mut head, keep, req.minor);
            out.write_all(head.as_bytes())?;
            return Ok(next);
        }
    }
    let range = match req.header("range") {
        _ if head_only || faults.ignore_range.load(Ordering::SeqCst) => RangeAsk::Whole,
        Some(_) if req.header("if-range").is_some_and(|v| v != st.etag) => RangeAsk::Whole,
        Some(v) => parse_range(v, st.len),
        None => RangeAsk::Whole,
    };
    let (mut head, start, end) = match range {
        RangeAsk::Whole => (status_head(200, "OK"), 0, st.len),
        RangeAsk::Part(a, b) => {
            let mut head = status_head(206, "Partial Content");
            head.push_str(&format!("Content-Range: bytes {a}-{}/{}\r\n", b - 1, st.len));
            (head, a, b)
        }
        RangeAsk::Unsatisfiable => {
            note(416, None);
            let mut head = status_head(416, "Range Not Satisfiable");
            head.push_str(&fields);
            head.push_str(&format!("Content-Range: bytes */{}\r\nContent-Length: 0\r\n", st.len));
            end_head(&mut head, keep, req.minor);
            out.write_all(head.as_bytes())?;
            return Ok(next);
        }
    };
    head.push_str(&fields);
    head.push_str(&format!("Content-Type: {}\r\nContent-Length: {}\r\n", content_type(name), end - start));
    let status = if matches!(range, RangeAsk::Part(..)) { 206 } else { 200 };
    note(status, (!head_only).then_some((start, end)));
    let short = !head_only && end > start && Faults::take(&faults.short_next);
    // A short body's headers are an honest answer's: nothing tells the client it will be cut.
    end_head(&mut head, keep || short, req.minor);
    out.write_all(head.as_bytes())?;
    if head_only {
        return Ok(next);
    }
    if short {
        send_body(shared, &file, start, start + (end - start) / 2, out)?;
        return Ok(Next::Close);
    }
    send_body(shared, &file, start, end, out)?;
    Ok(next)
}

/// Sends bytes `start..end` of `file` in chunks of at most [`CHUNK_BYTES`]. A file that ends
/// early (truncated mid-flight) is an error: the connection is closed with the body short.
fn send_body(shared: &Shared, file: &File, start: u64, end: u64, out: &mut impl Write) -> io::Result<()> {
    let mut buf = vec![0u8; CHUNK_BYTES.min(end - start) as usize];
    let mut pos = start;
    while pos < end {
        let want = CHUNK_BYTES.min(end - pos) as usize;
        let got = match file.read_at(&mut buf[..want], pos) {
            Ok(0) => return Err(io::ErrorKind::UnexpectedEof.into()),
            Ok(n) => n,
            Err(e) if e.kind() == io::ErrorKind::Interrupted => continue,
            Err(e) => return Err(e),
        };
        shared.bytes_sent.fetch_add(got as u64, Ordering::SeqCst);
        out.write_all(&buf[..got])?;
        pos += got as u64;
    }
    Ok(())
}

/// An HTTP date (IMF-fixdate, RFC 9110 §5.6.7): `Sun, 06 Nov 1994 08:49:37 GMT`.
fn http_date(t: SystemTime) -> String {
    let secs = t.duration_since(UNIX_EPOCH).map_or(0, |d| d.as_secs());
    let days = (secs / 86_400) as i64;
    let (h, m, s) = (secs % 86_400 / 3600, secs % 3600 / 60, secs % 60);
    // Civil date from days since 1970-01-01 (Howard Hinnant's algorithm).
    let z = days + 719_468;
    let era = z.div_euclid(146_097);
    let doe = z.rem_euclid(146_097);
    let yoe = (doe - doe / 1460 + doe / 36_524 - doe / 146_096) / 365;
    let doy = doe - (365 * yoe + yoe / 4 - yoe / 100);
    let mp = (5 * doy + 2) / 153;
    let day = doy - (153 * mp + 2) / 5 + 1;
    let month = if mp < 10 { mp + 3 } else { mp - 9 };
    let year = yoe + era * 400 + i64::from(month <= 2);
    const WEEKDAYS: [&str; 7] = ["Thu", "Fri", "Sat", "Sun", "Mon", "Tue", "Wed"];
    const MONTHS: [&str; 12] = ["Jan", "Feb", "Mar", "Apr", "May", "Jun", "Jul", "Aug", "Sep", "Oct", "Nov", "Dec"];
    format!(
        "{}, {day:02} {} {year} {h:02}:{m:02}:{s:02} GMT",
        WEEKDAYS[days.rem_euclid(7) as usize],
        MONTHS[(month - 1) as usize]
    )
}

/// Where uploaded object `name` (`bucket/key`) lives under `dir`; `None` for a name that would
/// leave it.
fn object_path(dir: &std::path::Path, name: &str) -> Option<PathBuf> {
    let ok = !name.is_empty() && name.split('/').all(|c| !c.is_empty() && c != "." && c != "..");
    ok.then(|| dir.join(name))
}

/// The value of `key` in a query string.
fn query_value<'a>(query: &'a str, key: &str) -> Option<&'a str> {
    query.split('&').find_map(|kv| match kv.split_once('=') {
        Some((k, v)) if k == key => Some(v),
        None if kv == key => Some(""),
        _ => None,
    })
}

const S3_XML_NS: &str = "http://s3.amazonaws.com/doc/2006-03-01/";
/// The smallest part but the last of a multipart upload, as S3 enforces.
pub const MIN_PART_BYTES: u64 = 5 << 20;

/// An S3-style upload into `dir` (no authentication: a test and local server):
/// `PUT bucket/key` writes an object; `POST ?uploads` starts a multipart upload, `PUT
/// ?partNumber=N&uploadId=U` stores part N, `POST ?uploadId=U` completes it (parts in the order
/// listed; every part but the last at least 5 MiB, else `EntityTooSmall`), `DELETE ?uploadId=U`
/// aborts it. Objects appear whole, by rename, when written or completed.
fn upload(
    shared: &Shared,
    dir: &std::path::Path,
    req: &Request,
    body: &[u8],
    keep: bool,
    out: &mut impl Write,
) -> io::Result<()> {
    let reply = |out: &mut dyn Write, status: u16, reason: &str, extra: &str, body: &str| -> io::Result<()> {
        let mut head = status_head(status, reason);
        let kind = if body.starts_with('<') { "application/xml" } else { "text/plain; charset=utf-8" };
        head.push_str(&format!("{extra}Content-Type: {kind}\r\nContent-Length: {}\r\n", body.len()));
        end_head(&mut head, keep, req.minor);
        head.push_str(body);
        out.write_all(head.as_bytes())
    };
    let Some(object) = object_path(dir, &req.name).filter(|_| req.name.contains('/')) else {
        return reply(out, 400, "Bad Request", "", "uploads go to bucket/key\n");
    };
    let parts_dir = |id: &str| dir.join(".uploads").join(id);
    let write_whole = |to: &std::path::Path, bytes: &[u8]| -> io::Result<()> {
        std::fs::create_dir_all(to.parent().unwrap_or(dir))?;
        let tmp = to.with_extension("upload-tmp");
        std::fs::write(&tmp, bytes)?;
        std::fs::rename(&tmp, to)
    };
    let err500 = |out: &mut dyn Write, e: io::Error| reply(out, 500, "Internal Server Error", "", &format!("{e}\n"));
    let (bucket, key) = req.name.split_once('/').unwrap_or_default();
    match (req.method.as_str(), query_value(&req.query, "uploads"), query_value(&req.query, "uploadId")) {
        ("POST", Some(_), _) => {
            let id = format!("u{}", shared.upload_ids.fetch_add(1, Ordering::SeqCst));
            if let Err(e) = std::fs::create_dir_all(parts_dir(&id)) {
                return err500(out, e);
            }
            let xml = format!(
                "<?xml version=\"1.0\" encoding=\"UTF-8\"?>\n<InitiateMultipartUploadResult xmlns=\"{S3_XML_NS}\"><Bucket>{bucket}</Bucket><Key>{key}</Key><UploadId>{id}</UploadId></InitiateMultipartUploadResult>"
            );
            reply(out, 200, "OK", "", &xml)
        }
        ("PUT", _, Some(id)) => {
            let number = query_value(&req.query, "partNumber").and_then(|n| n.parse::<u16>().ok()).filter(|&n| n >= 1);
            let (Some(number), true) = (number, parts_dir(id).is_dir()) else {
                return reply(out, 404, "Not Found", "", "<Error><Code>NoSuchUpload</Code></Error>");
            };
            if let Err(e) = write_whole(&parts_dir(id).join(number.to_string()), body) {
                return err500(out, e);
            }
            let etag = format!("\"{:016x}\"", xxhash_rust::xxh3::xxh3_64(body));
            reply(out, 200, "OK", &format!("ETag: {etag}\r\n"), "")
        }
        ("POST", _, Some(id)) => {
            if !parts_dir(id).is_dir() {
                return reply(out, 404, "Not Found", "", "<Error><Code>NoSuchUpload</Code></Error>");
            }
            // The part numbers listed, in order.
            let text = String::from_utf8_lossy(body);
            let numbers: Vec<&str> = text.split("<PartNumber>").skip(1).filter_map(|p| p.split('<').next()).collect();
            let mut sizes = Vec::new();
            for n in &numbers {
                match std::fs::metadata(parts_dir(id).join(n.trim())) {
                    Ok(m) => sizes.push(m.len()),
                    Err(_) => return reply(out, 400, "Bad Request", "", "<Error><Code>InvalidPart</Code></Error>"),
                }
            }
            if numbers.is_empty() || sizes[..sizes.len() - 1].iter().any(|&s| s < MIN_PART_BYTES) {
                return reply(out, 400, "Bad Request", "", "<Error><Code>EntityTooSmall</Code></Error>");
            }
            let assembled = (|| -> io::Result<()> {
                std::fs::create_dir_all(object.parent().unwrap_or(dir))?;
                let tmp = object.with_extension("upload-tmp");
                let mut f = File::create(&tmp)?;
                for n in &numbers {
                    io::copy(&mut File::open(parts_dir(id).join(n.trim()))?, &mut f)?;
                }
                f.sync_all()?;
                std::fs::rename(&tmp, &object)?;
                std::fs::remove_dir_all(parts_dir(id))
            })();
            if let Err(e) = assembled {
                return err500(out, e);
            }
            let xml = format!(
                "<?xml version=\"1.0\" encoding=\"UTF-8\"?>\n<CompleteMultipartUploadResult xmlns=\"{S3_XML_NS}\"><Bucket>{bucket}</Bucket><Key>{key}</Key><ETag>\"{id}\"</ETag></CompleteMultipartUploadResult>"
            );
            reply(out, 200, "OK", "", &xml)
        }
        ("DELETE", _, Some(id)) => {
            let _ = std::fs::remove_dir_all(parts_dir(id));
            reply(out, 204, "No Content", "", "")
        }
        ("PUT", None, None) => match write_whole(&object, body) {
            Ok(()) => reply(out, 200, "OK", &format!("ETag: \"{:016x}\"\r\n", xxhash_rust::xxh3::xxh3_64(body)), ""),
            Err(e) => err500(out, e),
        },
        _ => reply(
            out,
            405,
            "Method Not Allowed",
            "",
            "405: uploads are PUT, POST ?uploads / ?uploadId, DELETE ?uploadId\n",
        ),
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use std::time::Instant;

    const LOOPBACK: SocketAddr = SocketAddr::new(IpAddr::V4(Ipv4Addr::LOCALHOST), 0);

    /// A file of `n` bytes, byte `i` = `i * 7 % 251`.
    fn content(n: usize) -> Vec<u8> {
        (0..n).map(|i| (i * 7 % 251) as u8).collect()
    }

    fn serve(n: usize, options: ServeOptions) -> (tempfile::TempDir, Server, Vec<u8>) {
        let dir = tempfile::tempdir().unwrap();
        let data = content(n);
        let path = dir.path().join("t.relief");
        std::fs::write(&path, &data).unwrap();
        let server = Server::start(vec![("t.relief".into(), path)], LOOPBACK, options).unwrap();
        (dir, server, data)
    }

    #[derive(Debug)]
    struct Response {
        status: u16,
        headers: Vec<(String, String)>,
        body: Vec<u8>,
    }

    impl Response {
        fn header(&self, name: &str) -> Option<&str> {
            self.headers.iter().find(|(n, _)| n.eq_ignore_ascii_case(name)).map(|(_, v)| v.as_str())
        }
    }

    struct Client {
        reader: BufReader<TcpStream>,
    }

    impl Client {
        fn new(server: &Server) -> Client {
            let s = TcpStream::connect(server.addr()).unwrap();
            s.set_read_timeout(Some(Duration::from_secs(5))).unwrap();
            Client { reader: BufReader::new(s) }
        }

        fn send(&mut self, raw: &str) {
            self.reader.get_mut().write_all(raw.as_bytes()).unwrap();
        }

        fn get(&mut self, path: &str, headers: &str) -> Response {
            self.send(&format!("GET {path} HTTP/1.1\r\nHost: x\r\n{headers}\r\n"));
            self.read(false)
        }

        /// Reads one response; its body by `Content-Length` (none for HEAD). Panics on EOF.
        fn read(&mut self, head: bool) -> Response {
            self.try_read(head).expect("a response")
        }

        /// One response, or `None` when the connection ends before or inside it (the body read
        /// so far is kept in a `Some` with the status line when the headers arrived).
        fn try_read(&mut self, head: bool) -> Option<Response> {
            let mut line = String::new();
            if self.reader.read_line(&mut line).ok()? == 0 {
                return None;
            }
            let status = line.split(' ').nth(1)?.parse().ok()?;
            let mut headers = Vec::new();
            loop {
                let mut l = String::new();
                self.reader.read_line(&mut l).ok()?;
                let l = l.trim_end();
                if l.is_empty() {
                    break;
                }
                let (n, v) = l.split_once(':')?;
                headers.push((n.to_string(), v.trim().to_string()));
            }
            let mut r = Response { status, headers, body: Vec::new() };
            let len: usize = r.header("content-length").map_or(0, |v| v.parse().unwrap());
            if !head {
                let _ = (&mut self.reader).take(len as u64).read_to_end(&mut r.body);
            }
            Some(r)
        }

        /// Whether the server closed the connection (EOF, or a reset).
        fn closed(&mut self) -> bool {
            let mut b = [0u8; 1];
            matches!(self.reader.read(&mut b), Ok(0) | Err(_))
        }
    }

    #[test]
    fn ranges_are_206_with_the_exact_bytes() {
        let (_d, server, data) = serve(10_000, ServeOptions::default());
        let mut c = Client::new(&server);
        let r = c.get("/t.relief", "Range: bytes=100-199\r\n");
        assert_eq!(r.status, 206);
        assert_eq!(r.header("content-range"), Some("bytes 100-199/10000"));
        assert_eq!(r.header("content-length"), Some("100"));
        assert_eq!(r.header("accept-ranges"), Some("bytes"));
        assert!(r.header("etag").is_some_and(|e| e.len() == 18 && e.starts_with('"')));
        assert!(r.header("last-modified").is_some_and(|d| d.ends_with(" GMT")));
        assert_eq!(r.body, &data[100..200]);
        // Open-ended, clamped past the end, and the whole file.
        let r = c.get("/t.relief", "Range: bytes=9990-\r\n");
        assert_eq!((r.status, r.header("content-range")), (206, Some("bytes 9990-9999/10000")));
        assert_eq!(r.body, &data[9990..]);
        let r = c.get("/t.relief", "Range: bytes=9000-123456789012345678901234567890\r\n");
        assert_eq!((r.status, r.header("content-range")), (206, Some("bytes 9000-9999/10000")));
        assert_eq!(r.body, &data[9000..]);
        let r = c.get("/t.relief", "");
        assert_eq!((r.status, r.header("content-range")), (200, None));
        assert_eq!(r.body, data);
        assert_eq!(server.requests(), 4);
        assert_eq!(server.bytes_sent(), 100 + 10 + 1000 + 10_000);
        assert_eq!(server.connections(), 1);
    }

    #[test]
    fn suffix_ranges() {
        let (_d, server, data) = serve(1000, ServeOptions::default());
        let mut c = Client::new(&server);
        let r = c.get("/t.relief", "Range: bytes=-10\r\n");
        assert_eq!((r.status, r.header("content-range")), (206, Some("bytes 990-999/1000")));
        assert_eq!(r.body, &data[990..]);
        // A suffix longer than the file is the whole file, still as a 206.
        let r = c.get("/t.relief", "Range: bytes=-5000\r\n");
        assert_eq!((r.status, r.header("content-range")), (206, Some("bytes 0-999/1000")));
        assert_eq!(r.body, data);
    }

    #[test]
    fn unsatisfiable_ranges_are_416() {
        let (_d, server, _) = serve(1000, ServeOptions::default());
        let mut c = Client::new(&server);
        for range in ["bytes=1000-", "bytes=5000-6000", "bytes=-0", "bytes=2000-2001, 3000-"] {
            let r = c.get("/t.relief", &format!("Range: {range}\r\n"));
            assert_eq!(r.status, 416, "{range}");
            assert_eq!(r.header("content-range"), Some("bytes */1000"), "{range}");
            assert_eq!(r.header("content-length"), Some("0"));
            assert!(r.body.is_empty());
        }
        assert_eq!(server.bytes_sent(), 0);
    }

    #[test]
    fn several_ranges_serve_the_first_satisfiable_and_bad_ones_are_ignored() {
        let (_d, server, data) = serve(1000, ServeOptions::default());
        let mut c = Client::new(&server);
        let r = c.get("/t.relief", "Range: bytes=5000-, 10-19, 30-39\r\n");
        assert_eq!((r.status, r.header("content-range")), (206, Some("bytes 10-19/1000")));
        assert_eq!(r.body, &data[10..20]);
        for range in ["bytes=20-10", "bytes=a-b", "items=0-1", "bytes 0-1", "bytes=1-2-3"] {
            let r = c.get("/t.relief", &format!("Range: {range}\r\n"));
            assert_eq!((r.status, r.body.len()), (200, 1000), "{range}");
        }
        // If-Range of another ETag: the whole file.
        let r = c.get("/t.relief", "Range: bytes=0-9\r\nIf-Range: \"other\"\r\n");
        assert_eq!((r.status, r.body.len()), (200, 1000));
    }

    #[test]
    fn unknown_paths_are_404_other_methods_405() {
        let (_d, server, _) = serve(100, ServeOptions::default());
        let mut c = Client::new(&server);
        assert_eq!(c.get("/other", "").status, 404);
        assert_eq!(c.get("/t.relief/x", "").status, 404);
        c.send("DELETE /t.relief HTTP/1.1\r\nHost: x\r\n\r\n");
        let r = c.read(false);
        assert_eq!((r.status, r.header("allow")), (405, Some("GET, HEAD, OPTIONS")));
        // The connection survived them all; a query string is not part of the name.
        assert_eq!(c.get("/t.relief?v=1", "").status, 200);
        assert_eq!(server.requests(), 3);
    }

    /// What a browser needs: CORS on every answer (ranges and validators readable), a
    /// preflight answered, media types by extension, `/` as index.html; and every request logged.
    #[test]
    fn browsers_may_read_across_origins_and_every_request_is_logged() {
        let dir = tempfile::tempdir().unwrap();
        let (page, wasm, terrain) =
            (dir.path().join("index.html"), dir.path().join("a.wasm"), dir.path().join("t.relief"));
        std::fs::write(&page, "<!doctype html>").unwrap();
        std::fs::write(&wasm, b"\0asm").unwrap();
        std::fs::write(&terrain, content(1000)).unwrap();
        let files = vec![("index.html".into(), page), ("a.wasm".into(), wasm), ("t.relief".into(), terrain)];
        let server = Server::start(files, LOOPBACK, ServeOptions::default()).unwrap();
        let mut c = Client::new(&server);
        let r = c.get("/t.relief", "Range: bytes=10-19\r\nOrigin: http://elsewhere\r\n");
        assert_eq!((r.status, r.header("access-control-allow-origin")), (206, Some("*")));
        let exposed = r.header("access-control-expose-headers").unwrap_or_default();
        assert!(exposed.contains("Content-Range") && exposed.contains("ETag"), "{exposed}");
        assert_eq!(r.header("content-type"), Some("application/octet-stream"));
        c.send("OPTIONS /t.relief HTTP/1.1\r\nHost: x\r\nAccess-Control-Request-Headers: range\r\n\r\n");
        let r = c.read(true);
        assert_eq!(r.status, 204);
        assert!(r.header("access-control-allow-headers").unwrap_or_default().contains("Range"));
        assert_eq!(r.header("access-control-allow-origin"), Some("*"));
        let r = c.get("/a.wasm", "");
        assert_eq!((r.status, r.header("content-type")), (200, Some("application/wasm")));
        let r = c.get("/", "");
        assert_eq!((r.status, r.header("content-type")), (200, Some("text/html; charset=utf-8")));
        assert_eq!(r.body, b"<!doctype html>");
        assert_eq!(c.get("/gone.relief", "").status, 404);
        type Entry = (String, u16, Option<(u64, u64)>);
        let log: Vec<Entry> = server.log().into_iter().map(|l| (l.name, l.status, l.range)).collect();
        assert_eq!(
            log,
            [
                ("t.relief".into(), 206, Some((10, 20))),
                ("a.wasm".into(), 200, Some((0, 4))),
                ("".into(), 200, Some((0, 15))),
                ("gone.relief".into(), 404, None),
            ],
            "the preflight is not a read"
        );
    }

    #[test]
    fn head_has_the_headers_and_no_body() {
        let (_d, server, _) = serve(5000, ServeOptions::default());
        let mut c = Client::new(&server);
        c.send("HEAD /t.relief HTTP/1.1\r\nHost: x\r\nRange: bytes=0-9\r\n\r\n");
        let r = c.read(true);
        assert_eq!(r.status, 200);
        assert_eq!(r.header("content-length"), Some("5000"));
        assert_eq!(r.header("accept-ranges"), Some("bytes"));
        let etag = r.header("etag").unwrap().to_string();
        // No body came: the next answer on the connection starts right away.
        let r = c.get("/t.relief", "Range: bytes=0-9\r\n");
        assert_eq!((r.status, r.body.len()), (206, 10));
        assert_eq!(r.header("etag"), Some(etag.as_str()));
        assert_eq!(server.bytes_sent(), 10);
    }

    #[test]
    fn keep_alive_pipelining_and_close() {
        let (_d, server, data) = serve(3000, ServeOptions::default());
        let mut c = Client::new(&server);
        // Two requests in one write, answered in order on one connection.
        c.send("GET /t.relief HTTP/1.1\r\nRange: bytes=0-0\r\n\r\nGET /t.relief HTTP/1.1\r\nRange: bytes=1-2\r\n\r\n");
        assert_eq!(c.read(false).body, &data[0..1]);
        assert_eq!(c.read(false).body, &data[1..3]);
        let r = c.get("/t.relief", "Connection: close\r\n");
        assert_eq!((r.status, r.header("connection")), (200, Some("close")));
        assert_eq!(r.body, data);
        assert!(c.closed());
        // HTTP/1.0 closes unless asked to keep the connection.
        let mut c = Client::new(&server);
        c.send("GET /t.relief HTTP/1.0\r\nRange: bytes=0-1\r\n\r\n");
        assert_eq!(c.read(false).status, 206);
        assert!(c.closed());
        let mut c = Client::new(&server);
        c.send("GET /t.relief HTTP/1.0\r\nConnection: keep-alive\r\nRange: bytes=0-1\r\n\r\n");
        assert_eq!(c.read(false).header("connection"), Some("keep-alive"));
        assert_eq!(c.get("/t.relief", "Range: bytes=0-1\r\n").status, 206);
        assert_eq!(server.connections(), 3);
    }

    #[test]
    fn bad_and_oversized_requests_are_refused_and_closed() {
        let (_d, server, _) = serve(10, ServeOptions::default());
        for bad in ["GARBAGE\r\n\r\n", "GET /t.relief HTTP/2.0\r\n\r\n", "GET /t.relief HTTP/1.1\r\nno colon\r\n\r\n"] {
            let mut c = Client::new(&server);
            c.send(bad);
            assert_eq!(c.read(false).status, 400, "{bad:?}");
            assert!(c.closed());
        }
        let mut c = Client::new(&server);
        c.send(&format!("GET /t.relief HTTP/1.1\r\nX-Big: {}\r\n\r\n", "a".repeat(MAX_HEAD_BYTES)));
        assert_eq!(c.read(false).status, 431);
        assert!(c.closed());
        assert_eq!(server.requests(), 0);
    }

    #[test]
    fn fault_drop_closes_without_an_answer() {
        let (_d, server, _) = serve(100, ServeOptions::default());
        server.faults().drop_next.store(2, Ordering::SeqCst);
        for _ in 0..2 {
            let mut c = Client::new(&server);
            c.send("GET /t.relief HTTP/1.1\r\n\r\n");
            assert!(c.try_read(false).is_none());
        }
        assert_eq!(server.faults().drop_next.load(Ordering::SeqCst), 0);
        assert_eq!(Client::new(&server).get("/t.relief", "").status, 200);
        assert_eq!(server.requests(), 3);
    }

    #[test]
    fn fault_error_is_a_503() {
        let (_d, server, _) = serve(100, ServeOptions::default());
        server.faults().error_next.store(1, Ordering::SeqCst);
        let mut c = Client::new(&server);
        let r = c.get("/t.relief", "Range: bytes=0-9\r\n");
        assert_eq!((r.status, r.header("content-length")), (503, Some("0")));
        assert_eq!(c.get("/t.relief", "Range: bytes=0-9\r\n").status, 206);
    }

    #[test]
    fn fault_short_sends_half_the_body_and_closes() {
        let (_d, server, data) = serve(1000, ServeOptions::default());
        server.faults().short_next.store(1, Ordering::SeqCst);
        // A HEAD has no body to cut: it does not take the fault.
        let mut c = Client::new(&server);
        c.send("HEAD /t.relief HTTP/1.1\r\n\r\n");
        assert_eq!(c.read(true).status, 200);
        let r = c.get("/t.relief", "Range: bytes=100-299\r\n");
        assert_eq!((r.status, r.header("content-length")), (206, Some("200")));
        assert_eq!(r.header("content-range"), Some("bytes 100-299/1000"));
        assert_eq!(r.body, &data[100..200]);
        assert!(c.closed());
        assert_eq!(server.bytes_sent(), 100);
        assert_eq!(Client::new(&server).get("/t.relief", "Range: bytes=100-299\r\n").body, &data[100..300]);
    }

    #[test]
    fn fault_ignore_range_sends_the_whole_file() {
        let (_d, server, data) = serve(1000, ServeOptions::default());
        server.faults().ignore_range.store(true, Ordering::SeqCst);
        let mut c = Client::new(&server);
        let r = c.get("/t.relief", "Range: bytes=0-9\r\n");
        assert_eq!((r.status, r.header("content-range")), (200, None));
        assert_eq!(r.body, data);
        server.faults().ignore_range.store(false, Ordering::SeqCst);
        assert_eq!(c.get("/t.relief", "Range: bytes=0-9\r\n").status, 206);
    }

    #[test]
    fn faults_are_taken_one_per_request_in_order() {
        let (_d, server, _) = serve(100, ServeOptions::default());
        let f = server.faults().clone();
        f.drop_next.store(1, Ordering::SeqCst);
        f.error_next.store(1, Ordering::SeqCst);
        let mut c = Client::new(&server);
        c.send("GET /t.relief HTTP/1.1\r\n\r\n");
        assert!(c.try_read(false).is_none());
        assert_eq!((f.drop_next.load(Ordering::SeqCst), f.error_next.load(Ordering::SeqCst)), (0, 1));
        let mut c = Client::new(&server);
        assert_eq!(c.get("/t.relief", "").status, 503);
        assert_eq!(c.get("/t.relief", "").status, 200);
    }

    #[test]
    fn etag_changes_when_the_file_is_replaced_and_if_match_checks_it() {
        let (dir, server, data) = serve(1000, ServeOptions::default());
        let mut c = Client::new(&server);
        let r = c.get("/t.relief", "Range: bytes=0-9\r\n");
        let old = r.header("etag").unwrap().to_string();
        assert_eq!(c.get("/t.relief", "Range: bytes=0-9\r\n").header("etag"), Some(old.as_str()));
        let r = c.get("/t.relief", &format!("Range: bytes=0-9\r\nIf-Match: \"x\", {old}\r\n"));
        assert_eq!(r.status, 206);
        // Same length, new content, renamed over the served file (a new inode).
        let replaced: Vec<u8> = data.iter().map(|b| b ^ 0xff).collect();
        let tmp = dir.path().join("t.relief.tmp");
        std::fs::write(&tmp, &replaced).unwrap();
        std::fs::rename(&tmp, dir.path().join("t.relief")).unwrap();
        let r = c.get("/t.relief", "Range: bytes=0-9\r\n");
        let new = r.header("etag").unwrap().to_string();
        assert_ne!(new, old);
        assert_eq!(r.body, &replaced[..10]);
        let r = c.get("/t.relief", &format!("Range: bytes=0-9\r\nIf-Match: {old}\r\n"));
        assert_eq!((r.status, r.header("etag")), (412, Some(new.as_str())));
        assert!(r.body.is_empty());
        assert_eq!(c.get("/t.relief", "Range: bytes=0-9\r\nIf-Match: *\r\n").status, 206);
        // The file removed: 404.
        std::fs::remove_file(dir.path().join("t.relief")).unwrap();
        assert_eq!(c.get("/t.relief", "").status, 404);
    }

    #[test]
    fn latency_delays_each_request_and_connections_concurrently() {
        let latency = Duration::from_millis(20);
        let (_d, server, _) = serve(100, ServeOptions { latency, ..Default::default() });
        let mut c = Client::new(&server);
        let t = Instant::now();
        c.get("/t.relief", "Range: bytes=0-9\r\n");
        c.get("/t.relief", "Range: bytes=0-9\r\n");
        assert!(t.elapsed() >= 2 * latency, "{:?}", t.elapsed());
        // Four connections at once wait together, not one after another.
        let latency = Duration::from_millis(60);
        let (_d, server, _) = serve(100, ServeOptions { latency, ..Default::default() });
        let mut clients: Vec<Client> = (0..4).map(|_| Client::new(&server)).collect();
        let t = Instant::now();
        for c in &mut clients {
            c.send("GET /t.relief HTTP/1.1\r\nRange: bytes=0-9\r\n\r\n");
        }
        for c in &mut clients {
            assert_eq!(c.read(false).status, 206);
        }
        let took = t.elapsed();
        assert!(took >= latency && took < 3 * latency, "{took:?}");
    }

    #[test]
    fn names_urls_and_start_errors() {
        let dir = tempfile::tempdir().unwrap();
        let path = dir.path().join("a b.relief");
        std::fs::write(&path, b"hello").unwrap();
        let files = vec![("dir/a b.relief".to_string(), path.clone())];
        let server = Server::start(files, LOOPBACK, ServeOptions::default()).unwrap();
        let url = server.url("dir/a b.relief");
        assert_eq!(url, format!("http://127.0.0.1:{}/dir/a%20b.relief", server.addr().port()));
        let mut c = Client::new(&server);
        assert_eq!(c.get("/dir/a%20b.relief", "").body, b"hello");
        let addr = server.addr();
        server.stop();
        assert!(TcpStream::connect(addr).is_err(), "still listening after stop");

        let missing = vec![("m".to_string(), dir.path().join("missing"))];
        assert!(matches!(Server::start(missing, LOOPBACK, ServeOptions::default()), Err(Error::Io { .. })));
        let twice = vec![("a".to_string(), path.clone()), ("a".to_string(), path.clone())];
        assert!(matches!(Server::start(twice, LOOPBACK, ServeOptions::default()), Err(Error::InvalidArgument(_))));
        let slash = vec![("/a".to_string(), path)];
        assert!(matches!(Server::start(slash, LOOPBACK, ServeOptions::default()), Err(Error::InvalidArgument(_))));
    }

    #[test]
    fn stop_ends_kept_alive_connections() {
        let (_d, server, _) = serve(100, ServeOptions::default());
        let mut c = Client::new(&server);
        assert_eq!(c.get("/t.relief", "").status, 200);
        let t = Instant::now();
        server.stop();
        assert!(t.elapsed() < Duration::from_secs(1));
        assert!(c.closed());
    }

    #[test]
    fn range_parsing() {
        use RangeAsk::*;
        assert_eq!(parse_range("bytes=0-0", 10), Part(0, 1));
        assert_eq!(parse_range("BYTES = 2-", 10), Part(2, 10));
        assert_eq!(parse_range("bytes=-3", 10), Part(7, 10));
        assert_eq!(parse_range("bytes=-3", 0), Unsatisfiable);
        assert_eq!(parse_range("bytes=0-", 0), Unsatisfiable);
        assert_eq!(parse_range("bytes=,", 10), Whole);
        assert_eq!(parse_range("bytes=", 10), Whole);
        assert_eq!(parse_range("bytes=99999999999999999999999-", 10), Unsatisfiable);
        assert_eq!(parse_range("bytes=-", 10), Whole);
    }

    #[test]
    fn http_dates() {
        assert_eq!(http_date(UNIX_EPOCH), "Thu, 01 Jan 1970 00:00:00 GMT");
        assert_eq!(http_date(UNIX_EPOCH + Duration::from_secs(784_111_777)), "Sun, 06 Nov 1994 08:49:37 GMT");
        assert_eq!(http_date(UNIX_EPOCH + Duration::from_secs(951_825_600)), "Tue, 29 Feb 2000 12:00:00 GMT");
    }
}

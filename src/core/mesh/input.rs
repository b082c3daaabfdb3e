//! The byte stream every mesh parser reads: a plain file read in chunks, or a gzip'd one
//! decompressed on a thread of its own while the caller parses, in bounded buffers either way.
//!
//! The parsers see a window of unconsumed bytes ([`Input::window`]), consume what they have
//! parsed and ask for more ([`Input::more`]); the window grows past [`CHUNK`] only while one
//! line, token or record does not fit (or while the format is detected).
//!
//! Errors keep the order of a reader that first decompresses and validates the whole input: a
//! read error of the file, then a gzip error, then (for text) the first invalid UTF-8 sequence,
//! then what the parser found. [`Input::finish`] therefore reads the rest of the stream to its
//! end after every parse, successful or not, and reports which of those came first.

use std::cell::RefCell;
use std::fs::File;
use std::io::{self, Read};
use std::rc::Rc;
use std::sync::mpsc::{channel, sync_channel, Receiver, Sender};
use std::thread::JoinHandle;

/// Bytes read (or decompressed) at a time.
pub(super) const CHUNK: usize = 1 << 20;

/// Chunks in flight between the gzip thread and the parser.
const GZIP_QUEUE: usize = 4;

enum Msg {
    Data(Vec<u8>),
    /// The decoder failed (corrupt or truncated stream): `gzip: {this}`.
    Gzip(String),
    /// Reading the compressed file failed.
    Io(io::Error),
}

struct Gzip {
    rx: Receiver<Msg>,
    /// Used chunks go back to the decoder thread.
    free: Sender<Vec<u8>>,
    thread: Option<JoinHandle<()>>,
}

enum Source {
    Plain(File),
    Gzip(Gzip),
}

/// What stopped the stream early, in the order the errors are reported.
pub(super) enum StreamError {
    Io(io::Error),
    Gzip(String),
    /// The text holds invalid UTF-8: `{what} is not text ({the first invalid sequence, in
    /// std::str::Utf8Error's words})`.
    NotText(String),
}

pub(super) struct Input {
    buf: Vec<u8>,
    pos: usize,
    /// Offset in the (decompressed) stream of `buf[0]`.
    base: u64,
    eof: bool,
    source: Source,
    gzip: bool,
    /// Bytes the input can hold at most, as far as known before reading it: the file's length,
    /// or for gzip the smaller of the trailer's length and the most deflate can expand.
    size_hint: usize,
    chunk: usize,
    io_error: Option<io::Error>,
    gzip_error: Option<String>,
    /// The UTF-8 check of a text format and the text's name in its message.
    utf8: Option<(Utf8Check, &'static str)>,
}

impl Input {
    /// Opens `path`: gzip'd (magic 1f 8b) or plain, read `chunk` bytes at a time ([`CHUNK`]
    /// but in tests). `Ok(None)` for an empty file.
    pub(super) fn open(path: &std::path::Path, chunk: usize) -> io::Result<Option<Input>> {
        let mut file = File::open(path)?;
        let len = file.metadata().map(|m| if m.is_file() { m.len() } else { 0 }).unwrap_or(0);
        let mut magic = [0u8; 2];
        let mut got = 0;
        while got < 2 {
            match file.read(&mut magic[got..]) {
                Ok(0) => break,
                Ok(n) => got += n,
                Err(e) if e.kind() == io::ErrorKind::Interrupted => {}
                Err(e) => return Err(e),
            }
        }
        if got == 0 {
            return Ok(None);
        }
        let gzip = magic[..got] == [0x1f, 0x8b];
        let (source, buf, size_hint, chunk) = if gzip {
            let hint = gzip_size_hint(&file, len);
            let prefix = io::Cursor::new(magic);
            (Source::Gzip(Gzip::spawn(prefix.chain(file), chunk)), Vec::new(), hint, chunk)
        } else {
            // A small file is read in one chunk of its own size, not a whole [`CHUNK`].
            let chunk = match usize::try_from(len) {
                Ok(len) if len > 0 => chunk.min(len.max(4096)),
                _ => chunk,
            };
            let mut buf = Vec::with_capacity(chunk + 64);
            buf.extend_from_slice(&magic[..got]);
            (Source::Plain(file), buf, usize::try_from(len).unwrap_or(usize::MAX), chunk)
        };
        Ok(Some(Input {
            buf,
            pos: 0,
            base: 0,
            eof: false,
            source,
            gzip,
            size_hint,
            chunk,
            io_error: None,
            gzip_error: None,
            utf8: None,
        }))
    }

    pub(super) fn is_gzip(&self) -> bool {
        self.gzip
    }

    pub(super) fn size_hint(&self) -> usize {
        self.size_hint
    }

    /// The bytes read and not yet consumed.
    #[inline]
    pub(super) fn window(&self) -> &[u8] {
        &self.buf[self.pos..]
    }

    /// The last `n` bytes consumed (still in memory until the next [`Input::more`]).
    #[inline]
    pub(super) fn window_before(&self, n: usize) -> &[u8] {
        &self.buf[self.pos - n..self.pos]
    }

    #[inline]
    pub(super) fn consume(&mut self, n: usize) {
        debug_assert!(n <= self.buf.len() - self.pos);
        self.pos += n;
    }

    /// Whether the stream has ended (no [`Input::more`] will add bytes).
    #[inline]
    pub(super) fn at_end(&self) -> bool {
        self.eof
    }

    /// Offset in the (decompressed) stream of the window's first byte.
    pub(super) fn offset(&self) -> u64 {
        self.base + self.pos as u64
    }

    /// Appends the next chunk to the window; false once the stream has ended (or failed: the
    /// failure is reported by [`Input::finish`]).
    pub(super) fn more(&mut self) -> bool {
        if self.eof {
            return false;
        }
        // Keep only the unconsumed bytes (usually a partial line or record).
        if self.pos > 0 {
            self.buf.drain(..self.pos);
            self.base += self.pos as u64;
            self.pos = 0;
        }
        let start = self.buf.len();
        match &mut self.source {
            Source::Plain(file) => loop {
                match file.by_ref().take(self.chunk as u64).read_to_end(&mut self.buf) {
                    Ok(0) => {
                        self.eof = true;
                        break;
                    }
                    Ok(_) => break,
                    Err(e) if e.kind() == io::ErrorKind::Interrupted => {}
                    Err(e) => {
                        self.io_error = Some(e);
                        self.eof = true;
                        break;
                    }
                }
            },
            Source::Gzip(g) => match g.rx.recv() {
                Ok(Msg::Data(chunk)) => {
                    self.buf.extend_from_slice(&chunk);
                    let _ = g.free.send(chunk);
                }
                Ok(Msg::Gzip(e)) => {
                    self.gzip_error = Some(e);
                    self.eof = true;
                }
                Ok(Msg::Io(e)) => {
                    self.io_error = Some(e);
                    self.eof = true;
                }
                Err(_) => self.eof = true,
            },
        }
        if let Some((u, _)) = &mut self.utf8 {
            u.feed(&self.buf[start..], self.base + start as u64);
        }
        if self.eof {
            self.join();
        }
        self.buf.len() > start || !self.eof
    }

    /// Makes sure the window holds at least `n` bytes, reading more as needed; false if the
    /// stream ends first.
    #[inline]
    pub(super) fn fill(&mut self, n: usize) -> bool {
        while self.buf.len() - self.pos < n {
            if !self.more() {
                return false;
            }
        }
        true
    }

    /// From now on, checks that the stream from the window's start to its end is UTF-8; `what`
    /// names the text in the message (`OBJ`, `OFF`, `ASCII PLY body`).
    pub(super) fn require_utf8(&mut self, what: &'static str) {
        let mut u = Utf8Check::default();
        u.feed(&self.buf[self.pos..], self.offset());
        self.utf8 = Some((u, what));
    }

    /// Reads the stream to its end (checking it as it goes) and returns the first thing that
    /// went wrong with the stream itself: a read error, a gzip error, invalid UTF-8.
    pub(super) fn finish(&mut self) -> Option<StreamError> {
        loop {
            self.pos = self.buf.len();
            if !self.more() {
                break;
            }
        }
        if let Some(e) = self.io_error.take() {
            return Some(StreamError::Io(e));
        }
        if let Some(e) = self.gzip_error.take() {
            return Some(StreamError::Gzip(e));
        }
        let (u, what) = self.utf8.as_mut()?;
        u.end().map(|e| StreamError::NotText(format!("{what} is not text ({e})")))
    }

    fn join(&mut self) {
        if let Source::Gzip(g) = &mut self.source {
            if let Some(t) = g.thread.take() {
                let _ = t.join();
            }
        }
    }
}

/// The gzip trailer's ISIZE (the last member's length modulo 2^32), bounded by deflate's largest
/// expansion (1032:1): a hint for reserving, never trusted for anything else.
fn gzip_size_hint(file: &File, len: u64) -> usize {
    let most = len.saturating_mul(1032);
    let mut tail = [0u8; 4];
    #[cfg(unix)]
    let read_tail = |tail: &mut [u8; 4]| std::os::unix::fs::FileExt::read_exact_at(file, tail, len - 4).is_ok();
    #[cfg(not(unix))]
    let read_tail = |_: &mut [u8; 4]| false;
    let isize =
        if len >= 18 && read_tail(&mut tail) { u64::from(u32::from_le_bytes(tail)) } else { len.saturating_mul(4) };
    usize::try_from(isize.min(most)).unwrap_or(usize::MAX)
}

impl Gzip {
    fn spawn<R: Read + Send + 'static>(compressed: R, size: usize) -> Gzip {
        let (tx, rx) = sync_channel(GZIP_QUEUE);
        let (free, free_rx) = channel::<Vec<u8>>();
        let thread = std::thread::Builder::new().name("relief-gunzip".into()).spawn(move || {
            // Read errors of the file are told apart from the decoder's own.
            let read_error = Rc::new(RefCell::new(None));
            let tracked = Tracked { inner: compressed, error: Rc::clone(&read_error) };
            let mut decoder = flate2::read::MultiGzDecoder::new(tracked);
            loop {
                let mut chunk = free_rx.try_recv().unwrap_or_else(|_| Vec::with_capacity(size));
                chunk.clear();
                let r = decoder.by_ref().take(size as u64).read_to_end(&mut chunk);
                let end = match r {
                    Ok(0) => break,
                    Ok(_) => None,
                    Err(e) => Some(match read_error.borrow_mut().take() {
                        Some(io) => Msg::Io(io),
                        None => Msg::Gzip(e.to_string()),
                    }),
                };
                if !chunk.is_empty() && tx.send(Msg::Data(chunk)).is_err() {
                    break;
                }
                if let Some(msg) = end {
                    let _ = tx.send(msg);
                    break;
                }
            }
        });
        match thread {
            Ok(t) => Gzip { rx, free, thread: Some(t) },
            Err(e) => {
                // No thread: the stream is that error.
                let (tx, rx) = sync_channel(1);
                let _ = tx.send(Msg::Io(e));
                Gzip { rx, free, thread: None }
            }
        }
    }
}

struct Tracked<R> {
    inner: R,
    error: Rc<RefCell<Option<io::Error>>>,
}

impl<R: Read> Read for Tracked<R> {
    fn read(&mut self, buf: &mut [u8]) -> io::Result<usize> {
        match self.inner.read(buf) {
            Err(e) if e.kind() != io::ErrorKind::Interrupted => {
                let kind = e.kind();
                *self.error.borrow_mut() = Some(e);
                Err(io::Error::new(kind, "read failed"))
            }
            r => r,
        }
    }
}

/// Incremental UTF-8 validation that finds the same first error as [`std::str::from_utf8`] over
/// the whole text, however the text is cut into pieces.
#[derive(Default)]
pub(super) struct Utf8Check {
    /// The start of a sequence cut by the end of the last piece.
    pending: Vec<u8>,
    pending_at: u64,
    /// Offset from the text's start and length of the first invalid sequence (`None`: cut by
    /// the end of the text).
    error: Option<(u64, Option<usize>)>,
    /// Offset in the stream of the text's first byte.
    origin: Option<u64>,
}

impl Utf8Check {
    /// Checks the next piece, which starts at stream offset `at`.
    pub(super) fn feed(&mut self, mut data: &[u8], mut at: u64) {
        let origin = *self.origin.get_or_insert(at);
        if self.error.is_some() {
            return;
        }
        while !self.pending.is_empty() {
            let Some((&b, rest)) = data.split_first() else { return };
            self.pending.push(b);
            data = rest;
            at += 1;
            match std::str::from_utf8(&self.pending) {
                Ok(_) => self.pending.clear(),
                Err(e) => {
                    if let Some(n) = e.error_len() {
                        self.error = Some((self.pending_at + e.valid_up_to() as u64 - origin, Some(n)));
                        return;
                    }
                }
            }
        }
        if let Err(e) = std::str::from_utf8(data) {
            let bad = e.valid_up_to();
            match e.error_len() {
                Some(n) => self.error = Some((at + bad as u64 - origin, Some(n))),
                None => {
                    self.pending.extend_from_slice(&data[bad..]);
                    self.pending_at = at + bad as u64;
                }
            }
        }
    }

    /// The end of the text: the first error, as [`std::str::Utf8Error`] displays it.
    pub(super) fn end(&mut self) -> Option<String> {
        if self.error.is_none() && !self.pending.is_empty() {
            self.error = Some((self.pending_at - self.origin.unwrap_or(0), None));
        }
        self.error.map(|(at, len)| match len {
            Some(n) => format!("invalid utf-8 sequence of {n} bytes from index {at}"),
            None => format!("incomplete utf-8 byte sequence from index {at}"),
        })
    }
}

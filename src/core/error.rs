//! The library's error type: one enum whose variants carry the file and the problem, so the binary
//! can print a single line (`FILE: problem`) and exit non-zero.

use std::path::PathBuf;

use serde::Serialize;

/// Everything that can go wrong in relief's library code. Variants carry what a caller can act
/// on (the file, the limit, the offset) and chain their causes (`#[source]`); more may come, so
/// matches need a wildcard arm.
#[derive(Debug, thiserror::Error)]
#[non_exhaustive]
pub enum Error {
    #[error("{}: {source}", path.display())]
    Io {
        path: PathBuf,
        #[source]
        source: std::io::Error,
    },
    #[error("{}: unknown DEM format ({hint}); name the format to read it as", path.display())]
    UnknownFormat { path: PathBuf, hint: String },
    #[error("{}: {problem}", path.display())]
    BadDem { path: PathBuf, problem: String },
    #[error("{}: unsupported {what}", path.display())]
    Unsupported { path: PathBuf, what: String },
    /// A lossy-compressed DEM, refused unless asked for (its heights carry the codec's errors).
    #[error("{}: {what}; pass --allow-lossy to convert it anyway", path.display())]
    Lossy { path: PathBuf, what: String },
    #[error("{}: no valid sample (every sample is nodata, void or NaN)", path.display())]
    NoValidSamples { path: PathBuf },
    /// A relief file (terrain, VDT, meta-node or page file) that is not one, is of another version,
    /// is truncated, fails a checksum or holds inconsistent data (`format`).
    #[error("{}: {}", path.display(), problem.describe(*kind))]
    File { path: PathBuf, kind: FileKind, problem: Problem },
    /// A read past the end of a file (it is shorter than what was asked of it).
    #[error("{}: truncated: expected {expected} bytes, found {found}", path.display())]
    Truncated { path: PathBuf, expected: u64, found: u64 },
    #[error("{}: grid too large: {width} x {height} needs more than 2^{max_n} + 1 posts per side", path.display())]
    GridTooLarge { path: PathBuf, width: u64, height: u64, max_n: u32 },
    /// A grid whose terrain file or conversion scratch cannot be mapped (`pager::source::MAX_MAPPED_BYTES`).
    #[error("{}: a {side}² grid needs {} of {what}, more than the {} one process can map", path.display(), tib(*bytes), tib(*limit as u128))]
    TooLargeToMap { path: PathBuf, side: u64, what: &'static str, bytes: u128, limit: u64 },
    /// A flight-path file (`relief path`) that could not be parsed or holds an unusable frame.
    #[error("{}: {problem}", path.display())]
    BadPath { path: PathBuf, problem: String },
    /// A mesh file (`mesh::read_mesh`) that could not be parsed or holds unusable data.
    #[error("{}: {problem}", path.display())]
    BadMesh { path: PathBuf, problem: String },
    /// A memory budget too small for the step that needs it (`metanode::build`).
    #[error("memory budget of {budget_bytes} bytes is too small: {problem}")]
    MemoryBudget { budget_bytes: u64, problem: String },
    /// Scratch storage (the redb database of `metanode::build`) failed.
    #[error("{}: scratch database: {problem}", path.display())]
    Scratch { path: PathBuf, problem: String },
    /// A page layout (`diskpages::two_factor`) that could not be computed.
    #[error("page layout: {0}")]
    Layout(String),
    /// A remote file (HTTP range requests) that could not be read: the server's answer, a
    /// connection that kept failing after the retries, or a file that changed under us.
    #[error("{url}: {problem}")]
    Remote { url: String, problem: String },
    /// A number outside what relief accepts: what it is, what is allowed, what was given.
    #[error("{what} must be {allowed}, got {got}")]
    OutOfRange { what: &'static str, allowed: String, got: String },
    /// A block number past a file's block table (`pager`).
    #[error("{}: block {block} out of range ({blocks} blocks)", path.display())]
    BlockOutOfRange { path: PathBuf, block: u32, blocks: u32 },
    /// A thread relief needs could not be started (the OS refused: too many threads, no memory).
    #[error("cannot start the {what} thread: {source}")]
    Thread {
        what: String,
        #[source]
        source: std::io::Error,
    },
    /// An invariant relief's own code keeps did not hold: a bug, to be reported with the input.
    #[error("internal error in {stage}: {problem}")]
    Internal { stage: &'static str, problem: String },
    #[error("invalid argument: {0}")]
    InvalidArgument(String),
    /// An error of code outside the core that runs inside its loops or beside them (a
    /// renderer's `flight::frame::Presenter`, a window, a figure): its own error type, boxed.
    /// relief's binary puts its GPU, display and figure errors here (`relief::AppError`).
    #[error(transparent)]
    External(Box<dyn std::error::Error + Send + Sync + 'static>),
    #[error("interrupted")]
    Interrupted,
    /// The buffer pool (`pool`) could not start its I/O thread, or a block loader panicked.
    #[error("buffer pool: {0}")]
    Pool(String),
}

/// Bytes in TiB with two decimals (the sizes [`Error::TooLargeToMap`] speaks of).
pub(crate) fn tib(bytes: u128) -> String {
    format!("{:.2} TiB", bytes as f64 / (1u64 << 40) as f64)
}

pub type Result<T, E = Error> = std::result::Result<T, E>;

impl Error {
    /// Wraps an I/O error with the path it concerns.
    pub fn io(path: impl Into<PathBuf>, source: std::io::Error) -> Self {
        Error::Io { path: path.into(), source }
    }

    /// A DEM that could be opened but whose content is wrong.
    pub fn bad_dem(path: impl Into<PathBuf>, problem: impl Into<String>) -> Self {
        Error::BadDem { path: path.into(), problem: problem.into() }
    }

    /// A remote file that could not be read.
    pub fn remote(url: &str, problem: impl Into<String>) -> Self {
        Error::Remote { url: url.into(), problem: problem.into() }
    }

    /// A mesh file whose content is wrong.
    pub fn bad_mesh(path: impl Into<PathBuf>, problem: impl Into<String>) -> Self {
        Error::BadMesh { path: path.into(), problem: problem.into() }
    }

    /// A number outside what relief accepts.
    pub fn out_of_range(what: &'static str, allowed: impl Into<String>, got: impl std::fmt::Display) -> Self {
        Error::OutOfRange { what, allowed: allowed.into(), got: got.to_string() }
    }

    /// A thread that could not be started.
    pub fn thread(what: impl Into<String>) -> impl FnOnce(std::io::Error) -> Self {
        let what = what.into();
        move |source| Error::Thread { what, source }
    }

    /// A flight-path file whose content is wrong.
    pub fn bad_path(path: impl Into<PathBuf>, problem: impl Into<String>) -> Self {
        Error::BadPath { path: path.into(), problem: problem.into() }
    }
}

/// Extension to attach a path to `std::io::Result`.
pub trait IoContext<T> {
    fn at(self, path: &std::path::Path) -> Result<T>;
}

impl<T> IoContext<T> for std::io::Result<T> {
    fn at(self, path: &std::path::Path) -> Result<T> {
        self.map_err(|e| Error::io(path, e))
    }
}

/// The kinds of relief file.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash, Serialize)]
#[serde(rename_all = "lowercase")]
pub enum FileKind {
    Terrain,
    Vdt,
    MetaNode,
    Pages,
    Imagery,
    Shard,
}

impl FileKind {
    pub const ALL: [FileKind; 6] =
        [FileKind::Terrain, FileKind::Vdt, FileKind::MetaNode, FileKind::Pages, FileKind::Imagery, FileKind::Shard];

    /// What messages call it.
    pub fn name(self) -> &'static str {
        match self {
            FileKind::Terrain => "terrain file",
            FileKind::Vdt => "VDT file",
            FileKind::MetaNode => "meta-node file",
            FileKind::Pages => "page file",
            FileKind::Imagery => "imagery tile file",
            FileKind::Shard => "conversion shard file",
        }
    }

    /// Its first 8 bytes.
    pub fn magic(self) -> [u8; 8] {
        match self {
            FileKind::Terrain => *b"\x89RELIEF\n",
            FileKind::Vdt => *b"\x89RLFVDT\n",
            FileKind::MetaNode => *b"\x89RLFMNT\n",
            FileKind::Pages => *b"\x89RLFPGS\n",
            FileKind::Imagery => *b"\x89RLFIMG\n",
            FileKind::Shard => *b"\x89RLFSHD\n",
        }
    }

    /// The kind whose magic `bytes` start with.
    pub fn of_magic(bytes: &[u8]) -> Option<FileKind> {
        FileKind::ALL.into_iter().find(|k| bytes.len() >= 8 && bytes[..8] == k.magic())
    }
}

impl std::fmt::Display for FileKind {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.write_str(self.name())
    }
}

/// What is wrong with a relief file (see [`Error::File`]).
#[derive(Clone, Debug, PartialEq, Eq)]
#[non_exhaustive]
pub enum Problem {
    /// The first 8 bytes are not the format's magic.
    BadMagic,
    /// A version this build does not read (it reads `oldest` to `supported`).
    Version { found: u32, oldest: u32, supported: u32 },
    /// The file is shorter (or longer) than its header says it must be.
    Truncated { expected: u64, found: u64 },
    /// A stored checksum disagrees with the bytes.
    Checksum { which: &'static str, stored: u64, computed: u64 },
    /// A field, a table entry or a block that is inconsistent.
    Corrupt(String),
    /// A record, block or table entry that is inconsistent, at byte `offset` of the file (where
    /// a tool such as `xxd -s` finds it).
    CorruptAt { offset: u64, what: String },
}

impl Problem {
    /// The problem as said of a file of kind `kind`.
    pub fn describe(&self, kind: FileKind) -> String {
        match self {
            Problem::BadMagic => format!("not a relief {kind} (bad magic)"),
            Problem::Version { found, oldest, supported } if oldest < supported => {
                format!("{kind} version {found} is not supported (this build reads versions {oldest} to {supported})")
            }
            Problem::Version { found, supported, .. } => {
                format!("{kind} version {found} is not supported (this build reads version {supported})")
            }
            Problem::Truncated { expected, found } if found < expected => {
                format!("truncated {kind}: expected {expected} bytes, found {found}")
            }
            Problem::Truncated { expected, found } => {
                format!("{kind} has {} bytes past its end (expected {expected} bytes, found {found})", found - expected)
            }
            Problem::Checksum { which, stored, computed } => {
                format!("{kind}: {which} checksum mismatch (stored {stored:016x}, computed {computed:016x})")
            }
            Problem::Corrupt(what) => format!("corrupt {kind}: {what}"),
            Problem::CorruptAt { offset, what } => format!("corrupt {kind} at byte {offset}: {what}"),
        }
    }
}

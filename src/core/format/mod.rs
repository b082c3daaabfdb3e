//! relief's six file formats and the one container they share.
//!
//! Every relief file starts with the same 256-byte header block:
//!
//! ```text
//! offset size  field
//!      0    8  magic: "\x89RELIEF\n" (terrain), "\x89RLFVDT\n" (VDT), "\x89RLFMNT\n" (meta-node),
//!              "\x89RLFPGS\n" (pages), "\x89RLFIMG\n" (imagery tiles),
//!              "\x89RLFSHD\n" (conversion shard)
//!      8    4  version of that format
//!     12  236  the format's own fields (little-endian)
//!    248    8  header checksum: XXH3-64 of bytes 0..248
//! ```
//!
//! and is opened the same way: the header is read through the file's [`Source`], then magic,
//! version and checksum are checked here, then the format's [`Format::decode`] checks its fields
//! against each other and against the file's length. The errors ([`Error::File`]) name the file
//! and the format. The formats:
//!
//! - [`terrain`]: vertex records (height, nested error, bounding radius) in an index layout;
//! - [`vdt`]: a view-dependence forest (the meta-node build's intermediate file);
//! - [`metanode`]: meta-node trees blocked into disk pages (DATA + MNT);
//! - [`pagefile`]: self-contained disk pages with their directory and k-d tree;
//! - [`imagery`]: an image's mip levels in tiles, for draping imagery larger than memory;
//! - [`shard`]: one shard of a sharded conversion, merged into a terrain file.

use std::path::Path;

pub use crate::error::{FileKind, Problem};

use crate::error::{Error, Result};
use crate::pager::source::Source;

pub mod imagery;
pub mod metanode;
pub mod pagefile;
pub mod shard;
pub mod terrain;
pub mod vdt;

/// Bytes of the header block every relief file starts with.
pub const HEADER_BYTES: usize = 256;
/// Where the header checksum sits (it covers the bytes before it).
const CHECKSUM_AT: usize = 248;

// `FileKind` and `Problem` live in `error` (so `Error::File` needs nothing above it); the
// versions stay here, next to the formats that define them.
impl FileKind {
    /// The version this build writes and reads.
    pub fn version(self) -> u32 {
        match self {
            FileKind::Terrain => terrain::VERSION,
            FileKind::Vdt => vdt::VERSION,
            FileKind::MetaNode => metanode::VERSION,
            FileKind::Pages => pagefile::VERSION,
            FileKind::Imagery => imagery::VERSION,
            FileKind::Shard => shard::VERSION,
        }
    }

    /// The oldest version this build reads (it writes [`Self::version`]).
    pub fn oldest_version(self) -> u32 {
        match self {
            FileKind::Terrain => terrain::OLDEST_VERSION,
            _ => self.version(),
        }
    }

    /// Whether this build reads `version` of this kind.
    pub fn reads_version(self, version: u32) -> bool {
        (self.oldest_version()..=self.version()).contains(&version)
    }
}

// The box the VDT, meta-node and page file headers store (re-exported as `mesh::Bounds`).
/// Axis-aligned bounding box.
#[derive(Clone, Copy, Debug, PartialEq, serde::Serialize)]
pub struct Bounds {
    pub min: [f64; 3],
    pub max: [f64; 3],
}

impl Bounds {
    /// Centre of the box.
    pub fn centre(&self) -> glam::DVec3 {
        (glam::DVec3::from(self.min) + glam::DVec3::from(self.max)) / 2.0
    }

    /// Side lengths along x, y, z.
    pub fn extent(&self) -> [f64; 3] {
        [0, 1, 2].map(|k| self.max[k] - self.min[k])
    }

    /// Length of the diagonal.
    pub fn diagonal(&self) -> f64 {
        glam::DVec3::from(self.extent()).length()
    }

    /// Distance from `p` to the box (0 inside or on it).
    pub fn distance_to(&self, p: glam::DVec3) -> f64 {
        let lo = glam::DVec3::from(self.min) - p;
        let hi = p - glam::DVec3::from(self.max);
        lo.max(hi).max(glam::DVec3::ZERO).length()
    }
}

/// The header block of a relief file: 256 bytes, little-endian fields at fixed offsets.
#[derive(Clone, PartialEq, Eq)]
pub struct HeaderBytes(pub [u8; HEADER_BYTES]);

impl std::fmt::Debug for HeaderBytes {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        write!(f, "HeaderBytes({:02x?}…)", &self.0[..16])
    }
}

impl HeaderBytes {
    /// A zeroed header with `kind`'s magic and version.
    pub fn new(kind: FileKind) -> HeaderBytes {
        let mut h = HeaderBytes([0; HEADER_BYTES]);
        h.0[..8].copy_from_slice(&kind.magic());
        h.put_u32(8, kind.version());
        h
    }

    pub fn u32(&self, at: usize) -> u32 {
        u32::from_le_bytes(self.0[at..at + 4].try_into().expect("4 bytes"))
    }
    pub fn u64(&self, at: usize) -> u64 {
        u64::from_le_bytes(self.0[at..at + 8].try_into().expect("8 bytes"))
    }
    pub fn f64(&self, at: usize) -> f64 {
        f64::from_bits(self.u64(at))
    }
    pub fn put_u32(&mut self, at: usize, v: u32) {
        self.0[at..at + 4].copy_from_slice(&v.to_le_bytes());
    }
    pub fn put_u64(&mut self, at: usize, v: u64) {
        self.0[at..at + 8].copy_from_slice(&v.to_le_bytes());
    }
    pub fn put_f64(&mut self, at: usize, v: f64) {
        self.put_u64(at, v.to_bits());
    }

    /// Three f64 at `at` (a point or one corner of a box).
    pub fn f64x3(&self, at: usize) -> [f64; 3] {
        [self.f64(at), self.f64(at + 8), self.f64(at + 16)]
    }
    pub fn put_f64x3(&mut self, at: usize, v: [f64; 3]) {
        for (k, c) in v.into_iter().enumerate() {
            self.put_f64(at + 8 * k, c);
        }
    }

    /// The checksum the bytes before it hash to.
    pub fn computed_checksum(&self) -> u64 {
        xxhash_rust::xxh3::xxh3_64(&self.0[..CHECKSUM_AT])
    }

    /// Stamps the header checksum (after every other field is set).
    pub fn seal(&mut self) {
        let sum = self.computed_checksum();
        self.put_u64(CHECKSUM_AT, sum);
    }

    /// Checks magic, version and checksum as a file of kind `kind` (in that order, so a file of
    /// another kind, or another version, is named as such rather than as damaged).
    pub fn check(&self, kind: FileKind) -> std::result::Result<(), Problem> {
        if self.0[..8] != kind.magic() {
            return Err(Problem::BadMagic);
        }
        let version = self.u32(8);
        if !kind.reads_version(version) {
            return Err(Problem::Version { found: version, oldest: kind.oldest_version(), supported: kind.version() });
        }
        let (stored, computed) = (self.u64(CHECKSUM_AT), self.computed_checksum());
        if stored != computed {
            return Err(Problem::Checksum { which: "header", stored, computed });
        }
        Ok(())
    }
}

/// One of relief's file formats: its typed header, read from and written to the header block.
pub trait Format: Sized {
    const KIND: FileKind;
    /// Decodes the format's fields from a header whose magic, version and checksum are checked,
    /// and checks them against each other and against the file's length.
    fn decode(h: &HeaderBytes, file_len: u64) -> std::result::Result<Self, Problem>;
    /// Writes the format's fields (magic, version and checksum are the container's).
    fn encode_fields(&self, h: &mut HeaderBytes);

    /// The sealed header block.
    fn encode(&self) -> HeaderBytes {
        let mut h = HeaderBytes::new(Self::KIND);
        self.encode_fields(&mut h);
        h.seal();
        h
    }
}

/// An error about a file of kind `kind` at `path`.
pub fn file_error(path: &Path, kind: FileKind, problem: Problem) -> Error {
    Error::File { path: path.to_path_buf(), kind, problem }
}

/// A [`Problem::Corrupt`] error.
pub fn corrupt(path: &Path, kind: FileKind, what: impl Into<String>) -> Error {
    file_error(path, kind, Problem::Corrupt(what.into()))
}

/// A [`Problem::CorruptAt`] error: what is wrong at byte `offset` of the file.
pub fn corrupt_at(path: &Path, kind: FileKind, offset: u64, what: impl Into<String>) -> Error {
    file_error(path, kind, Problem::CorruptAt { offset, what: what.into() })
}

/// Decodes header bytes as format `F` (the container's checks, then `F`'s).
pub fn decode_header<F: Format>(path: &Path, bytes: &[u8], file_len: u64) -> Result<F> {
    let err = |p| file_error(path, F::KIND, p);
    if bytes.len() < 8 || bytes[..8] != F::KIND.magic() {
        return Err(err(Problem::BadMagic));
    }
    if bytes.len() >= 12 {
        let version = u32::from_le_bytes(bytes[8..12].try_into().expect("4 bytes"));
        if !F::KIND.reads_version(version) {
            return Err(err(Problem::Version {
                found: version,
                oldest: F::KIND.oldest_version(),
                supported: F::KIND.version(),
            }));
        }
    }
    if bytes.len() < HEADER_BYTES {
        return Err(err(Problem::Truncated { expected: HEADER_BYTES as u64, found: file_len }));
    }
    let h = HeaderBytes(bytes[..HEADER_BYTES].try_into().expect("256 bytes"));
    h.check(F::KIND).map_err(err)?;
    F::decode(&h, file_len).map_err(err)
}

/// Reads and validates `F`'s header from `source`: the one open path of every format.
pub fn read_header<F: Format>(source: &dyn Source) -> Result<F> {
    let n = (HEADER_BYTES as u64).min(source.len()) as usize;
    let mut bytes = vec![0u8; n];
    source.read_at(0, &mut bytes)?;
    decode_header(source.path(), &bytes, source.len())
}

/// The kind of relief file at `path`, from its magic (`None`: not a relief file, e.g. a DEM or a
/// mesh).
pub fn sniff(path: &Path) -> Result<Option<FileKind>> {
    use std::io::Read;
    let mut head = [0u8; 8];
    let mut f = std::fs::File::open(path).map_err(|e| Error::io(path, e))?;
    let mut n = 0;
    while n < 8 {
        match f.read(&mut head[n..]) {
            Ok(0) => break,
            Ok(k) => n += k,
            Err(e) if e.kind() == std::io::ErrorKind::Interrupted => {}
            Err(e) => return Err(Error::io(path, e)),
        }
    }
    Ok(FileKind::of_magic(&head[..n]))
}

/// A section's end (`offset + count × size`), or a corrupt-file problem when it overflows.
pub fn section_end(offset: u64, count: u64, size: u64, what: &str) -> std::result::Result<u64, Problem> {
    count
        .checked_mul(size)
        .and_then(|b| b.checked_add(offset))
        .ok_or_else(|| Problem::Corrupt(format!("the size of {what} overflows")))
}

#[cfg(test)]
mod tests {
    use super::*;

    /// A format with one field, for the container's own checks.
    #[derive(Debug, PartialEq)]
    struct Toy(u64);

    impl Format for Toy {
        const KIND: FileKind = FileKind::Pages;
        fn decode(h: &HeaderBytes, file_len: u64) -> std::result::Result<Toy, Problem> {
            if file_len != 256 {
                return Err(Problem::Truncated { expected: 256, found: file_len });
            }
            match h.u64(16) {
                0 => Err(Problem::Corrupt("zero".into())),
                v => Ok(Toy(v)),
            }
        }
        fn encode_fields(&self, h: &mut HeaderBytes) {
            h.put_u64(16, self.0);
        }
    }

    #[test]
    fn every_kind_has_its_own_magic_and_a_name() {
        for k in FileKind::ALL {
            assert_eq!(FileKind::of_magic(&k.magic()), Some(k));
            assert!(k.name().ends_with(" file"));
        }
        assert_eq!(FileKind::of_magic(b"II*\0\x08\0\0\0"), None);
        assert_eq!(FileKind::of_magic(b"\x89REL"), None);
    }

    #[test]
    fn the_container_checks_magic_version_checksum_and_size_in_that_order() {
        let p = Path::new("t.rpg");
        let good = Toy(7).encode().0;
        assert_eq!(decode_header::<Toy>(p, &good, 256).unwrap(), Toy(7));
        let msg = |b: &[u8], len: u64| decode_header::<Toy>(p, b, len).unwrap_err().to_string();
        let mut b = good;
        b[0] = b'X';
        assert_eq!(msg(&b, 256), "t.rpg: not a relief page file (bad magic)");
        let mut b = good;
        b[8] = 9;
        assert_eq!(msg(&b, 256), "t.rpg: page file version 9 is not supported (this build reads version 1)");
        let mut b = good;
        b[20] ^= 1;
        assert!(msg(&b, 256).starts_with("t.rpg: page file: header checksum mismatch (stored "), "{}", msg(&b, 256));
        assert_eq!(msg(&good[..100], 100), "t.rpg: truncated page file: expected 256 bytes, found 100");
        assert_eq!(msg(&good, 200), "t.rpg: truncated page file: expected 256 bytes, found 200");
        assert_eq!(msg(&good, 300), "t.rpg: page file has 44 bytes past its end (expected 256 bytes, found 300)");
        assert_eq!(msg(&Toy(0).encode().0, 256), "t.rpg: corrupt page file: zero");
        // Another kind's file is named by what it is not.
        assert_eq!(msg(&HeaderBytes::new(FileKind::Terrain).0, 256), "t.rpg: not a relief page file (bad magic)");
    }
}

//! Conversion shard files: what one shard of a sharded conversion (`preprocess::shard`) hands
//! to the merge.
//!
//! ```text
//! offset size  field (after the container's magic and version)
//!     12   16  shard index, shard count, block side log2, lattice step log2 (u32)
//!     28    4  blocks this shard computed
//!     32   16  z min, z max over the shard's DEM posts (f64; +inf/-inf when it has none)
//!     48   80  five sections, each (offset, count) u64:
//!              records   12 B: (z, error, radius) of the shard's vertices, in index order
//!              runs      16 B: (first index, length) of each run of consecutive records
//!              foreign   16 B: (index, error, radius) partial bounds of other shards' vertices
//!              centres   20 B: (x, y, z, error, radius) of its vertices of the blocks' top level
//!              posts     12 B: (x, y, z) heights of the coarse lattice's posts
//!    128    8  body checksum: XXH3-64 of bytes 256..file end
//!    136    8  file length
//!    256  256  the terrain header the merge writes (its height range, page map and checksum
//!              still to fill)
//!    512       the sections, in the order above
//! ```

use super::{section_end, Format, HeaderBytes, Problem, HEADER_BYTES};
use crate::error::FileKind;

pub const VERSION: u32 = 1;
/// Where the first section starts: the header block, then the terrain header template.
pub const SECTIONS_AT: u64 = 2 * HEADER_BYTES as u64;

/// Bytes of one entry of each section, in section order.
pub const ENTRY_BYTES: [u64; 5] = [12, 16, 16, 20, 12];
/// Section names, for messages.
pub const SECTION_NAMES: [&str; 5] = ["records", "runs", "foreign bounds", "centres", "posts"];

#[derive(Clone, Debug, PartialEq)]
pub struct ShardHeader {
    pub shard: u32,
    pub shards: u32,
    pub block_bits: u32,
    pub lattice_bits: u32,
    pub blocks: u32,
    pub z_min: f64,
    pub z_max: f64,
    /// `(offset, count)` of records, runs, foreign, centres, posts.
    pub sections: [(u64, u64); 5],
    pub body_checksum: u64,
    pub file_len: u64,
}

impl ShardHeader {
    /// Sections laid out one after another from [`SECTIONS_AT`], for these counts.
    pub fn layout(counts: [u64; 5]) -> ([(u64, u64); 5], u64) {
        let mut at = SECTIONS_AT;
        let mut sections = [(0, 0); 5];
        for k in 0..5 {
            sections[k] = (at, counts[k]);
            at += counts[k] * ENTRY_BYTES[k];
        }
        (sections, at)
    }
}

impl Format for ShardHeader {
    const KIND: FileKind = FileKind::Shard;

    fn encode_fields(&self, h: &mut HeaderBytes) {
        h.put_u32(12, self.shard);
        h.put_u32(16, self.shards);
        h.put_u32(20, self.block_bits);
        h.put_u32(24, self.lattice_bits);
        h.put_u32(28, self.blocks);
        h.put_f64(32, self.z_min);
        h.put_f64(40, self.z_max);
        for (k, (offset, count)) in self.sections.iter().enumerate() {
            h.put_u64(48 + 16 * k, *offset);
            h.put_u64(56 + 16 * k, *count);
        }
        h.put_u64(128, self.body_checksum);
        h.put_u64(136, self.file_len);
    }

    fn decode(b: &HeaderBytes, file_len: u64) -> std::result::Result<Self, Problem> {
        let bad = |what: String| Problem::Corrupt(format!("header: {what}"));
        let mut sections = [(0, 0); 5];
        for (k, s) in sections.iter_mut().enumerate() {
            *s = (b.u64(48 + 16 * k), b.u64(56 + 16 * k));
        }
        let h = ShardHeader {
            shard: b.u32(12),
            shards: b.u32(16),
            block_bits: b.u32(20),
            lattice_bits: b.u32(24),
            blocks: b.u32(28),
            z_min: b.f64(32),
            z_max: b.f64(40),
            sections,
            body_checksum: b.u64(128),
            file_len: b.u64(136),
        };
        if h.shards == 0 || h.shard >= h.shards {
            return Err(bad(format!("shard {} of {}", h.shard, h.shards)));
        }
        if h.file_len != file_len {
            return Err(Problem::Truncated { expected: h.file_len, found: file_len });
        }
        let mut at = SECTIONS_AT;
        for (k, &(offset, count)) in h.sections.iter().enumerate() {
            if offset != at {
                return Err(bad(format!("{} at {offset} (expected {at})", SECTION_NAMES[k])));
            }
            at = section_end(offset, count, ENTRY_BYTES[k], SECTION_NAMES[k])?;
        }
        if at != file_len {
            return Err(bad(format!("sections end at {at}, the file at {file_len}")));
        }
        Ok(h)
    }
}

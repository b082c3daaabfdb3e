//! Inputs the fuzzers (`tools/fuzz.sh`) found crashing a reader, kept as regression tests: each
//! must now give a clean error or a well-formed value, never a panic.

use crate::common;

use std::alloc::{GlobalAlloc, Layout, System};
use std::cell::Cell;
use std::path::PathBuf;

/// The system allocator, noting the largest single allocation made on each thread, so a test
/// can assert that a reader did not size a buffer from a header it did not bound.
struct Tracking;

thread_local! {
    static LARGEST: Cell<usize> = const { Cell::new(0) };
}

fn note(size: usize) {
    let _ = LARGEST.try_with(|l| l.set(l.get().max(size)));
}

// SAFETY: every call is forwarded unchanged to the system allocator; `note` only records a size.
unsafe impl GlobalAlloc for Tracking {
    unsafe fn alloc(&self, layout: Layout) -> *mut u8 {
        note(layout.size());
        // SAFETY: forwarded unchanged to the system allocator.
        unsafe { System.alloc(layout) }
    }

    unsafe fn alloc_zeroed(&self, layout: Layout) -> *mut u8 {
        note(layout.size());
        // SAFETY: as above.
        unsafe { System.alloc_zeroed(layout) }
    }

    unsafe fn realloc(&self, ptr: *mut u8, layout: Layout, new_size: usize) -> *mut u8 {
        note(new_size);
        // SAFETY: as above.
        unsafe { System.realloc(ptr, layout, new_size) }
    }

    unsafe fn dealloc(&self, ptr: *mut u8, layout: Layout) {
        // SAFETY: as above.
        unsafe { System.dealloc(ptr, layout) }
    }
}

#[global_allocator]
static ALLOCATOR: Tracking = Tracking;

/// The largest single allocation `f` made on this thread.
fn largest_allocation<R>(f: impl FnOnce() -> R) -> (R, usize) {
    LARGEST.with(|l| l.set(0));
    let r = f();
    (r, LARGEST.with(Cell::get))
}

fn input(name: &str) -> PathBuf {
    PathBuf::from(env!("CARGO_MANIFEST_DIR")).join("tests/fuzz_regressions").join(name)
}

/// A VDT file whose leaf has a triangle start far past the section (leaves own no triangles, so
/// open does not check it): every node's triangle list is readable, leaves' empty.
#[test]
fn vdt_leaf_with_a_wild_triangle_start() {
    let f = relief::metanode::VdtFile::open(&input("vdt-leaf-triangle-start.vdt")).unwrap();
    for id in 0..f.nodes().len() as u32 {
        let tris = f.node_triangles(id);
        assert!(id as u64 >= f.leaves() || tris.is_empty(), "leaf {id} has triangles");
    }
}

/// A meta-node file whose table entry's offset + size overflows u64: a one-line error naming the
/// file, from the library and from the command line.
#[test]
fn metanode_entry_whose_offset_overflows() {
    let path = input("metanode-entry-offset-overflow.rmn");
    let e = relief::format::metanode::MetaNodeFile::open(&path).err().expect("an error").to_string();
    assert!(e.contains("metanode-entry-offset-overflow.rmn") && e.contains("inconsistent"), "{e}");
    let dir = tempfile::tempdir().unwrap();
    let flight = dir.path().join("p.json");
    std::fs::write(&flight, "[\n  {\"eye\":[0,0,5],\"look\":[0,0,0]}\n]\n").unwrap();
    let o = common::relief()
        .args(["mesh", "fly"])
        .arg(&path)
        .arg("--path")
        .arg(&flight)
        .arg("--no-render")
        .output()
        .unwrap();
    let err = common::stderr_of(&o);
    assert_eq!(o.status.code(), Some(1), "{err}");
    assert!(err.trim_end().lines().count() == 1 && err.contains("metanode-entry-offset-overflow.rmn"), "{err}");
}

/// An OpenEXR file of 335 bytes whose header claims scan-line blocks of gigabytes: `exr` sized
/// its chunk buffer from the header and allocated them. Refused with one line before reading.
#[test]
fn exr_claiming_huge_blocks_is_refused_before_allocating() {
    let path = input("exr-huge-block.exr");
    let (r, largest) = largest_allocation(|| relief::dem::open(&path, None).and_then(|mut s| s.read(&mut |_| Ok(()))));
    assert!(largest < 1 << 20, "{largest} bytes allocated at once");
    let e = r.expect_err("an error").to_string();
    assert!(e.contains("exr-huge-block.exr") && e.contains("OpenEXR blocks of") && !e.contains('\n'), "{e}");
}

/// A TIFF of 630 bytes claiming tiles billions of pixels wide: `tiff` sized a row buffer from the
/// tile width and allocated gigabytes while reading the first tile. Refused with one line.
#[test]
fn tiff_claiming_huge_tiles_is_refused_before_allocating() {
    let path = input("tiff-huge-tile.tif");
    let (r, largest) = largest_allocation(|| relief::dem::open(&path, None).and_then(|mut s| s.read(&mut |_| Ok(()))));
    assert!(largest < 1 << 20, "{largest} bytes allocated at once");
    let e = r.expect_err("an error").to_string();
    assert!(e.contains("tiff-huge-tile.tif") && e.contains("TIFF chunks of") && !e.contains('\n'), "{e}");
}

/// An OFF file of 60 bytes whose header claims 4.2·10^15 vertices: the reader reserved 2^24
/// vertices and faces up front (600 MB). Now the reservation is bounded by the file's length, and
/// the file fails with one line at its truncation.
#[test]
fn off_claiming_huge_counts_fails_without_reserving_for_them() {
    let path = input("off-huge-counts.off");
    let (r, largest) = largest_allocation(|| relief::mesh::read_mesh(&path));
    assert!(largest < 1 << 20, "{largest} bytes allocated at once");
    let e = r.expect_err("an error").to_string();
    assert!(e.contains("off-huge-counts.off") && !e.contains('\n'), "{e}");
}

/// Two OpenEXR files of 358 and 389 bytes with B44-compressed f16 blocks whose packed differences
/// overflow `exr`'s B44 arithmetic (u32, meant to wrap as in OpenEXR's reference decoder). Release
/// builds wrapped; builds with overflow checks (tests, debug, fuzzing) panicked inside `exr`.
/// Cargo.toml now builds `exr` without overflow checks in every profile, so each file streams to
/// the end or fails with one line, never a panic.
#[test]
fn exr_b44_blocks_that_overflow_decode_without_a_panic() {
    for name in ["exr-b44-overflow.exr", "exr-b44-overflow-2.exr"] {
        let path = input(name);
        let r = std::panic::catch_unwind(|| {
            relief::dem::open(&path, Some(relief::dem::DemFormat::Exr)).and_then(|mut s| {
                let mut samples = 0u64;
                s.read(&mut |run| {
                    samples += run.values.len() as u64;
                    Ok(())
                })
                .map(|()| samples)
            })
        });
        match r.unwrap_or_else(|_| panic!("{name}: the reader panicked")) {
            Ok(samples) => assert!(samples > 0, "{name}"),
            Err(e) => assert!(e.to_string().contains(name) && !e.to_string().contains('\n'), "{e}"),
        }
    }
}

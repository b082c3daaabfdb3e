//! Inputs the fuzzers (`tools/fuzz.sh`) found crashing a reader, kept as regression tests: each
//! must now give a clean error or a well-formed value, never a panic.

mod common;

use std::path::PathBuf;

fn input(name: &str) -> PathBuf {
    PathBuf::from(env!("CARGO_MANIFEST_DIR")).join("tests/fuzz_regressions").join(name)
}

/// A VDT file whose leaf has a triangle start far past the section (leaves own no triangles, so
/// open does not check it): every node's triangle list is readable, leaves' empty.
#[test]
fn vdt_leaf_with_a_wild_triangle_start() {
    let f = relief::vdtree::VdtFile::open(&input("vdt-leaf-triangle-start.vdt")).unwrap();
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
    let e = relief::vdtree::metanode::MetaNodeFile::open(&path).err().expect("an error").to_string();
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

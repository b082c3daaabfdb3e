//! The one container every relief file format shares (`relief_core::format`): per format, the golden
//! bytes of a header (any change to an on-disk format must change these, and its version, on
//! purpose), the header decoding back to itself, and every malformation the container and the
//! format refuse, each as one line naming the file and the format.

use std::path::Path;

use relief_core::format::imagery::ImageryHeader;
use relief_core::format::metanode::MetaHeader;
use relief_core::format::pagefile::{PageHeader, PageLayout};
use relief_core::format::terrain::{Header, PAYLOAD_OFFSET, RECORD_BYTES, RECORD_FORMAT_F32};
use relief_core::format::vdt::{VdtHeader, VdtMetric};
use relief_core::format::{decode_header, FileKind, Format, HeaderBytes, Problem};
use relief_core::georef::{unit, CrsKind, Georef};
use relief_core::layout::LayoutKind;
use relief_core::mesh::Bounds;

fn hex(b: &[u8]) -> String {
    b.iter().map(|x| format!("{x:02x}")).collect()
}

/// The bytes a [`hex`] string spells.
fn unhex(s: &str) -> Vec<u8> {
    (0..s.len() / 2).map(|k| u8::from_str_radix(&s[2 * k..2 * k + 2], 16).unwrap()).collect()
}

fn terrain_header() -> Header {
    // A 9 × 9 grid (n = 3) in the interleaved layout: 4 + 5·(4³ − 1)/3 = 109 records.
    Header {
        version: relief_core::format::terrain::VERSION,
        layout: LayoutKind::Interleaved,
        layout_param: 0,
        record_format: RECORD_FORMAT_F32,
        record_bytes: RECORD_BYTES,
        n: 3,
        flags: 2,
        valid_window: [0, 0, 7, 9],
        source_format: 0,
        records: 109,
        payload_offset: PAYLOAD_OFFSET,
        payload_bytes: 109 * 12,
        spacing_m: [25.0, 30.5],
        z_scale: 1.0,
        z_offset: 0.0,
        z_min: -12.5,
        z_max: 870.0,
        nodata_filled: 3,
        source_centre_lat_deg: 47.5,
        source_spacing_deg: [1.0 / 3600.0, 1.0 / 3600.0],
        georef: Some(Georef {
            kind: CrsKind::Projected,
            epsg: 2056,
            unit: unit::METRE,
            vertical_epsg: 5728,
            vertical_unit: unit::FOOT,
            origin: [2_600_000.0, 1_200_000.5],
            step: [25.0, 30.5],
        }),
        // The page after the payload (4096 + 109 × 12 bytes).
        void_mask_offset: 8192,
        page_map_pages: 0,
        payload_checksum: 0x0123_4567_89ab_cdef,
    }
}

/// The same header as version 1 wrote it (no CRS): still read, as version 1 without a CRS.
const TERRAIN_GOLDEN_V1: &str = concat!(
    "8952454c4945460a01000000000100000200000000000000010000000c000000",
    "0300000006000000090000000200000000000000000000000700000009000000",
    "00000000000000006d0000000000000051000000000000000010000000000000",
    "1c0500000000000000000000000039400000000000803e40000000000000f03f",
    "000000000000000000000000000029c00000000000308b400300000000000000",
    "0000000000c04740dfbc9a785634323fdfbc9a785634323f0000000000000000",
    "0000000000000000000000000000000000000000000000000000000000000000",
    "00000000000000000000000000000000efcdab8967452301d34f9e2cc2e27cb5",
);

/// The same header as version 2 wrote it (every page stored): still read.
const TERRAIN_GOLDEN_V2: &str = concat!(
    "8952454c4945460a02000000000100000200000000000000010000000c000000",
    "0300000006000000090000000200000000000000000000000700000009000000",
    "00000000000000006d0000000000000051000000000000000010000000000000",
    "1c0500000000000000000000000039400000000000803e40000000000000f03f",
    "000000000000000000000000000029c00000000000308b400300000000000000",
    "0000000000c04740dfbc9a785634323fdfbc9a785634323f0808000001002923",
    "601600002a2301000000000020d6434100000080804f32410000000000003940",
    "0000000000803e400020000000000000efcdab896745230183e5e0cdf537e87b",
);

fn vdt_header() -> VdtHeader {
    VdtHeader {
        metric: VdtMetric::Quadric,
        leaves: 3,
        nodes: 5,
        triangles: 1,
        base_triangles: 0,
        bounds: Bounds { min: [0.0, -1.0, 2.0], max: [1.0, 0.5, 3.0] },
    }
}

fn metanode_header() -> MetaHeader {
    MetaHeader {
        metric: 0,
        page_bytes: 4096,
        levels_per_node: 8,
        leaves: 100,
        nodes: 199,
        triangles: 196,
        base_triangles: 2,
        metanodes: 3,
        root_metanodes: 1,
        holder_bytes: 3000,
        mnt_offset: 4096,
        base_offset: 4096 + 3 * 24,
        data_offset: 8192,
        data_bytes: 3 * 4096,
        bounds: Bounds { min: [-1.0, -2.0, -3.0], max: [1.0, 2.0, 3.0] },
    }
}

fn pages_header() -> PageHeader {
    PageHeader {
        page_bytes: 1024,
        layout: PageLayout::Hilbert,
        pages: 2,
        triangles: 40,
        vertex_copies: 50,
        source_vertices: 30,
        kd_nodes: 1,
        kd_offset: 256 + 2 * 48,
        kd_refs: 2,
        refs_offset: 256 + 2 * 48 + 40,
        data_offset: 1024,
        bounds: Bounds { min: [0.0; 3], max: [4.0, 5.0, 6.0] },
        tables_checksum: 0xfeed_f00d,
    }
}

fn imagery_header() -> ImageryHeader {
    ImageryHeader {
        width: 1000,
        height: 300,
        tile: 254,
        levels: 3,
        placement: Some([2_600_012.5, 25.0, 1_200_987.5, 25.0]),
        wraps: false,
        tiles: 11,
        payload_checksum: 0x0123_4567_89ab_cdef,
    }
}

/// The file length each sample header describes.
fn file_len(kind: FileKind) -> u64 {
    match kind {
        // The void mask's checksum and 7 × 9 bits after the payload's page.
        FileKind::Terrain => 8192 + 8 + 8,
        FileKind::Vdt => vdt_header().file_bytes(),
        FileKind::MetaNode => 8192 + 3 * 4096,
        FileKind::Pages => 1024 + 2 * 1024,
        FileKind::Imagery => 4096 + 11 * 256 * 256 * 4,
        FileKind::Shard => shard_header().file_len,
    }
}

fn shard_header() -> relief_core::format::shard::ShardHeader {
    let (sections, file_len) = relief_core::format::shard::ShardHeader::layout([100, 3, 7, 5, 9]);
    relief_core::format::shard::ShardHeader {
        shard: 2,
        shards: 4,
        block_bits: 6,
        lattice_bits: 1,
        blocks: 3,
        z_min: 393.0,
        z_max: 870.0,
        sections,
        body_checksum: 0x0123_4567_89ab_cdef,
        file_len,
    }
}

#[test]
fn shard_headers_are_checked_as_every_format() {
    use relief_core::format::shard::ShardHeader;
    let h = shard_header();
    assert_eq!(h.file_len, 512 + 100 * 12 + 3 * 16 + 7 * 16 + 5 * 20 + 9 * 12);
    container_checks(&h, "s.shard");
    corrupt_field::<ShardHeader>("s.shard", |b| b.put_u32(12, 4), "shard 4 of 4");
    corrupt_field::<ShardHeader>("s.shard", |b| b.put_u64(64, 9000), "runs at 9000");
    corrupt_field::<ShardHeader>("s.shard", |b| b.put_u64(56, 101), "runs at");
}

/// The container's checks, the same for every format: magic, version, checksum, size; each a
/// one-line error naming the file and the format.
fn container_checks<F: Format + std::fmt::Debug + PartialEq>(good: &F, name: &str) {
    let kind = F::KIND;
    let len = file_len(kind);
    let path = Path::new(name);
    let bytes = good.encode().0;
    let decoded: F = decode_header(path, &bytes, len).unwrap();
    assert_eq!(&decoded, good, "{kind}: decodes back");
    assert_eq!(decoded.encode().0, bytes, "{kind}: encodes to the same bytes");
    let problem = |b: &[u8], len: u64| match decode_header::<F>(path, b, len) {
        Err(e @ relief_core::Error::File { .. }) => {
            let msg = e.to_string();
            assert!(msg.starts_with(&format!("{name}: ")) && !msg.contains('\n'), "{msg}");
            assert!(msg.contains(kind.name()), "{msg} does not name the {kind}");
            let relief_core::Error::File { kind: k, problem, .. } = e else { unreachable!() };
            assert_eq!(k, kind);
            problem
        }
        other => panic!("{kind}: {other:?}"),
    };
    let mut b = bytes;
    b[3] ^= 0x20;
    assert_eq!(problem(&b, len), Problem::BadMagic);
    // Another kind's header is not this kind's.
    for other in FileKind::ALL.into_iter().filter(|&o| o != kind) {
        assert_eq!(problem(&HeaderBytes::new(other).0, len), Problem::BadMagic, "{other} read as {kind}");
    }
    let mut b = bytes;
    b[8] = b[8].wrapping_add(7);
    assert!(matches!(problem(&b, len), Problem::Version { .. }));
    let mut b = bytes;
    b[200] ^= 1;
    assert!(matches!(problem(&b, len), Problem::Checksum { which: "header", .. }));
    assert!(matches!(problem(&bytes[..100], 100), Problem::Truncated { expected: 256, found: 100 }));
    assert!(matches!(problem(&bytes, len - 1), Problem::Truncated { .. }));
    assert!(matches!(problem(&bytes, len + 1), Problem::Truncated { .. }), "{kind}: bytes past the end");
    assert_eq!(FileKind::of_magic(&bytes), Some(kind));
}

/// A field inconsistent with the others, with a valid checksum: the format's own check.
fn corrupt_field<F: Format + std::fmt::Debug>(name: &str, edit: impl Fn(&mut HeaderBytes), want: &str) {
    let mut h = HeaderBytes(match F::KIND {
        FileKind::Terrain => terrain_header().encode().0,
        FileKind::Vdt => vdt_header().encode().0,
        FileKind::MetaNode => metanode_header().encode().0,
        FileKind::Pages => pages_header().encode().0,
        FileKind::Imagery => imagery_header().encode().0,
        FileKind::Shard => shard_header().encode().0,
    });
    edit(&mut h);
    h.seal();
    let e = decode_header::<F>(Path::new(name), &h.0, file_len(F::KIND)).unwrap_err().to_string();
    assert!(e.starts_with(&format!("{name}: corrupt {}: ", F::KIND.name())) && e.contains(want), "{e}");
}

/// Version 3 without stored pages (a file written before stored pages, relabelled, reads the same).
const TERRAIN_GOLDEN: &str = concat!(
    "8952454c4945460a03000000000100000200000000000000010000000c000000",
    "0300000006000000090000000200000000000000000000000700000009000000",
    "00000000000000006d0000000000000051000000000000000010000000000000",
    "1c0500000000000000000000000039400000000000803e40000000000000f03f",
    "000000000000000000000000000029c00000000000308b400300000000000000",
    "0000000000c04740dfbc9a785634323fdfbc9a785634323f0808000001002923",
    "601600002a2301000000000020d6434100000080804f32410000000000003940",
    "0000000000803e400020000000000000efcdab89674523010efe4d46657e7320",
);

#[test]
fn terrain_header_bytes_are_frozen_and_checked() {
    assert_eq!(hex(&terrain_header().encode().0), TERRAIN_GOLDEN);
    container_checks(&terrain_header(), "golden.relief");
    corrupt_field::<Header>("golden.relief", |h| h.put_u32(16, 99), "unknown layout code 99");
    corrupt_field::<Header>("golden.relief", |h| h.put_u64(72, 110), "110 records");
    corrupt_field::<Header>("golden.relief", |h| h.put_u32(188, 7 | 9001 << 16), "unknown CRS kind 7");
    corrupt_field::<Header>("golden.relief", |h| h.put_f64(216, 0.0), "CRS placement");
    corrupt_field::<Header>("golden.relief", |h| h.put_f64(200, f64::NAN), "CRS placement");
    corrupt_field::<Header>("golden.relief", |h| h.put_u64(232, 4096), "void mask offset 4096");
    // Stored pages (flag 4) need a page map; a page map needs the flag.
    corrupt_field::<Header>(
        "golden.relief",
        |h| h.put_u32(44, 2 | 4),
        "stored pages (flag 4) need version 3, a page map",
    );
    corrupt_field::<Header>("golden.relief", |h| h.put_u32(68, 3), "3 page map pages without stored pages");
}

#[test]
fn version_2_terrain_headers_still_open() {
    let bytes = unhex(TERRAIN_GOLDEN_V2);
    let h: Header = decode_header(Path::new("v2.relief"), &bytes, file_len(FileKind::Terrain)).unwrap();
    assert_eq!(h, Header { version: 2, ..terrain_header() });
    assert!(!h.stores_pages());
    assert_eq!(hex(&h.encode().0), TERRAIN_GOLDEN_V2);
}

#[test]
fn version_1_terrain_headers_still_open_without_a_crs() {
    let bytes = unhex(TERRAIN_GOLDEN_V1);
    let h: Header = decode_header(Path::new("v1.relief"), &bytes, PAYLOAD_OFFSET + 109 * 12).unwrap();
    assert_eq!(h, Header { version: 1, georef: None, void_mask_offset: 0, ..terrain_header() });
    // Version 1 re-encoded is byte for byte what version 1 wrote.
    assert_eq!(hex(&h.encode().0), TERRAIN_GOLDEN_V1);
    // Versions before 1 and after this build's are refused, naming both ends.
    for v in [0u32, relief_core::format::terrain::VERSION + 1] {
        let mut b = HeaderBytes(bytes.clone().try_into().unwrap());
        b.put_u32(8, v);
        b.seal();
        let e = decode_header::<Header>(Path::new("v.relief"), &b.0, file_len(FileKind::Terrain)).unwrap_err();
        assert_eq!(
            e.to_string(),
            format!(
                "v.relief: terrain file version {v} is not supported (this build reads versions 1 to {})",
                relief_core::format::terrain::VERSION
            )
        );
    }
}

#[test]
fn vdt_header_bytes_are_frozen_and_checked() {
    assert_eq!(
        hex(&vdt_header().encode().0[..96]),
        concat!(
            "89524c465644540a020000000100000003000000000000000500000000000000",
            "010000000000000000000000000000000000000000000000000000000000f0bf",
            "0000000000000040000000000000f03f000000000000e03f0000000000000840",
        )
    );
    container_checks(&vdt_header(), "golden.vdt");
    corrupt_field::<VdtHeader>("golden.vdt", |h| h.put_u64(24, 9), "9 nodes is more than a binary forest");
}

#[test]
fn metanode_header_bytes_are_frozen_and_checked() {
    assert_eq!(
        hex(&metanode_header().encode().0[..64]),
        concat!(
            "89524c464d4e540a010000000000000000100000080000006400000000000000",
            "c700000000000000c40000000000000002000000000000000300000000000000",
        )
    );
    container_checks(&metanode_header(), "golden.rmn");
    corrupt_field::<MetaHeader>("golden.rmn", |h| h.put_u32(16, 3000), "page size 3000");
    corrupt_field::<MetaHeader>("golden.rmn", |h| h.put_u64(88, 4097), "section offsets are inconsistent");
}

#[test]
fn page_header_bytes_are_frozen_and_checked() {
    assert_eq!(
        hex(&pages_header().encode().0[..64]),
        concat!(
            "89524c465047530a010000000001000000040000020000000200000000000000",
            "280000000000000032000000000000001e000000000000000001000000000000",
        )
    );
    container_checks(&pages_header(), "golden.rpg");
    corrupt_field::<PageHeader>("golden.rpg", |h| h.put_u32(20, 9), "unknown layout 9");
    corrupt_field::<PageHeader>("golden.rpg", |h| h.put_u64(24, 0), "0 pages");
}

#[test]
fn imagery_header_bytes_are_frozen_and_checked() {
    assert_eq!(
        hex(&imagery_header().encode().0[..96]),
        concat!(
            "89524c46494d470a01000000e80300002c010000fe0000000300000001000000",
            "0000004026d643410000000000003940000000805b5332410000000000003940",
            "0b00000000000000efcdab896745230100000000000000000000000000000000",
        )
    );
    container_checks(&imagery_header(), "golden.rimg");
    corrupt_field::<ImageryHeader>("golden.rimg", |h| h.put_u32(24, 4), "4 levels and 11 tiles");
    corrupt_field::<ImageryHeader>("golden.rimg", |h| h.put_u32(20, 2), "tiles of 2 texels");
    corrupt_field::<ImageryHeader>("golden.rimg", |h| h.put_u32(12, 0), "an image of 0 x 300 texels");
    corrupt_field::<ImageryHeader>("golden.rimg", |h| h.put_f64(40, -25.0), "texel sizes must be positive");
    corrupt_field::<ImageryHeader>("golden.rimg", |h| h.put_u32(28, 5), "unknown flags 0x5");
    corrupt_field::<ImageryHeader>("golden.rimg", |h| h.put_u32(28, 2), "wraps (flag 2) without a placement");
}

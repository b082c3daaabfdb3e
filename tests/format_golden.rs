//! Golden bytes of the version-1 header: any change to the on-disk format must change this test
//! (and the version number) on purpose.

use relief::format::terrain::{Header, PAYLOAD_OFFSET, RECORD_BYTES, RECORD_FORMAT_F32, VERSION};
use relief::format::{decode_header, Format};
use relief::layout::LayoutKind;

fn golden_header() -> Header {
    // A 9 × 9 grid (n = 3) in the interleaved layout: 4 + 5·(4³ − 1)/3 = 109 records.
    Header {
        version: VERSION,
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
        payload_checksum: 0x0123_4567_89ab_cdef,
    }
}

fn hex(b: &[u8]) -> String {
    b.iter().map(|x| format!("{x:02x}")).collect()
}

const GOLDEN: &str = concat!(
    "8952454c4945460a01000000000100000200000000000000010000000c000000",
    "0300000006000000090000000200000000000000000000000700000009000000",
    "00000000000000006d0000000000000051000000000000000010000000000000",
    "1c0500000000000000000000000039400000000000803e40000000000000f03f",
    "000000000000000000000000000029c00000000000308b400300000000000000",
    "0000000000c04740dfbc9a785634323fdfbc9a785634323f0000000000000000",
    "0000000000000000000000000000000000000000000000000000000000000000",
    "00000000000000000000000000000000efcdab8967452301d34f9e2cc2e27cb5",
);

#[test]
fn header_bytes_are_frozen() {
    let bytes = golden_header().encode().0;
    assert_eq!(hex(&bytes), GOLDEN);
    // And the frozen bytes decode back to the same header.
    let file_len = PAYLOAD_OFFSET + 109 * 12;
    let decoded: Header = decode_header(std::path::Path::new("golden.relief"), &bytes, file_len).unwrap();
    assert_eq!(decoded.encode().0, bytes);
}

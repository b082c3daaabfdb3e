//! `relief imagery` and paged imagery from the command line: the tile file of the bundled real
//! image, bad inputs as one-line errors with nothing written, and a headless flight whose imagery
//! cache stays within its GPU and upload budgets.

use std::ffi::OsStr;
use std::path::Path;

use crate::common::{self, fails_with, relief};

#[test]
fn relief_imagery_tiles_the_real_image_and_refuses_bad_input() {
    let dir = tempfile::tempdir().unwrap();
    let d = dir.path();
    let jpg = Path::new(env!("CARGO_MANIFEST_DIR")).join("data/imagery/earth_2048.jpg");
    let out = d.join("earth.rimg");
    let o = relief().arg("imagery").arg(&jpg).arg(&out).arg("--json").output().unwrap();
    assert!(o.status.success(), "{}", common::stderr_of(&o));
    let j: serde_json::Value = serde_json::from_slice(&o.stdout).unwrap();
    assert_eq!((j["width"].as_u64(), j["height"].as_u64(), j["levels"].as_u64()), (Some(2048), Some(1024), Some(5)));
    assert_eq!(j["file_bytes"].as_u64(), Some(std::fs::metadata(&out).unwrap().len()));
    // A world image wraps: the west edge's tiles border on the east edge's texels.
    let file = relief::format::imagery::ImageryFile::open(&out, relief::pager::Access::Map).unwrap();
    assert!(file.header().wraps);
    let g = file.grid().clone();
    let side = g.slot_side() as usize;
    let last = g.levels[0].tiles_x - 1;
    let (mut west, mut east) = (vec![0u32; side * side], vec![0u32; side * side]);
    file.read_tile(g.key(0, 0, 0), &mut west).unwrap();
    file.read_tile(g.key(0, last, 0), &mut east).unwrap();
    // West tile texel i = 0 is level texel −1 = 2047; in the east tile that is i = 2047 − (last·254 − 1).
    let i_east = (2047 - (last as usize * 254 - 1)) as usize;
    for j in 0..side {
        assert_eq!(west[j * side], east[j * side + i_east], "row {j}");
    }
    // The world file's placement travels with the tiles.
    let img = relief::render::imagery::Imagery::open(&out).unwrap();
    let whole = relief::render::imagery::Imagery::open(&jpg).unwrap();
    assert_eq!((img.width, img.height, img.placement), (2048, 1024, whole.placement));

    // `verify` checks a tile file's payload; a changed texel is one line naming the file.
    let o = relief().arg("verify").arg(&out).output().unwrap();
    assert!(
        o.status.success() && String::from_utf8_lossy(&o.stdout).contains("ok (69 tiles"),
        "{}",
        common::stderr_of(&o)
    );
    let mut bytes = std::fs::read(&out).unwrap();
    bytes[4096 + 3 * 262_144 + 77] ^= 1;
    let damaged = d.join("damaged.rimg");
    std::fs::write(&damaged, &bytes).unwrap();
    fails_with(
        &[OsStr::new("verify"), damaged.as_os_str()],
        "damaged.rimg: imagery tile file: payload checksum mismatch",
    );
    std::fs::remove_file(&damaged).unwrap();
    let junk = d.join("junk.png");
    std::fs::write(&junk, b"\x89PNG not really").unwrap();
    let bad_out = d.join("bad.rimg");
    let os = |p: &Path| p.as_os_str().to_owned();
    fails_with(&[OsStr::new("imagery"), &os(&junk), &os(&bad_out)], "junk.png");
    fails_with(&[OsStr::new("imagery"), &os(&out), &os(&bad_out)], "is already an imagery tile file");
    fails_with(&[OsStr::new("imagery"), &os(&d.join("none.jpg")), &os(&bad_out)], "none.jpg");
    fails_with(&[OsStr::new("imagery"), &os(&jpg), &os(&d.join("no/such/dir.rimg"))], "does not exist");
    assert!(!bad_out.exists());
    let left: Vec<_> = std::fs::read_dir(d).unwrap().map(|e| e.unwrap().file_name()).collect();
    assert_eq!(left.len(), 2, "only the tile file and the junk: {left:?}");
    // A tile file is no terrain to fly over.
    let p = os(&d.join("p.json"));
    let path_args = ["path", "flyover"].map(OsStr::new);
    fails_with(
        &[path_args[0], path_args[1], &os(&out), OsStr::new("--frames"), OsStr::new("4"), OsStr::new("--out"), &p],
        "imagery tile file",
    );
}

#[test]
fn a_flight_pages_imagery_within_its_budgets() {
    let dir = tempfile::tempdir().unwrap();
    let d = dir.path();
    let jpg = Path::new(env!("CARGO_MANIFEST_DIR")).join("data/imagery/earth_2048.jpg");
    let tiles = d.join("earth.rimg");
    let terrain = d.join("e.relief");
    let path = d.join("p.json");
    for args in [
        vec![OsStr::new("imagery"), jpg.as_os_str(), tiles.as_os_str(), OsStr::new("-q")],
        vec![
            OsStr::new("convert"),
            common::dem("etopo20_world.tif").as_os_str(),
            terrain.as_os_str(),
            OsStr::new("-q"),
        ],
    ] {
        let o = relief().args(&args).output().unwrap();
        assert!(o.status.success(), "{}", common::stderr_of(&o));
    }
    common::make_path("flyover", &terrain, 8, &path);
    // An image too large to hold whole: one line saying how to page it (only its header is read).
    let huge = d.join("huge.png");
    {
        let mut e = png::Encoder::new(std::fs::File::create(&huge).unwrap(), 20_000, 20_000);
        e.set_color(png::ColorType::Rgb);
        // The header and a first row of data: decoders read that far to know the size.
        let mut w = e.write_header().unwrap();
        let mut rows = w.stream_writer().unwrap();
        std::io::Write::write_all(&mut rows, &vec![90u8; 3 * 20_000 * 4]).unwrap();
        std::io::Write::flush(&mut rows).unwrap();
        drop(rows);
    }
    let (t, h, png_out) = (terrain.as_os_str(), huge.as_os_str(), d.join("huge_render.png"));
    fails_with(
        &["render".as_ref(), t, "--eye=1e6,1e6,1e6".as_ref(), "--look=2e6,2e6,0".as_ref(), "--imagery".as_ref(), h, "--out".as_ref(), png_out.as_os_str()],
        "a 20000 x 20000 image takes 1525.9 MiB decoded, more than the 512 MiB an image held whole may; cut it once with `relief imagery",
    );
    assert!(!png_out.exists());
    // 1,000,000 bytes: 3 slots of 262,144 bytes and the 404-byte table; one tile a frame.
    let o = relief()
        .arg("fly")
        .arg(&terrain)
        .arg("--path")
        .arg(&path)
        .args(["--imagery"])
        .arg(&tiles)
        .args(["--imagery-gpu-memory", "1000000", "--gpu-upload", "300000", "--z-exaggeration", "40"])
        .args(["--width", "160", "--height", "100", "--json"])
        .output()
        .unwrap();
    assert!(o.status.success(), "{}", common::stderr_of(&o));
    let j: serde_json::Value = serde_json::from_slice(&o.stdout).unwrap();
    let s = &j["summary"];
    let max = |k: &str| s[k]["max"].as_f64().unwrap();
    assert!(max("gpu_imagery_bytes") <= 3.0 * 262_144.0 + 404.0, "{s}");
    assert!(max("imagery_tiles_resident") >= 2.0 && max("imagery_tiles_resident") <= 3.0, "{s}");
    assert!(max("imagery_upload_bytes") <= 300_000.0, "{s}");
    assert_eq!(j["frames"].as_array().unwrap().len(), 8);
}

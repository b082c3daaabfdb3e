//! Shared by the fuzz targets: the readers take paths, so each input is written to a file in a
//! RAM-backed directory (/dev/shm where it exists) under the name the reader expects.

use std::path::PathBuf;

pub fn input_file(name: &str, bytes: &[u8]) -> (tempfile::TempDir, PathBuf) {
    let base = if std::path::Path::new("/dev/shm").is_dir() { "/dev/shm" } else { "/tmp" };
    let dir = tempfile::tempdir_in(base).expect("a temporary directory");
    let path = dir.path().join(name);
    std::fs::write(&path, bytes).expect("writing the input");
    (dir, path)
}

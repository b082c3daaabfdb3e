//! ESRI ASCII grid (`.asc`) reader. The header has `key value` lines in any order and any case:
//! `ncols`, `nrows`, `xllcorner` or `xllcenter`, `yllcorner` or `yllcenter`, `cellsize` (or `dx`
//! and `dy`), and optionally `nodata_value`; unknown keys are ignored. The body is a stream of
//! `nrows · ncols` numbers, north row first; line breaks need not coincide with rows.
//!
//! The spacing is in metres, unless a sibling `.prj` file (same stem) describes a geographic
//! coordinate system (`GEOGCS` without `PROJCS`), in which case it is in degrees.
//!
//! The file is streamed a line at a time.

use std::fs::File;
use std::io::{BufRead, BufReader};
use std::path::{Path, PathBuf};

use super::{check_dimensions, DemFormat, DemInfo, DemSource, Run, SourceSpacing, MAX_RUN};
use crate::error::{Error, IoContext, Result};
use crate::georef::{unit, CrsKind, Georef};

/// Whether `head` (the first bytes of a file) starts like an ASCII grid: its first token is
/// `ncols` or `nrows`, in any case.
pub(super) fn looks_like_asc(head: &[u8]) -> bool {
    let head = head.strip_prefix(b"\xef\xbb\xbf").unwrap_or(head);
    let token: Vec<u8> = head
        .iter()
        .copied()
        .skip_while(u8::is_ascii_whitespace)
        .take_while(|b| !b.is_ascii_whitespace())
        .take(6)
        .collect();
    token.eq_ignore_ascii_case(b"ncols") || token.eq_ignore_ascii_case(b"nrows")
}

/// A buffered reader that keeps the current line and its 1-based number for error messages.
struct Lines {
    path: PathBuf,
    reader: BufReader<File>,
    line: String,
    number: u64,
}

impl Lines {
    fn open(path: &Path) -> Result<Lines> {
        let reader = BufReader::new(File::open(path).at(path)?);
        Ok(Lines { path: path.to_path_buf(), reader, line: String::new(), number: 0 })
    }

    /// Reads the next line into `self.line`; false at the end of the file.
    fn advance(&mut self) -> Result<bool> {
        self.line.clear();
        self.number += 1;
        match self.reader.read_line(&mut self.line) {
            Ok(0) => Ok(false),
            Ok(_) => {
                // A UTF-8 byte order mark on the first line is not part of the text.
                if self.number == 1 && self.line.starts_with('\u{feff}') {
                    self.line.drain(..'\u{feff}'.len_utf8());
                }
                Ok(true)
            }
            Err(e) if e.kind() == std::io::ErrorKind::InvalidData => {
                Err(Error::bad_dem(&self.path, format!("line {}: not text (invalid UTF-8)", self.number)))
            }
            Err(e) => Err(Error::io(&self.path, e)),
        }
    }

    fn error(&self, problem: impl std::fmt::Display) -> Error {
        Error::bad_dem(&self.path, format!("line {}: {problem}", self.number))
    }
}

/// The header, with the first body line left in `Lines::line`.
#[derive(Clone, Debug)]
struct Header {
    ncols: u64,
    nrows: u64,
    /// Lower-left corner (not centre) of the grid.
    xll_corner: f64,
    yll_corner: f64,
    dx: f64,
    dy: f64,
    nodata: Option<f64>,
}

/// Reads header lines up to the first line that starts with a number.
fn read_header(lines: &mut Lines) -> Result<Header> {
    let mut ncols = None;
    let mut nrows = None;
    let mut xll_corner = None;
    let mut xll_centre = None;
    let mut yll_corner = None;
    let mut yll_centre = None;
    let mut cellsize = None;
    let mut dx = None;
    let mut dy = None;
    let mut nodata = None;

    loop {
        if !lines.advance()? {
            return Err(lines.error("end of file in the header (no data values)"));
        }
        let mut tokens = lines.line.split_ascii_whitespace();
        let Some(key) = tokens.next() else { continue };
        if key.parse::<f64>().is_ok() {
            break;
        }
        let Some(value) = tokens.next() else {
            return Err(lines.error(format!("header key '{key}' has no value")));
        };
        let key = key.to_ascii_lowercase();
        let count = |v: &str| -> Result<u64> {
            v.parse::<u64>()
                .ok()
                .filter(|&n| n > 0)
                .ok_or_else(|| lines.error(format!("{key} '{v}' is not a positive integer")))
        };
        let number = |v: &str| -> Result<f64> {
            v.parse::<f64>()
                .ok()
                .filter(|n| n.is_finite())
                .ok_or_else(|| lines.error(format!("{key} '{v}' is not a number")))
        };
        match key.as_str() {
            "ncols" => ncols = Some(count(value)?),
            "nrows" => nrows = Some(count(value)?),
            "xllcorner" => xll_corner = Some(number(value)?),
            "xllcenter" => xll_centre = Some(number(value)?),
            "yllcorner" => yll_corner = Some(number(value)?),
            "yllcenter" => yll_centre = Some(number(value)?),
            "cellsize" => cellsize = Some(number(value)?),
            "dx" => dx = Some(number(value)?),
            "dy" => dy = Some(number(value)?),
            "nodata_value" => nodata = Some(number(value)?),
            _ => {}
        }
    }

    let missing =
        |key: &str| Error::bad_dem(&lines.path, format!("header key '{key}' missing before line {}", lines.number));
    let ncols = ncols.ok_or_else(|| missing("ncols"))?;
    let nrows = nrows.ok_or_else(|| missing("nrows"))?;
    let (dx, dy) = match (cellsize, dx, dy) {
        (_, Some(dx), Some(dy)) => (dx, dy),
        (Some(c), _, _) => (c, c),
        _ => return Err(missing("cellsize")),
    };
    if !(dx > 0.0 && dy > 0.0) {
        return Err(Error::bad_dem(&lines.path, format!("cell size {dx} x {dy} is not positive")));
    }
    let xll_corner = match (xll_corner, xll_centre) {
        (Some(x), _) => x,
        (None, Some(x)) => x - dx / 2.0,
        (None, None) => return Err(missing("xllcorner")),
    };
    let yll_corner = match (yll_corner, yll_centre) {
        (Some(y), _) => y,
        (None, Some(y)) => y - dy / 2.0,
        (None, None) => return Err(missing("yllcorner")),
    };
    Ok(Header { ncols, nrows, xll_corner, yll_corner, dx, dy, nodata })
}

/// Whether a `.prj` next to `path` describes geographic (unprojected) coordinates.
fn prj_is_geographic(path: &Path) -> bool {
    let candidates = [path.with_extension("prj"), path.with_extension("PRJ")];
    candidates.iter().any(|prj| {
        std::fs::read(prj).is_ok_and(|bytes| {
            let text = String::from_utf8_lossy(&bytes).to_ascii_uppercase();
            text.contains("GEOGCS") && !text.contains("PROJCS")
        })
    })
}

struct Asc {
    path: PathBuf,
    info: DemInfo,
}

pub(super) fn open(path: &Path) -> Result<Box<dyn DemSource>> {
    let mut lines = Lines::open(path)?;
    let header = read_header(&mut lines)?;
    let (width, height) = check_dimensions(path, header.ncols, header.nrows)?;
    let geographic = prj_is_geographic(path);
    // The grid is cell-registered from its lower-left corner: the south-west post is the centre
    // of the lower-left cell. Which CRS it is in, a `.prj` would say in WKT (not parsed here).
    let georef = Georef {
        kind: if geographic { CrsKind::Geographic } else { CrsKind::Unknown },
        epsg: 0,
        unit: if geographic { unit::DEGREE } else { 0 },
        vertical_epsg: 0,
        vertical_unit: 0,
        origin: [header.xll_corner + header.dx / 2.0, header.yll_corner + header.dy / 2.0],
        step: [header.dx, header.dy],
    };
    let spacing = if geographic {
        let centre_lat_deg = header.yll_corner + header.nrows as f64 * header.dy / 2.0;
        SourceSpacing::Degrees { x: header.dx, y: header.dy, centre_lat_deg }
    } else {
        SourceSpacing::Metres { x: header.dx, y: header.dy }
    };
    let info = DemInfo {
        format: DemFormat::Asc,
        width,
        height,
        spacing: Some(spacing),
        nodata: header.nodata,
        sample_type: "ascii decimal".into(),
        georef: georef.is_valid().then_some(georef),
    };
    Ok(Box::new(Asc { path: path.to_path_buf(), info }))
}

impl DemSource for Asc {
    fn info(&self) -> &DemInfo {
        &self.info
    }

    fn read(&mut self, sink: &mut dyn FnMut(Run<'_>) -> Result<()>) -> Result<()> {
        let mut lines = Lines::open(&self.path)?;
        read_header(&mut lines)?;
        let (width, height) = (self.info.width, self.info.height);
        let expected = u64::from(width) * u64::from(height);
        let nodata = self.info.nodata;

        let mut run: Vec<f64> = Vec::with_capacity((width as usize).min(MAX_RUN));
        let (mut row, mut x0) = (0u32, 0u32);
        let mut found = 0u64;
        // The first body line is already in `lines.line`.
        loop {
            for token in lines.line.split_ascii_whitespace() {
                if found == expected {
                    return Err(lines.error(format!(
                        "more than the {expected} values that {width} x {height} needs ('{}')",
                        excerpt(token)
                    )));
                }
                let v: f64 = token.parse().map_err(|_| lines.error(format!("'{}' is not a number", excerpt(token))))?;
                let v = if Some(v) == nodata || !v.is_finite() { f64::NAN } else { v };
                run.push(v);
                found += 1;
                let at_row_end = x0 as usize + run.len() == width as usize;
                if at_row_end || run.len() == MAX_RUN {
                    sink(Run { row, x0, values: &run })?;
                    if at_row_end {
                        row += 1;
                        x0 = 0;
                    } else {
                        x0 += run.len() as u32;
                    }
                    run.clear();
                }
            }
            if !lines.advance()? {
                break;
            }
        }
        if found != expected {
            return Err(Error::bad_dem(
                &self.path,
                format!("expected {expected} values ({width} x {height}), found {found}"),
            ));
        }
        Ok(())
    }
}

/// At most 20 characters of a token, for error messages.
fn excerpt(token: &str) -> String {
    let mut s: String = token.chars().take(20).collect();
    if s.len() < token.len() {
        s.push('…');
    }
    s
}

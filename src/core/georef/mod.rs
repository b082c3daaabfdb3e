//! Where a terrain lies on the Earth: the coordinate reference system (CRS) of its source DEM and
//! the map from grid posts to coordinates in that CRS.
//!
//! The CRS is kept as the EPSG codes GeoTIFF stores in its GeoKeys (OGC GeoTIFF 1.1, §7:
//! `GTModelTypeGeoKey`, `GeographicTypeGeoKey`, `ProjectedCSTypeGeoKey`, `VerticalGeoKey` and the
//! unit keys), not as a full definition: relief does no reprojection, it only has to give the
//! identity back (`info`) and to place coordinates given in that CRS on the grid (`--crs-coords`).
//! The map is the source's axis-aligned affine transform, restated for posts: grid post `(x, y)`
//! (x east, y north, post (0, 0) the grid's south-west corner) lies at `origin + (x, y) · step` in
//! CRS units, and local metres are `(x, y) · spacing_m`, so a CRS coordinate maps to local metres
//! by one scale and offset per axis.

use serde::Serialize;

/// What kind of horizontal CRS the source named.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Serialize)]
#[serde(rename_all = "lowercase")]
pub enum CrsKind {
    /// Georeferenced (the source places its posts), but it does not say in which CRS.
    Unknown = 0,
    /// Easting and northing in a linear unit.
    Projected = 1,
    /// Longitude and latitude in an angular unit.
    Geographic = 2,
}

impl CrsKind {
    pub fn from_code(code: u16) -> Option<CrsKind> {
        match code {
            0 => Some(CrsKind::Unknown),
            1 => Some(CrsKind::Projected),
            2 => Some(CrsKind::Geographic),
            _ => None,
        }
    }

    pub fn name(self) -> &'static str {
        match self {
            CrsKind::Unknown => "unknown",
            CrsKind::Projected => "projected",
            CrsKind::Geographic => "geographic",
        }
    }
}

pub mod drape;
mod epsg_units;

/// EPSG unit-of-measure codes (GeoTIFF's unit keys use these).
pub mod unit {
    use super::epsg_units;

    pub const METRE: u16 = 9001;
    pub const FOOT: u16 = 9002;
    pub const US_SURVEY_FOOT: u16 = 9003;
    pub const RADIAN: u16 = 9101;
    pub const DEGREE: u16 = 9102;

    /// The unit's name, or `None` for a code relief does not know (0: not stated).
    pub fn name(code: u16) -> Option<&'static str> {
        match code {
            METRE => Some("metre"),
            RADIAN => Some("radian"),
            DEGREE => Some("degree"),
            _ => epsg_units::UNITS.iter().find(|u| u.0 == code).map(|u| u.1),
        }
    }

    /// Metres per unit, for the linear units relief knows.
    pub fn metres(code: u16) -> Option<f64> {
        match code {
            METRE => Some(1.0),
            // Exact by definition (the table's factor is the same ratio, rounded).
            US_SURVEY_FOOT => Some(1200.0 / 3937.0),
            _ => epsg_units::UNITS.iter().find(|u| u.0 == code).map(|u| u.2),
        }
    }

    /// The linear unit an EPSG projected CRS's coordinates are in (most are metres; the
    /// exceptions come from the EPSG dataset, `tools/epsg_units.py`).
    pub fn of_projected(epsg: u32) -> u16 {
        lookup(epsg_units::PROJECTED, epsg)
    }

    /// The unit an EPSG vertical CRS's heights are in.
    pub fn of_vertical(epsg: u32) -> u16 {
        lookup(epsg_units::VERTICAL, epsg)
    }

    fn lookup(table: &[(u32, u16)], epsg: u32) -> u16 {
        match table.binary_search_by_key(&epsg, |e| e.0) {
            Ok(k) => table[k].1,
            Err(_) => METRE,
        }
    }
}

/// The source's CRS and where the grid's posts lie in it.
#[derive(Clone, Copy, Debug, PartialEq, Serialize)]
pub struct Georef {
    pub kind: CrsKind,
    /// EPSG code of the horizontal CRS; 0 when the source names none (user-defined or absent).
    pub epsg: u32,
    /// Unit of the horizontal coordinates (EPSG unit code, see [`unit`]; 0: not stated).
    pub unit: u16,
    /// EPSG code of the vertical CRS; 0 when not stated.
    pub vertical_epsg: u32,
    /// Unit of the source's height values (EPSG unit code; 0: not stated, taken as metres).
    pub vertical_unit: u16,
    /// CRS coordinates of grid post (0, 0), the grid's south-west corner.
    pub origin: [f64; 2],
    /// CRS units from one post to the next, east and north (both positive).
    pub step: [f64; 2],
}

impl Georef {
    /// Checks what a decoder or a caller put together: finite origin, positive finite steps.
    pub fn is_valid(&self) -> bool {
        self.origin.iter().all(|v| v.is_finite()) && self.step.iter().all(|v| v.is_finite() && *v > 0.0)
    }

    /// The CRS's name as `EPSG:n`, or what is known without one.
    pub fn crs_label(&self) -> String {
        match (self.epsg, self.kind) {
            (0, CrsKind::Unknown) => "not stated".into(),
            (0, k) => format!("{} (no EPSG code)", k.name()),
            (code, _) => format!("EPSG:{code}"),
        }
    }

    /// CRS coordinates of grid post `(x, y)` (fractional posts allowed).
    pub fn crs_of_post(&self, post: [f64; 2]) -> [f64; 2] {
        [self.origin[0] + post[0] * self.step[0], self.origin[1] + post[1] * self.step[1]]
    }

    /// The grid post (fractional) at CRS coordinates `crs`.
    pub fn post_of_crs(&self, crs: [f64; 2]) -> [f64; 2] {
        [(crs[0] - self.origin[0]) / self.step[0], (crs[1] - self.origin[1]) / self.step[1]]
    }

    /// Local metres (from the grid's south-west post, with posts `spacing_m` apart) of CRS
    /// coordinates `crs`.
    pub fn local_of_crs(&self, crs: [f64; 2], spacing_m: [f64; 2]) -> [f64; 2] {
        let p = self.post_of_crs(crs);
        [p[0] * spacing_m[0], p[1] * spacing_m[1]]
    }

    /// CRS coordinates of local metres `local` (the inverse of [`Self::local_of_crs`]).
    pub fn crs_of_local(&self, local: [f64; 2], spacing_m: [f64; 2]) -> [f64; 2] {
        self.crs_of_post([local[0] / spacing_m[0], local[1] / spacing_m[1]])
    }

    /// Metres per unit of the source's heights: the vertical unit's, else 1 (not stated or not
    /// known: taken as metres, as before the unit was read).
    pub fn vertical_metres(&self) -> f64 {
        unit::metres(self.vertical_unit).unwrap_or(1.0)
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn units_implied_by_epsg_codes() {
        // NAD83 / Florida East (ftUS), NAD83 / UTM 15N, NAVD88 height (ftUS), NAVD88 height.
        assert_eq!(unit::of_projected(2236), unit::US_SURVEY_FOOT);
        assert_eq!(unit::of_projected(26915), unit::METRE);
        assert_eq!(unit::of_vertical(6360), unit::US_SURVEY_FOOT);
        assert_eq!(unit::of_vertical(5703), unit::METRE);
        assert_eq!(unit::metres(unit::FOOT), Some(0.3048));
        assert_eq!(unit::name(unit::US_SURVEY_FOOT), Some("US survey foot"));
        assert!(super::epsg_units::PROJECTED.windows(2).all(|w| w[0].0 < w[1].0), "sorted for the search");
        assert!(super::epsg_units::VERTICAL.windows(2).all(|w| w[0].0 < w[1].0), "sorted for the search");
    }

    #[test]
    fn crs_and_local_metres_round_trip() {
        let g = Georef {
            kind: CrsKind::Projected,
            epsg: 26915,
            unit: unit::METRE,
            vertical_epsg: 0,
            vertical_unit: 0,
            origin: [429252.813, 5150486.425],
            step: [1.0, 1.0],
        };
        let spacing = [1.0, 1.0];
        let local = g.local_of_crs([429352.813, 5150586.425], spacing);
        assert!((local[0] - 100.0).abs() < 1e-6 && (local[1] - 100.0).abs() < 1e-6, "{local:?}");
        let back = g.crs_of_local(local, spacing);
        assert!((back[0] - 429352.813).abs() < 1e-6 && (back[1] - 5150586.425).abs() < 1e-6);
        // Geographic posts: degrees per post, metres per post differ.
        let g = Georef { kind: CrsKind::Geographic, epsg: 4326, unit: unit::DEGREE, step: [0.5, 0.25], ..g };
        let local = g.local_of_crs([g.origin[0] + 1.0, g.origin[1] + 1.0], [1000.0, 500.0]);
        assert!((local[0] - 2000.0).abs() < 1e-6 && (local[1] - 2000.0).abs() < 1e-6, "{local:?}");
        assert_eq!(g.crs_label(), "EPSG:4326");
        assert!(g.is_valid());
        assert!(!Georef { step: [0.0, 1.0], ..g }.is_valid());
    }
}

//! relief's file formats.

pub mod terrain;
pub mod vdt;

//! Helpers shared by the file-reader fuzz targets (not a target itself).

/// The project's round-trip equality (bit-exact numbers; see `robocal::schema::same_json`).
pub use robocal::schema::same_json;

//! The host side of boucwen: analysis of records, identification, the paper's
//! experiments (`sweep`), diagnosis of measured data, reports and plots. The `boucwen`
//! binary is a thin command-line layer over this library.

pub mod analysis;
pub mod diagnose;
pub mod experiment;
pub mod fit;
pub mod hidden;
pub mod plot;
pub mod report;
pub mod sweep;

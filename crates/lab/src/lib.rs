//! # boucwen-lab
//!
//! The host library of boucwen: everything between a record on disk and a result. The
//! `boucwen` binary is a thin command-line layer over it.
//!
//! | module | what |
//! |---|---|
//! | [`record`] | measured records on disk (CSV), [`record::Replay`] as a plant |
//! | [`analysis`] | spectra, harmonics, whole periods |
//! | [`steady`] | the drive's kind and the steady window of a record |
//! | [`fit`] | identification: the paper's RLS and output error |
//! | [`board_design`] | the board's compensator from measured records, and the design file |
//! | [`design`] | an identified model (or a plant) to the board's parameters; the cancellation rule and the probe of the response at `n·f`, shared by `boucwen hil` and the sweep |
//! | [`experiment`] | one closed-loop runner for any core `Controller` on any core `Plant`: the compensator (with preview) and the peers |
//! | [`simulate`] | the virtual bimorph on a sine or a drive file, to a record |
//! | [`sweep`] | the paper's Figs. 10 and 16 on the virtual bimorph |
//! | [`diagnose`] | what a model gets wrong on a record, the cause, the term that fixes it |
//! | [`report`], [`plot`] | files, pages and SVG figures |
//! | `hidden`, `messy` (feature `fixtures`) | records of the virtual bimorph with a hidden effect, and written as bench records come, for tests and benches |

pub mod analysis;
pub mod board_design;
pub mod design;
pub mod diagnose;
pub mod experiment;
pub mod fit;
#[cfg(feature = "fixtures")]
pub mod hidden;
#[cfg(feature = "fixtures")]
pub mod messy;
pub mod plot;
pub mod record;
pub mod report;
pub mod simulate;
pub mod steady;
pub mod sweep;

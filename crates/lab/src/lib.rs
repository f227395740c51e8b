//! # boucwen-lab
//!
//! The host library of boucwen: everything between a record on disk and a result. The
//! `boucwen` binary is a thin command-line layer over it.
//!
//! One room per job, each using only the rooms above it in this table (checked by
//! `tests/layers.rs`):
//!
//! | module | what |
//! |---|---|
//! | [`rules`] | every threshold the diagnosis decides by, in one documented table |
//! | [`signal`] | spectra, harmonics and whole periods; periodic excitations; the drive's kind, the steady window and the noise floor; lines of whole periods and the BLA |
//! | [`record`] | measured records on disk (CSV as they come), [`record::Replay`] as a plant |
//! | [`model`] | the models the host fits and simulates: the paper's actuator (hysteresis at the drive, branches, drift, delay) and the terms around it |
//! | [`fit`] | identification: the paper's RLS, output error, the joint refinement of terms |
//! | [`diagnose`] | what a model gets wrong on a record, the cause, the term that fixes it |
//! | [`identify`] | a model fitted on part of a record, tested on the rest |
//! | [`design`] | an identified model to the board's parameters; the closed-loop runner; the board's design from measured records and the design file |
//! | [`experiments`] | the virtual bimorph on a drive, the paper's sweep (Figs. 10 and 16), the sweep from measured records |
//! | [`report`] | text, JSON, files, pages and SVG figures |
//! | `fixtures` (feature `fixtures`) | records of the virtual bimorph with a hidden effect, and written as bench records come, for tests and benches |

pub mod design;
pub mod diagnose;
pub mod experiments;
pub mod fit;
#[cfg(feature = "fixtures")]
pub mod fixtures;
pub mod identify;
pub mod mimo;
pub mod model;
pub mod record;
pub mod report;
pub mod rules;
pub mod signal;

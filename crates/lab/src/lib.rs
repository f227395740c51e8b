//! # boucwen-lab
//!
//! The host library of boucwen: everything between a record on disk and a result. The
//! `boucwen` binary is a thin command-line layer over it.
//!
//! | module | what |
//! |---|---|
//! | [`record`] | measured records on disk (CSV), [`record::Replay`] as a plant |
//! | [`analysis`] | spectra, harmonics, whole periods |
//! | [`excitation`] | periodic excitations: odd random-phase multisines, triangles |
//! | [`steady`] | the drive's kind and the steady window of a record |
//! | [`fit`] | identification: the paper's RLS and output error |
//! | [`board_design`] | the board's compensator from measured records, and the design file |
//! | [`design`] | an identified model (or a plant) to the board's parameters; the cancellation rule and the probe of the response at `n·f`, shared by `boucwen hil` and the sweep |
//! | [`experiment`] | one closed-loop runner for any core `Controller` on any core `Plant`: the compensator (with preview) and the peers |
//! | [`simulate`] | the virtual bimorph on a sine or a drive file, to a record |
//! | [`sweep`] | the paper's Figs. 10 and 16 on the virtual bimorph |
//! | [`sweep_measured`] | the identification half of the sweep (Fig. 10) from measured records, one sine frequency each |
//! | [`diagnose`] | what a model gets wrong on a record, the cause, the term that fixes it |
//! | [`distortion`] | periodic and multisine drives: lines of whole periods, the BLA, noise and distortion levels at odd and even non-excited lines |
//! | [`causes`] | the causes a sine diagnosis tries beyond harmonics and drift (saturation, creep, input delay): their evidence and fits |
//! | [`periodic`] | diagnosis of periodic (not sine) and multisine drives: the data's distortion, the hysteresis model against the linear one, stiffening terms, held out on another realisation or period |
//! | [`terms`] | terms beyond the fitted model (saturation, input delay, creep, stiffening) and their joint refinement |
//! | [`report`], [`plot`] | files, pages and SVG figures |
//! | `hidden`, `messy`, `effects` (feature `fixtures`) | records of the virtual bimorph with a hidden effect (harmonics and drift; saturation, creep, delay, two at once; periodic and multisine drives with a hidden odd or even nonlinearity), and written as bench records come, for tests and benches |

pub mod analysis;
pub mod board_design;
pub mod causes;
pub mod design;
pub mod diagnose;
pub mod distortion;
#[cfg(feature = "fixtures")]
pub mod effects;
pub mod excitation;
pub mod experiment;
pub mod fit;
#[cfg(feature = "fixtures")]
pub mod hidden;
#[cfg(feature = "fixtures")]
pub mod messy;
pub mod mimo;
pub mod periodic;
pub mod plot;
pub mod record;
pub mod report;
pub mod simulate;
pub mod steady;
pub mod sweep;
pub mod sweep_measured;
pub mod terms;

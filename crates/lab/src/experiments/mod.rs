//! Experiments: the virtual bimorph on a drive, the paper's sweep, and its identification
//! half from measured records.
//!
//! | module | what |
//! |---|---|
//! | [`simulate`] | the virtual bimorph on a sine or a drive file, to a record |
//! | [`sweep`] | the paper's Figs. 10 and 16 on the virtual bimorph |
//! | [`sweep_measured`] | the identification half of the sweep (Fig. 10) from measured records, one sine frequency each |

pub mod simulate;
pub mod sweep;
pub mod sweep_measured;

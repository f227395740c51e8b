//! Signals on their own: no model, no record format.
//!
//! | module | what |
//! |---|---|
//! | [`analysis`] | RMS, tones and harmonics over whole periods, spectra, the drive frequency |
//! | [`excitation`] | periodic excitations: odd random-phase multisines, triangles |
//! | [`steady`] | the drive's kind, the steady window of a record, its noise floor, stepped sines |
//! | [`distortion`] | lines of whole periods, the BLA, noise and distortion levels at odd and even non-excited lines |

pub mod analysis;
pub mod distortion;
pub mod excitation;
pub mod steady;

//! # boucwen-hal
//!
//! What stands between the toolkit and an actuator: the wire protocol shared with the
//! driver-board firmware ([`wire`], `no_std`, the firmware depends on this crate with
//! `default-features = false`), and on the host (feature `std`, on by default) the
//! project's measured-record format ([`record`]), one trait for a plant the host can drive
//! ([`plant`]), the serial link to the board ([`transport`]) and hardware in the loop
//! ([`hil`]: the board computes the compensator, the host is its actuator).
#![cfg_attr(not(feature = "std"), no_std)]

#[cfg(feature = "std")]
pub mod hil;
#[cfg(feature = "std")]
pub mod plant;
#[cfg(feature = "std")]
pub mod record;
#[cfg(feature = "std")]
pub mod transport;
pub mod wire;

//! # boucwen-hal
//!
//! What stands between the toolkit and an actuator: the wire protocol shared with the
//! driver-board firmware (`no_std`), and on the host (feature `std`, on by default) the
//! project's measured-record format ([`record`]) and one trait for a plant the host can
//! drive ([`plant`]).
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

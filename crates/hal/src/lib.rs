//! # boucwen-hal
//!
//! The host's I/O to devices: the serial link to the driver board ([`transport`]: ports,
//! fault injection, a framed link speaking `boucwen-link`'s protocol, and the board in its
//! plant mode as a `boucwen_core::Plant`) and hardware in the loop ([`hil`]: the board
//! computes the controller, the host is its actuator), and the board on a bench ([`board`]:
//! a design loaded and verified, the board's own loop run with its telemetry streamed into
//! a record, the board as the data acquisition).

pub mod board;
pub mod hil;
pub mod transport;

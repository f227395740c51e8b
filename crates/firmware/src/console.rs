//! Lines to the host console (semihosting stdout), one host call per line.

use core::fmt::{self, Write};
use cortex_m_semihosting::hio;

/// Writes one formatted line (cut at 120 bytes) to the host's standard output.
pub fn line(args: fmt::Arguments) {
    let mut s: heapless::String<120> = heapless::String::new();
    // A line cut short is still sent.
    let _ = s.write_fmt(args);
    let _ = s.push('\n');
    if let Ok(mut out) = hio::hstdout() {
        // Nowhere to report a failed console write.
        let _ = out.write_all(s.as_bytes());
    }
}

/// `println!` to the host console.
#[macro_export]
macro_rules! say {
    ($($arg:tt)*) => { $crate::console::line(format_args!($($arg)*)) };
}

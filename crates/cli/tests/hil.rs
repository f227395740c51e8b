//! `boucwen hil` refuses what it cannot use with one line naming it, and exits non-zero.
//! (The run against the firmware is `cargo xtask hil`: it needs QEMU.)

use std::process::Command;

fn boucwen(args: &[&str]) -> std::process::Output {
    Command::new(env!("CARGO_BIN_EXE_boucwen")).args(args).output().expect("run boucwen")
}

#[test]
fn bad_ports_and_options_are_one_line_errors() {
    for (args, want) in [
        (vec!["hil", "--port", "/nonexistent/ttyBOARD"], "/nonexistent/ttyBOARD"),
        (vec!["hil", "--port", "/dev/null", "--samples", "10"], "--samples 10"),
        (vec!["hil", "--port", "/dev/null", "--inject-faults", "2"], "--inject-faults 2"),
        (vec!["hil", "--port", "/dev/null", "--freq", "400"], "--freq 400"),
    ] {
        let o = boucwen(&args);
        let err = String::from_utf8_lossy(&o.stderr);
        assert_eq!(o.status.code(), Some(1), "{args:?}: {err}");
        assert!(!err.contains("panicked"), "{err}");
        let lines: Vec<&str> = err.lines().filter(|l| l.starts_with("boucwen:")).collect();
        assert_eq!(lines.len(), 1, "{args:?}: {err}");
        assert!(lines[0].contains(want), "{args:?}: want {want:?} in {err}");
    }
}

//! Lines on standard output that survive a closed reader: `nimbus inspect FILE | head` stops
//! quietly (exit 0, as ripgrep and coreutils do) instead of panicking in `println!`; any other
//! write failure is a one-line runtime error.
use std::io::Write;

/// `println!` for the CLI's reports ([`write_line`]).
#[macro_export]
macro_rules! outln {
    ($($arg:tt)*) => {
        $crate::stdout::write_line(format_args!($($arg)*))
    };
}

/// Writes one line to standard output; a closed pipe ends the process with exit 0, any other
/// failure with the runtime exit code.
pub fn write_line(args: std::fmt::Arguments) {
    let mut out = std::io::stdout().lock();
    let written = out
        .write_fmt(args)
        .and_then(|_| out.write_all(b"\n"))
        .and_then(|_| out.flush());
    if let Err(e) = written {
        if e.kind() == std::io::ErrorKind::BrokenPipe {
            std::process::exit(crate::error::exit::OK);
        }
        eprintln!("error: writing to standard output: {e}");
        std::process::exit(crate::error::exit::RUNTIME);
    }
}

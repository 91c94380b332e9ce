//! Thin entry point: everything lives in the library (`robocal::cli`).
fn main() {
    // Like other Unix command-line tools, end quietly when the reader of stdout goes away
    // (`robocal inspect … | head`) instead of panicking on a broken pipe.
    #[cfg(unix)]
    // SAFETY: restoring the default disposition of SIGPIPE before any thread starts.
    unsafe {
        libc::signal(libc::SIGPIPE, libc::SIG_DFL);
    }
    std::process::exit(robocal::main_with_args(std::env::args_os()));
}

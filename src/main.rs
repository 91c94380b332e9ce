//! Thin entry point: everything lives in the library (`robocal::cli`).
fn main() {
    std::process::exit(robocal::cli::run(std::env::args_os()));
}

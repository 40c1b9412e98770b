//! The `eyekey` binary: a thin wrapper around [`eyekey::cli`].

use clap::Parser;

fn main() -> std::process::ExitCode {
    let cli = eyekey::cli::Cli::parse();
    match eyekey::cli::run(cli) {
        Ok(()) => std::process::ExitCode::SUCCESS,
        Err(e) => {
            // One line naming the problem and its causes.
            eprintln!("error: {e:#}");
            std::process::ExitCode::from(2)
        }
    }
}

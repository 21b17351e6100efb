//! The `stereogen` command line: argument parsing, progress bars and printing. The work is done
//! by the `stereogen` library.

mod cli;

fn main() -> std::process::ExitCode {
    cli::main()
}

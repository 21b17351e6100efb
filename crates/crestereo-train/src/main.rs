//! `crestereo`: see `crestereo --help`. The command line (`cli/`: `infer | train | eval | plot |
//! bench | export`) is this binary's own; the work is in the `crestereo_train` library.

mod cli;

fn main() -> std::process::ExitCode {
    cli::main()
}

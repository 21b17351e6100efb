//! `crestereo`: see `crestereo --help`; the work is in the `crestereo_train` library.

fn main() -> std::process::ExitCode {
    crestereo_train::cli::main()
}

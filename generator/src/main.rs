fn main() -> std::process::ExitCode {
    stereogen::cli::main()
}

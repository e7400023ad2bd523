fn main() -> std::process::ExitCode {
    cloudscape::cli::main()
}

//! `conductor-executor --manifest M --subsystem S`: one subsystem in real time.

fn main() -> std::process::ExitCode {
    conductor_executor::process::main_with_args(std::env::args_os())
}

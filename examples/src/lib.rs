//! # conductor-examples
//!
//! External controllers for Conductor, written the way a user writes them, and the simulated
//! plant they are tested against:
//!
//! * `pid-controller` — the thesis' Fig. 3.4 PID, fed by a State's derivative and integral;
//! * `state-observer` — the thesis' Fig. 3.5 observer + state feedback, with nalgebra;
//! * `python/controller.py` — the `conductor` Python package (`python/`, over the official
//!   iceoryx2 package);
//! * `python/udp_client.py` — a MATLAB-style client of `conductor udp-gateway`;
//! * `sim-motor` — a first-order motor owned by a simulated executor ([`sim`], [`motor`]);
//! * `conductor-demo` — the simulated mini-Hubo right leg launched from its manifest and walking
//!   under the thesis' PID ([`minihubo`]: its gait and the linear theory it is checked against).
//!
//! See `examples/README.md` for how to run each.

pub mod minihubo;
pub mod motor;
pub mod sim;

/// How an example program ends: success, or `name: error` on stderr and a failure status.
/// Every example binary's `main` ends through this.
pub fn exit_code<E: std::fmt::Display>(
    name: &str,
    result: Result<(), E>,
) -> std::process::ExitCode {
    match result {
        Ok(()) => std::process::ExitCode::SUCCESS,
        Err(e) => {
            eprintln!("{name}: {e}");
            std::process::ExitCode::FAILURE
        }
    }
}

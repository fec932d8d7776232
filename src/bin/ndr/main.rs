//! The `ndr` command line: one module per subcommand.

mod paper;
mod sim;
mod size;

use std::process::ExitCode;

use clap::{Parser, Subcommand};

#[derive(Parser)]
#[command(
    name = "ndr",
    version,
    about = "Regulated teleoperation link: constant, known delay over IP"
)]
struct Cli {
    #[command(subcommand)]
    command: Command,
}

#[derive(Subcommand)]
enum Command {
    /// Size an NDR queue from the round-trip times of an initialization
    /// pattern, with the paper's laws (ns = 2 + floor(eta·mt/T), T = max(T_min, NRTT/3)).
    Size(size::SizeArgs),
    /// Simulate the link (base, remote with its plant, and the network) in
    /// deterministic simulated time, and report what a controller would see.
    Sim(sim::SimArgs),
}

fn main() -> ExitCode {
    let cli = Cli::parse();
    let result = match &cli.command {
        Command::Size(args) => size::run(args),
        Command::Sim(args) => sim::run(args),
    };
    match result {
        Ok(()) => ExitCode::SUCCESS,
        Err(msg) => {
            eprintln!("ndr: error: {msg}");
            ExitCode::FAILURE
        }
    }
}

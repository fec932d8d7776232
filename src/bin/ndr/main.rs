//! The `ndr` command line: a module per subcommand, and the modules they
//! share (argument groups, the base's report, the robot, the runtime).

mod args;
mod compare;
mod control;
mod demo;
#[cfg(test)]
mod doc_commands;
#[cfg(test)]
mod doc_messages;
mod explain;
mod keygen;
mod logging;
mod metrics;
mod operator;
mod paper;
mod pauses;
mod peers;
mod relay;
mod report;
mod robot;
mod router;
mod runtime;
mod shared;
mod signals;
mod sim;
mod size;
mod soak;
mod throwaway;
mod tracking;
mod transport;
mod watchers;

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
    /// Log more on stderr: -v for info (handshakes, link events), -vv for
    /// debug. Without it, warnings and errors only (refused peers, lost
    /// links, timeouts). RUST_LOG (e.g. ndr_net=debug) filters further.
    #[arg(short, long, action = clap::ArgAction::Count, global = true)]
    verbose: u8,
}

#[derive(Subcommand)]
enum Command {
    /// Size an NDR queue from the round-trip times of an initialization
    /// pattern, with the paper's laws (ns = 2 + floor(eta·mt/T), T = max(T_min, NRTT/3)).
    Size(size::SizeArgs),
    /// The main job: a remote robot (simulated plant), a delaying relay and a
    /// base whose operator follows a signal, all in this process over loopback
    /// (UDP datagrams unless --transport says otherwise); a live status line,
    /// then NRTT beside GRTT and everything counted.
    Demo(demo::DemoArgs),
    /// The operator's side as its own process: connect to a remote (or a
    /// relay), follow a signal, report like `ndr demo`. Exits non-zero, with
    /// the report still written, when no link came up or the link failed.
    Base(peers::BaseArgs),
    /// The robot's side as its own process: serve bases one after another,
    /// each driving the simulated plant; a line for each base's end. SIGUSR1
    /// prints the listener's counters; SIGINT or SIGTERM stops it in order.
    Remote(peers::RemoteArgs),
    /// Simulate the link (base, remote with its plant, and the network) in
    /// deterministic simulated time, and report what a controller would see.
    Sim(sim::SimArgs),
    /// Every playout policy (the paper's NDR, Ramjee et al., NetEQ-like,
    /// fixed latency) on the same simulated traces, beside the oracle: delay,
    /// late rate, underflows, recovery, mean ± 95 % CI over seeds.
    Compare(compare::CompareArgs),
    /// A classical controller (Smith predictor, PID, wave variables) closed
    /// across each kind of link, side by side, in simulated time.
    Control(control::ControlArgs),
    /// Relay TCP connections to an upstream, delaying every frame (a TLS
    /// link: every TLS record, unopened) in order
    /// with a delay model, by default the paper's relay (paris-newyork).
    Relay(relay::RelayArgs),
    /// Run a 1 kHz link through the relay under a schedule of faults (relay
    /// restarts, garbage, the remote killed) and check that nothing is lost,
    /// duplicated or reordered without a counter, nothing panics and memory
    /// stays flat. Ctrl-C (or SIGTERM) stops it in order: it reports the
    /// time so far, exits non-zero, and leaves no remote or keys behind.
    Soak(soak::SoakArgs),
    /// Route zenoh links (`--transport zenoh`): zenoh's own router, in
    /// this process, listening on --listen; robots and bases dial it.
    /// (Built with the `zenoh` feature.)
    Router(router::RouterArgs),
    /// Make a self-signed certificate and key (PEM) for a lab setup, and
    /// print its SHA-256 fingerprint (what the peer pins).
    Keygen(keygen::KeygenArgs),
    /// Print a completion script for a shell to standard output, e.g.
    /// `ndr completions bash > ~/.local/share/bash-completion/completions/ndr`
    /// or `ndr completions zsh > "${fpath[1]}/_ndr"`.
    Completions {
        /// The shell: bash, elvish, fish, powershell or zsh.
        shell: clap_complete::Shell,
    },
}

fn main() -> ExitCode {
    let cli = Cli::parse();
    logging::init(cli.verbose);
    let result = match &cli.command {
        Command::Size(args) => size::run(args),
        Command::Demo(args) => demo::run(args),
        Command::Base(args) => peers::base(args),
        Command::Remote(args) => peers::remote(args),
        Command::Sim(args) => sim::run(args),
        Command::Relay(args) => relay::run(args),
        Command::Compare(args) => compare::run(args),
        Command::Control(args) => control::run(args),
        Command::Soak(args) => soak::run(args),
        Command::Keygen(args) => keygen::run(args),
        Command::Router(args) => router::run(args),
        Command::Completions { shell } => {
            let mut cmd = <Cli as clap::CommandFactory>::command();
            clap_complete::generate(*shell, &mut cmd, "ndr", &mut std::io::stdout());
            Ok(())
        }
    };
    match result {
        Ok(()) => ExitCode::SUCCESS,
        Err(msg) => {
            eprintln!("ndr: error: {msg}");
            ExitCode::FAILURE
        }
    }
}

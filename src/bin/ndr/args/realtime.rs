//! The hub threads' real-time scheduling on the command line.

use ndr::net::LinkConfig;
use ndr::net::realtime::{DEFAULT_RT_PRIORITY, Realtime, RealtimeMode};

/// `--realtime`, `--rt-priority`, `--rt-cpu`, shared by `demo`, `base` and
/// `remote`.
#[derive(clap::Args, Clone, Debug)]
pub struct RealtimeArgs {
    /// Real-time scheduling of the link's hub thread: try (the default:
    /// SCHED_FIFO and locked memory if the host grants them, else one
    /// warning saying what to grant, and the default policy), enforce
    /// (refuse to run without them) or off (ask for nothing). Granting:
    /// root, or `setcap cap_sys_nice,cap_ipc_lock+ep` on the binary, or
    /// rtprio and memlock limits (docs/guide/realtime.md).
    #[arg(long, value_name = "MODE", default_value = "try", value_parser = parse_mode)]
    pub realtime: RealtimeMode,
    /// The hub thread's SCHED_FIFO priority, 1 to 99.
    #[arg(long, value_name = "N", default_value_t = DEFAULT_RT_PRIORITY,
          value_parser = clap::value_parser!(u8).range(1..=99))]
    pub rt_priority: u8,
    /// Pin the hub thread to this CPU (by default it may run on any).
    #[arg(long, value_name = "CPU")]
    pub rt_cpu: Option<usize>,
}

fn parse_mode(s: &str) -> Result<RealtimeMode, String> {
    s.parse()
        .map_err(|e: ndr::net::RealtimeError| e.to_string())
}

impl RealtimeArgs {
    /// The settings in `config`.
    pub fn apply(&self, config: &mut LinkConfig) -> Result<(), String> {
        let mut realtime = Realtime::default()
            .with_mode(self.realtime)
            .with_priority(self.rt_priority)
            .map_err(|e| e.to_string())?;
        if let Some(cpu) = self.rt_cpu {
            realtime = realtime.on_cpu(cpu);
        }
        config.realtime = realtime;
        Ok(())
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use clap::Parser;

    #[derive(Parser)]
    struct Cli {
        #[command(flatten)]
        realtime: RealtimeArgs,
    }

    fn realtime(args: &[&str]) -> Result<Realtime, String> {
        let cli = Cli::try_parse_from(std::iter::once("ndr").chain(args.iter().copied()))
            .map_err(|e| e.to_string())?;
        let mut config = LinkConfig::new(ndr::core::endpoint::Config::paper(
            ndr::core::wire::Role::Base,
        ));
        cli.realtime.apply(&mut config)?;
        Ok(config.realtime)
    }

    #[test]
    fn try_at_the_default_priority_unless_told() {
        assert_eq!(realtime(&[]), Ok(Realtime::default()));
        let rt = realtime(&[
            "--realtime",
            "enforce",
            "--rt-priority",
            "80",
            "--rt-cpu",
            "1",
        ])
        .expect("valid flags");
        assert_eq!(
            (rt.mode, rt.priority, rt.cpu),
            (RealtimeMode::Enforce, 80, Some(1))
        );
        assert_eq!(
            realtime(&["--realtime", "off"]).map(|r| r.mode),
            Ok(RealtimeMode::Off)
        );
    }

    #[test]
    fn bad_modes_and_priorities_are_refused() {
        let e = realtime(&["--realtime", "fifo"]).expect_err("no such mode");
        assert!(e.contains("enforce, try or off"), "{e}");
        for p in ["0", "100"] {
            let e = realtime(&["--rt-priority", p]).expect_err("out of range");
            assert!(e.contains("1..=99") || e.contains("1..100"), "{e}");
        }
    }
}

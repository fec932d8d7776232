//! `ndr control`: a classical controller closed across each kind of link,
//! side by side, in simulated time.

use ndr::core::endpoint::{Transport, Underflow};
use ndr::core::time::Duration;
use ndr::sim::SimConfig;
use ndr::sim::compare::{self, Family};
use ndr::sim::control::{
    self, CONTROL_PERIOD, ControlReport, Controller, LinkKind, LoopConfig, Scenario,
};
use ndr::sim::delay::LossModel;

use crate::args::{DelayArgs, millis};

#[derive(clap::Args)]
pub struct ControlArgs {
    /// The loop: tracking (a position loop on the remote's delayed state)
    /// or bilateral (master and slave coupled by wave variables, the slave
    /// against a wall).
    #[arg(long, default_value = "tracking")]
    pub scenario: String,
    /// Links to compare (repeatable; default all): ideal, unregulated,
    /// paper-static, paper-dynamic, adaptive.
    #[arg(long = "link", value_name = "NAME")]
    pub links: Vec<LinkKind>,
    /// The controller: smith (a PID through a Smith predictor with the
    /// plant's true model; the default for tracking), smith-identified (the
    /// model identified online), pid (the PID alone), wave (bilateral).
    #[arg(long)]
    pub controller: Option<String>,
    /// A family of `ndr compare` (its delays, losses, transport, skew)
    /// instead of --profile/--trace/--dist.
    #[arg(long, value_name = "NAME", conflicts_with_all = ["profile", "trace", "dist"])]
    pub family: Option<String>,
    #[command(flatten)]
    pub net: DelayArgs,
    /// Packets lost each way (as `ndr sim --loss`), with --profile etc.
    #[arg(long, default_value = "none", conflicts_with = "family")]
    pub loss: LossModel,
    /// How samples cross (as `ndr sim --transport`), with --profile etc.
    #[arg(
        long,
        default_value = "stream",
        conflicts_with = "family",
        value_parser = crate::transport::simulated
    )]
    pub transport: Transport,
    /// What the regulators do at a tick whose sample has not arrived: hold
    /// (the paper's: repeat the last sample, keep every one, the delay
    /// stretches) or drop-late (keep the delay: the late sample is lost).
    #[arg(long, default_value = "hold")]
    pub underflow: Underflow,
    /// Seeds per link (1..=N).
    #[arg(long, default_value_t = 3)]
    pub seeds: u64,
    /// The period, in ms.
    #[arg(long, default_value_t = CONTROL_PERIOD.as_secs_f64() * 1e3)]
    pub period_ms: f64,
    /// Simulated time per run, in seconds.
    #[arg(long, default_value_t = 60.0)]
    pub duration_s: f64,
    /// Print one JSON object instead of the table.
    #[arg(long)]
    pub json: bool,
}

fn scenario(name: &str) -> Result<Scenario, String> {
    match name {
        "tracking" => Ok(Scenario::Tracking),
        "bilateral" => Ok(Scenario::Bilateral),
        _ => Err(format!(
            "unknown scenario `{name}`; valid: tracking, bilateral"
        )),
    }
}

fn controller(name: Option<&str>, scenario: Scenario) -> Result<Controller, String> {
    match (name, scenario) {
        (None | Some("smith"), Scenario::Tracking) => Ok(Controller::Smith),
        (Some("smith-identified"), Scenario::Tracking) => Ok(Controller::SmithIdentified),
        (Some("pid"), Scenario::Tracking) => Ok(Controller::Pid),
        (None | Some("wave"), Scenario::Bilateral) => Ok(Controller::Wave),
        (n, _) => Err(format!(
            "controller `{}` does not fit this scenario; tracking: smith, smith-identified, \
             pid; bilateral: wave",
            n.unwrap_or("")
        )),
    }
}

fn family(name: &str) -> Result<Family, String> {
    let all = compare::builtin();
    all.iter().find(|f| f.name == name).cloned().ok_or_else(|| {
        let known: Vec<&str> = all.iter().map(|f| f.name.as_str()).collect();
        format!("unknown family `{name}`; valid: {}", known.join(", "))
    })
}

pub fn run(args: &ControlArgs) -> Result<(), String> {
    let period = millis("--period-ms", args.period_ms)?;
    if period < ndr::core::endpoint::MIN_PERIOD {
        return Err(format!(
            "--period-ms must be at least {} ms",
            ndr::core::endpoint::MIN_PERIOD.as_secs_f64() * 1e3
        ));
    }
    if !(args.duration_s.is_finite() && args.duration_s > 0.0) {
        return Err(format!(
            "--duration-s must be a positive number of seconds, got {}",
            args.duration_s
        ));
    }
    let duration = Duration::from_secs_f64(args.duration_s);
    let scenario = scenario(&args.scenario)?;
    let controller = controller(args.controller.as_deref(), scenario)?;
    let sim = match &args.family {
        Some(name) => {
            let f = family(name)?.with_duration(duration);
            let mut sim = compare::sim_config(&f, ndr::core::Regulation::PaperStatic, 1, period);
            sim.record_forward = false;
            sim
        }
        None => {
            let mut sim = SimConfig::paper(args.net.model("lan-75km")?);
            sim.loss = args.loss;
            sim.transport = args.transport;
            sim.period = period;
            sim.duration = duration;
            sim
        }
    };
    let mut cfg = LoopConfig::new(sim, scenario, LinkKind::Ideal);
    cfg.sim.underflow = args.underflow;
    cfg.controller = controller;
    let links = if args.links.is_empty() {
        LinkKind::ALL.to_vec()
    } else {
        args.links.clone()
    };
    let mut report = control::compare_links(&cfg, &links, args.seeds).map_err(|e| e.to_string())?;
    if let Some(name) = &args.family {
        report.network.clone_from(name);
    }
    if args.json {
        println!(
            "{}",
            serde_json::to_string_pretty(&report).map_err(|e| e.to_string())?
        );
    } else {
        print_table(&report);
    }
    Ok(())
}

fn opt(v: Option<f64>, digits: usize) -> String {
    v.map_or_else(|| "-".into(), |x| format!("{x:.digits$e}"))
}

pub fn print_table(r: &ControlReport) {
    println!(
        "{:?} / {:?} on {} (T = {} ms, {:.0} s, {} seed(s))",
        r.scenario,
        r.controller,
        r.network,
        r.period_s * 1e3,
        r.duration_s,
        r.rows.first().map_or(0, |row| row.runs)
    );
    println!(
        "{:14} {:>9} {:>10} {:>9} {:>10} {:>8} {:>9} {:>8} {:>6} {:>6} {:>7} {:>6} {:>9} {:>9} {:>9} {:>9}",
        "link",
        "rms/ref",
        "rms/design",
        "late",
        "max/design",
        "oversh.",
        "settle s",
        "unstable",
        "RTT tk",
        "annc.",
        "unannc.",
        "a.late",
        "peak",
        "E gen",
        "F err N",
        "x err"
    );
    for row in &r.rows {
        let m = &row.mean;
        println!(
            "{:14} {:>9.4} {:>10.2e} {:>9.2e} {:>10.2e} {:>8.3} {:>9} {:>8} {:>6.1} {:>6} {:>7} {:>6} {:>9} {:>9} {:>9} {:>9}",
            row.link,
            m.rms_vs_reference,
            m.rms_vs_delayed_design,
            m.rms_vs_delayed_design_late,
            row.max_rms_vs_delayed_design,
            m.overshoot,
            m.settling_s
                .map_or_else(|| "-".into(), |s| format!("{s:.2}")),
            format!("{}/{}", row.unstable_runs, row.runs),
            m.round_trip_mean_ticks,
            m.announced,
            m.unannounced_changes,
            m.announced_late,
            opt(m.change_peak, 2),
            opt(row.max_energy_generated, 2),
            m.contact_force_rms_error
                .map_or_else(|| "-".into(), |f| format!("{f:.2}")),
            opt(m.position_rms_error, 2),
        );
    }
}

//! `ndr base` and `ndr remote`: the two peers as separate processes or hosts.

use std::net::SocketAddr;
use std::sync::Mutex;
use std::sync::atomic::AtomicBool;

use ndr::core::endpoint::LinkError;
use ndr::net::{Link, LinkStats, Listener, NetError};

use crate::demo::{LinkArgs, Outcome, RunArgs, check_duration, finish, operator, robot, runtime};
use crate::keygen::SecurityArgs;

#[derive(clap::Args)]
pub struct BaseArgs {
    /// The remote (or a relay in front of it) to connect to.
    #[arg(long, value_name = "ADDR")]
    pub connect: SocketAddr,
    #[command(flatten)]
    pub link: LinkArgs,
    #[command(flatten)]
    pub security: SecurityArgs,
    #[command(flatten)]
    pub run: RunArgs,
}

#[derive(clap::Args)]
pub struct RemoteArgs {
    /// Where to wait for bases.
    #[arg(long, value_name = "ADDR")]
    pub listen: SocketAddr,
    #[command(flatten)]
    pub link: LinkArgs,
    #[command(flatten)]
    pub security: SecurityArgs,
    /// Serve one base, then exit (by default it serves one after another).
    #[arg(long)]
    pub once: bool,
}

pub fn base(args: &BaseArgs) -> Result<(), String> {
    let mut config = args.link.config()?;
    let tls = args.security.apply(&mut config)?;
    check_duration(&args.run)?;
    let link = match &tls {
        Some(tls) => Link::connect_blocking_tls(args.connect, config, tls),
        None => Link::connect_blocking(args.connect, config),
    }
    .map_err(|e| format!("cannot connect to {}: {e}", args.connect))?;
    let (stats, rows) = operator(link, &args.run, args.link.axes, None)?;
    let outcome = Outcome {
        profile: format!("tcp {}", args.connect),
        base: stats,
        remote: None,
        relay: None,
        rows,
    };
    finish(&args.link, &args.run, &outcome)
}

pub fn remote(args: &RemoteArgs) -> Result<(), String> {
    let mut config = args.link.config()?;
    let tls = args.security.apply(&mut config)?;
    let rt = runtime()?;
    let listener = rt
        .block_on(async {
            match &tls {
                Some(tls) => Listener::bind_tls(args.listen, config, tls).await,
                None => Listener::bind(args.listen, config).await,
            }
        })
        .map_err(|e| format!("cannot listen on {}: {e}", args.listen))?;
    let addr = listener.local_addr().map_err(|e| e.to_string())?;
    eprintln!("ndr remote: waiting for a base on {addr}");
    loop {
        let link = match rt.block_on(listener.accept()) {
            Ok(link) => link,
            // One failed accept (a peer that vanished at once) must not stop the robot.
            Err(NetError::Io(e)) => {
                eprintln!("ndr remote: accept failed: {e}");
                continue;
            }
            Err(e) => return Err(e.to_string()),
        };
        let peer = link.peer_addr();
        eprintln!("ndr remote: base {peer} connected");
        let stats = Mutex::new(None::<LinkStats>);
        robot(
            link,
            usize::from(args.link.axes),
            config.endpoint.period,
            &AtomicBool::new(false),
            &stats,
        );
        let last = *stats
            .lock()
            .unwrap_or_else(std::sync::PoisonError::into_inner);
        match last {
            Some(s) => eprintln!(
                "ndr remote: base {peer} gone after {} samples released ({} underflows, {} late)",
                s.endpoint.released_fresh, s.endpoint.underflows, s.endpoint.late
            ),
            None => eprintln!("ndr remote: base {peer} gone ({})", LinkError::Closed),
        }
        if args.once {
            return Ok(());
        }
    }
}

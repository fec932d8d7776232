//! `ndr router`: zenoh's own router, run by the zenoh crate in router
//! mode, for zenoh links (`--transport zenoh`). It adds configuration only.

use crate::args::ZenohArgs;
#[cfg(feature = "zenoh")]
use crate::runtime::runtime;

#[derive(clap::Args)]
pub struct RouterArgs {
    /// A zenoh endpoint to listen on (tcp/HOST:7447; repeat for several).
    #[arg(long, value_name = "ENDPOINT", required = true)]
    pub listen: Vec<String>,
    #[command(flatten)]
    pub zenoh: ZenohArgs,
}

/// Routes until SIGINT or SIGTERM.
#[cfg(not(feature = "zenoh"))]
pub fn run(_: &RouterArgs) -> Result<(), String> {
    Err(ndr::net::TransportError::ZenohNotBuilt.to_string())
}

/// Routes until SIGINT or SIGTERM.
#[cfg(feature = "zenoh")]
pub fn run(args: &RouterArgs) -> Result<(), String> {
    let rt = runtime()?;
    let options = args.zenoh.options(&args.listen);
    let router = rt
        .block_on(ndr::net::ZenohRouter::start(&options))
        .map_err(|e| e.to_string())?;
    eprintln!(
        "ndr router: routing zenoh on {} (SIGINT or SIGTERM: stop)",
        args.listen.join(", ")
    );
    rt.block_on(async {
        let mut term = tokio::signal::unix::signal(tokio::signal::unix::SignalKind::terminate())
            .map_err(|e| format!("cannot watch SIGTERM: {e}"))?;
        tokio::select! {
            _ = tokio::signal::ctrl_c() => {}
            _ = term.recv() => {}
        }
        router.close().await.map_err(|e| e.to_string())
    })
}

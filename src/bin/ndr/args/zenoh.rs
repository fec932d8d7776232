//! The zenoh options of `base`, `remote` and `router` (`--transport zenoh`).

use std::path::PathBuf;

/// How a side joins zenoh.
#[derive(clap::Args, Clone, Debug, Default)]
pub struct ZenohArgs {
    /// With --transport zenoh: a zenoh endpoint to dial, a router's
    /// (tcp/HOST:7447; repeat for several). Without it, this side is a
    /// zenoh peer that finds others on the LAN.
    #[arg(long, value_name = "ENDPOINT")]
    pub zenoh_connect: Vec<String>,
    /// With --transport zenoh (and for `ndr router`): a zenoh
    /// configuration file (JSON5) for zenoh's own settings (access
    /// control, timeouts); the endpoints given here are set on top of it.
    #[arg(long, value_name = "FILE")]
    pub zenoh_config: Option<PathBuf>,
}

impl ZenohArgs {
    /// Whether any zenoh option was given (refused without --transport zenoh).
    pub fn given(&self) -> bool {
        !self.zenoh_connect.is_empty() || self.zenoh_config.is_some()
    }

    #[cfg(feature = "zenoh")]
    pub fn options(&self, listen: &[String]) -> ndr::net::ZenohOptions {
        let mut options = ndr::net::ZenohOptions::connect(self.zenoh_connect.iter().cloned())
            .listening(listen.iter().cloned());
        if let Some(file) = &self.zenoh_config {
            options = options.with_config_file(file);
        }
        options
    }
}

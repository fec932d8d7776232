//! Links over zenoh ([`Transport::Zenoh`], feature `zenoh`): a robot
//! found by its name through a zenoh router (or zenoh peers on a LAN),
//! with ndr's frames as the publications' payloads, unchanged.
//!
//! A remote named `NAME` ([`Listener::listen_zenoh`](crate::Listener::listen_zenoh))
//! subscribes to `ndr/NAME/control/*/base`. A base
//! ([`Link::connect_zenoh`]) draws a session `S` (16 hex digits) and
//! publishes its Hello on `ndr/NAME/control/S/base`; the remote then runs
//! the link on these keys:
//!
//! | key                         | from   | what                                   |
//! |-----------------------------|--------|----------------------------------------|
//! | `ndr/NAME/control/S/base`   | base   | Hello, Control, Close, Token (reliable) |
//! | `ndr/NAME/control/S/remote` | remote | the same, the remote's                 |
//! | `ndr/NAME/command/S`        | base   | the commands' Bundles (best effort, express) |
//! | `ndr/NAME/state/S`          | remote | the states' Bundles (best effort, express)   |
//!
//! Observers are bases like any other, each with its own `S`: a plain
//! zenoh subscriber of `ndr/NAME/state/*` sees every link's states
//! (docs/wire.md has the Bundle's layout). Both sides' publications are
//! dropped rather than queued when zenoh's queue is full, and never block
//! the hub's thread.

use std::path::PathBuf;
use std::time::{Duration as StdDuration, Instant as StdInstant};

use ndr_core::wire::Role;

use crate::config::LinkConfig;
use crate::error::NetError;
use crate::hub::Msg;
use crate::hub::zenoh::{Keys, ZenohPath};
use crate::link::Link;
use crate::transport::Transport;

/// How long a base waits at least for the robot's subscriber to be seen
/// (zenoh's routing learns subscriptions some milliseconds after a session
/// opens).
const MIN_WAIT_FOR_ROBOT: StdDuration = StdDuration::from_secs(2);
/// How often a base looks again for the robot's subscriber.
const LOOK_AGAIN: StdDuration = StdDuration::from_millis(10);

/// How a side joins zenoh: the endpoints it dials and listens on, and a
/// zenoh configuration file read first.
///
/// With endpoints to dial, a base or remote runs as a zenoh client (a
/// router's); without, as a zenoh peer (on a LAN, peers find each other by
/// multicast scouting).
#[derive(Clone, Debug, Default)]
#[non_exhaustive]
pub struct ZenohOptions {
    /// Endpoints to dial, as zenoh writes them (`tcp/HOST:7447`).
    pub connect: Vec<String>,
    /// Endpoints to listen on (`tcp/0.0.0.0:7447`).
    pub listen: Vec<String>,
    /// A zenoh configuration file (JSON5), for zenoh's own settings (access
    /// control, timeouts…); the endpoints above are set on top of it.
    /// Without one, a base or remote dials its router again every 250 ms
    /// at first, then every second, when it loses it (zenoh's default
    /// backs off to 4 s).
    pub config_file: Option<PathBuf>,
}

impl ZenohOptions {
    /// Dials `endpoints` (a router's).
    #[must_use]
    pub fn connect<I: IntoIterator<Item = S>, S: Into<String>>(endpoints: I) -> ZenohOptions {
        ZenohOptions {
            connect: endpoints.into_iter().map(Into::into).collect(),
            ..ZenohOptions::default()
        }
    }

    /// The same, listening on `endpoints` too.
    #[must_use]
    pub fn listening<I: IntoIterator<Item = S>, S: Into<String>>(
        mut self,
        endpoints: I,
    ) -> ZenohOptions {
        self.listen = endpoints.into_iter().map(Into::into).collect();
        self
    }

    /// The same, reading zenoh's configuration from `file` first.
    #[must_use]
    pub fn with_config_file(mut self, file: impl Into<PathBuf>) -> ZenohOptions {
        self.config_file = Some(file.into());
        self
    }

    /// zenoh's configuration for a session in `mode` (`client`, `peer`
    /// or `router`).
    fn config(&self, mode: &str) -> Result<zenoh::Config, NetError> {
        let mut config = match &self.config_file {
            Some(file) => zenoh::Config::from_file(file).map_err(|e| {
                zenoh_error(format!(
                    "cannot read the zenoh configuration {}: {e}",
                    file.display()
                ))
            })?,
            None => zenoh::Config::default(),
        };
        let set = |config: &mut zenoh::Config, key: &str, value: String| {
            config
                .insert_json5(key, &value)
                .map_err(|e| zenoh_error(format!("zenoh configuration {key} = {value}: {e}")))
        };
        set(&mut config, "mode", format!("{mode:?}"))?;
        if self.config_file.is_none() && mode != "router" {
            // zenoh's own default backs off to 4 s between attempts: a
            // router back after a restart would be found seconds late,
            // past what a link's liveness allows. Attempts every 250 ms
            // at first, then every second.
            set(
                &mut config,
                "connect/retry",
                r#"{"period_init_ms": 250, "period_max_ms": 1000, "period_increase_factor": 2}"#
                    .into(),
            )?;
        }
        if !self.connect.is_empty() {
            set(&mut config, "connect/endpoints", json_list(&self.connect))?;
        }
        if !self.listen.is_empty() {
            set(&mut config, "listen/endpoints", json_list(&self.listen))?;
        }
        Ok(config)
    }

    /// Opens a session: a router's client if it dials, else a peer.
    pub(crate) async fn open(&self) -> Result<zenoh::Session, NetError> {
        let mode = if self.connect.is_empty() {
            "peer"
        } else {
            "client"
        };
        self.open_as(mode).await
    }

    async fn open_as(&self, mode: &str) -> Result<zenoh::Session, NetError> {
        let config = self.config(mode)?;
        zenoh::open(config).await.map_err(|e| {
            zenoh_error(format!(
                "cannot open a zenoh session ({mode}, dialing {:?}): {e}; is the router \
                 there (`ndr router --listen tcp/HOST:7447`, or zenohd)?",
                self.connect
            ))
        })
    }
}

/// A zenoh router run in this process (`ndr router`): zenoh's own
/// routing, configured here, adding nothing of ndr's. It routes while
/// this value lives.
pub struct ZenohRouter {
    session: zenoh::Session,
}

impl std::fmt::Debug for ZenohRouter {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("ZenohRouter")
            .field("zid", &self.session.zid().to_string())
            .finish()
    }
}

impl ZenohRouter {
    /// Starts a router listening as `options` says (its `listen`
    /// endpoints; `connect`, other routers to join).
    pub async fn start(options: &ZenohOptions) -> Result<ZenohRouter, NetError> {
        let session = options.open_as("router").await?;
        Ok(ZenohRouter { session })
    }

    /// Stops routing.
    pub async fn close(self) -> Result<(), NetError> {
        self.session
            .close()
            .await
            .map_err(|e| zenoh_error(format!("closing the zenoh router: {e}")))
    }
}

impl Link {
    /// Connects to the robot named `robot` over zenoh (this side is the
    /// base): opens a zenoh session as `zenoh` says, waits for the robot's
    /// subscriber to be seen (up to [`LinkConfig::wait_for_remote`], at
    /// least 2 s), then runs the link on a hub as [`Link::connect`] does.
    /// The [`LinkConfig::transport`] must be [`Transport::Zenoh`], and the
    /// link carries no ndr TLS.
    pub async fn connect_zenoh(
        robot: &str,
        zenoh: &ZenohOptions,
        config: LinkConfig,
    ) -> Result<Link, NetError> {
        let transport = config.checked_transport(config.tls.is_some())?;
        if !transport.is_zenoh() {
            return Err(wrong_transport(transport));
        }
        check_name(robot)?;
        let session = zenoh.open().await?;
        let hub = config.hub.pick(config.spin_margin, config.realtime)?;
        let token = format!("{:016x}", crate::link::session_token()?);
        let keys = Keys::of(robot, &token, Role::Base);
        let path = ZenohPath::open(&session, &keys, None)
            .map_err(|e| zenoh_error(format!("declaring the link's keys: {e}")))?;
        let wait: StdDuration = config.wait_for_remote.into();
        let wait = wait.max(MIN_WAIT_FOR_ROBOT);
        let until = StdInstant::now() + wait;
        // A Hello published before the robot's subscriber is known would be
        // lost: zenoh keeps nothing for subscribers to come.
        while !path.peer_listens().await {
            if StdInstant::now() >= until {
                return Err(NetError::Io(std::io::Error::new(
                    std::io::ErrorKind::NotFound,
                    format!(
                        "no robot named {robot:?} answers over zenoh (no subscriber of \
                         {} within {wait:?}): start `ndr remote --transport zenoh --name \
                         {robot}` against the same router, or check the name",
                        keys.frames_out
                    ),
                )));
            }
            tokio::time::sleep(LOOK_AGAIN).await;
        }
        let (id, entry, link) = Link::start_zenoh(&config, Role::Base, &hub, path, None)?;
        if !hub.send(Msg::Add(id, Box::new(entry))) {
            return Err(NetError::Io(std::io::Error::other(
                "the link's hub thread has stopped",
            )));
        }
        Ok(link)
    }
}

impl Keys {
    /// The keys of session `token` with the robot `name`, as `role` sees them.
    pub(crate) fn of(name: &str, token: &str, role: Role) -> Keys {
        let base = format!("ndr/{name}/control/{token}/base");
        let remote = format!("ndr/{name}/control/{token}/remote");
        let command = format!("ndr/{name}/command/{token}");
        let state = format!("ndr/{name}/state/{token}");
        match role {
            Role::Remote => Keys {
                frames_out: remote,
                samples_out: state,
                frames_in: base,
                samples_in: command,
            },
            _ => Keys {
                frames_out: base,
                samples_out: command,
                frames_in: remote,
                samples_in: state,
            },
        }
    }
}

/// What a remote named `name` subscribes to for new bases' Hellos.
pub(crate) fn hellos(name: &str) -> String {
    format!("ndr/{name}/control/*/base")
}

/// The session token in a key of [`hellos`]: its fourth chunk.
pub(crate) fn token_of(key: &str) -> Option<&str> {
    let token = key.split('/').nth(3)?;
    (token.len() == 16 && token.bytes().all(|b| b.is_ascii_hexdigit())).then_some(token)
}

/// A robot's name must be one chunk of a zenoh key, without wildcards.
pub(crate) fn check_name(name: &str) -> Result<(), NetError> {
    let ok = !name.is_empty()
        && name.len() <= 128
        && name
            .bytes()
            .all(|b| b.is_ascii_alphanumeric() || b"-_.".contains(&b));
    if ok {
        Ok(())
    } else {
        Err(NetError::Io(std::io::Error::new(
            std::io::ErrorKind::InvalidInput,
            format!(
                "robot name {name:?}: give 1 to 128 letters, digits, '-', '_' or '.' (it \
                 becomes one chunk of zenoh's keys, ndr/NAME/...)"
            ),
        )))
    }
}

pub(crate) fn wrong_transport(transport: Transport) -> NetError {
    NetError::Io(std::io::Error::new(
        std::io::ErrorKind::InvalidInput,
        format!("a zenoh link needs LinkConfig::with_transport(Transport::ZENOH), not {transport}"),
    ))
}

pub(crate) fn zenoh_error(what: String) -> NetError {
    NetError::Io(std::io::Error::other(what))
}

fn json_list(items: &[String]) -> String {
    let quoted: Vec<String> = items.iter().map(|s| format!("{s:?}")).collect();
    format!("[{}]", quoted.join(","))
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn keys_pair_up_and_tokens_read_back() {
        let base = Keys::of("arm1", "00112233aabbccdd", Role::Base);
        let remote = Keys::of("arm1", "00112233aabbccdd", Role::Remote);
        assert_eq!(base.frames_out, remote.frames_in);
        assert_eq!(base.samples_out, remote.samples_in);
        assert_eq!(remote.samples_out, "ndr/arm1/state/00112233aabbccdd");
        assert_eq!(token_of(&base.frames_out), Some("00112233aabbccdd"));
        assert_eq!(token_of("ndr/arm1/control/zz/base"), None);
        assert!(check_name("arm1").is_ok());
        for bad in ["", "a/b", "a*", "$x", "a b"] {
            assert!(check_name(bad).is_err(), "{bad}");
        }
    }
}

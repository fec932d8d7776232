//! A robot that bases find by its name over zenoh
//! ([`Listener::listen_zenoh`]): a subscriber of new bases' Hellos, and for
//! each a link on the keys of its session (`crate::zenoh_link`), its
//! Hello exchange within the pre-authentication budget, then the same
//! seats, observers and accept queue as any listener's.

use std::collections::{HashSet, VecDeque};
use std::net::SocketAddr;
use std::sync::Arc;
use std::time::{Duration as StdDuration, Instant as StdInstant};

use ndr_core::wire::{Frame, Kind};
use tokio::runtime::Handle;
use tokio::sync::{Semaphore, mpsc};
use tokio::time::Instant as TokioInstant;
use zenoh::Wait as _;

use super::handshake::{Cut, Failed, enqueue, hello};
use super::{Common, Hubs, Listener, Refusal};
use crate::config::LinkConfig;
use crate::error::NetError;
use crate::hub::zenoh::{Keys, ZenohPath};
use crate::hub::{Hub, Msg};
use crate::link::Link;
use crate::pool::HubChoice;
use crate::zenoh_link::{ZenohOptions, check_name, hellos, token_of, wrong_transport, zenoh_error};

/// Hellos heard and not yet taken by the gate; past them one is dropped
/// (counted as a timeout: its base hears nothing and gives up).
const HEARD: usize = 64;
/// Sessions remembered as started, so that a late frame of one that ended
/// does not start another: the oldest are forgotten past this.
const REMEMBERED: usize = 4096;

impl Listener {
    /// Serves bases that ask for the robot named `name` over zenoh (this
    /// side is the remote unless [`with_role`](Self::with_role) says
    /// otherwise): opens a zenoh session as `zenoh` says and answers each
    /// base's Hello on its own keys. The [`LinkConfig::transport`] must be
    /// [`Transport::Zenoh`](crate::Transport::Zenoh), without ndr TLS.
    /// [`local_addr`](Self::local_addr) is the unspecified address: zenoh
    /// links have none.
    pub async fn listen_zenoh(
        name: &str,
        zenoh: &ZenohOptions,
        config: LinkConfig,
    ) -> Result<Listener, NetError> {
        let transport = config.checked_transport(config.tls.is_some())?;
        if !transport.is_zenoh() {
            return Err(wrong_transport(transport));
        }
        check_name(name)?;
        let session = zenoh.open().await?;
        let hubs = match &config.hub {
            HubChoice::Own => Hubs::One(Hub::with_realtime(config.spin_margin, config.realtime)?),
            HubChoice::Shared(hub) => Hubs::One(hub.clone()),
            HubChoice::Pool(pool) => Hubs::Pool(pool.clone()),
        };
        let accept_queue = config.admission.accept_queue.max(1);
        let slots = crate::tls::DEFAULT_MAX_PENDING_HANDSHAKES;
        let common = Common::new(config, None, None, hubs)?;
        let (heard_tx, heard_rx) = mpsc::channel::<(String, StdInstant, Vec<u8>)>(HEARD);
        let subscriber = session
            .declare_subscriber(hellos(name))
            .callback(move |s: zenoh::sample::Sample| {
                let at = StdInstant::now();
                let Some(token) = token_of(s.key_expr().as_str()) else {
                    return;
                };
                let bytes = s.payload().to_bytes();
                // Only a Hello opens a link: a late frame of a session
                // that ended opens none.
                let is_hello =
                    Frame::new_checked(bytes.as_ref()).is_ok_and(|f| f.kind() == Kind::Hello);
                if is_hello {
                    let _ = heard_tx.try_send((token.to_owned(), at, bytes.into_owned()));
                }
            })
            .wait()
            .map_err(|e| zenoh_error(format!("subscribing to {}: {e}", hellos(name))))?;
        let (tx, rx) = mpsc::channel(accept_queue);
        let gate = Gate {
            common: Arc::clone(&common),
            session,
            name: name.to_owned(),
            ready: tx,
            slots: Arc::new(Semaphore::new(slots)),
            started: HashSet::new(),
            order: VecDeque::new(),
        };
        let gate = Handle::current()
            .spawn(gate.run(heard_rx, subscriber))
            .abort_handle();
        Ok(Listener {
            local: SocketAddr::from((std::net::Ipv4Addr::UNSPECIFIED, 0)),
            common,
            ready: tokio::sync::Mutex::new(rx),
            gate,
            listening: None,
            runtime: None,
        })
    }
}

/// The zenoh listener's accept loop.
struct Gate {
    common: Arc<Common>,
    session: zenoh::Session,
    name: String,
    ready: mpsc::Sender<Link>,
    /// Handshakes under way, at most the listener's slots.
    slots: Arc<Semaphore>,
    started: HashSet<String>,
    order: VecDeque<String>,
}

impl Gate {
    async fn run(
        mut self,
        mut heard: mpsc::Receiver<(String, StdInstant, Vec<u8>)>,
        // Kept while the loop runs: aborting it unsubscribes.
        _subscriber: zenoh::pubsub::Subscriber<()>,
    ) {
        while let Some((token, at, first)) = heard.recv().await {
            if !self.remember(&token) {
                continue;
            }
            let Ok(slot) = Arc::clone(&self.slots).try_acquire_owned() else {
                self.common.refuse(
                    Refusal::Evicted,
                    None,
                    &"every handshake slot is taken: a zenoh base's Hello was not answered",
                );
                continue;
            };
            let link = match self.start(&token, at, first) {
                Ok(link) => link,
                Err(e) => {
                    self.common.refuse(Refusal::of_link(&e), None, &e);
                    continue;
                }
            };
            let common = Arc::clone(&self.common);
            let ready = self.ready.clone();
            tokio::spawn(async move {
                let budget: StdDuration = common.config.admission.preauth_timeout.into();
                let deadline = (!budget.is_zero()).then(|| TokioInstant::now() + budget);
                let late = || -> Failed {
                    (
                        Refusal::Timeout,
                        format!(
                            "no handshake within {budget:?} (the pre-authentication budget, \
                             LinkConfig::admission.preauth_timeout)"
                        ),
                    )
                };
                let outcome = hello(link, deadline, late, &Cut::default()).await;
                drop(slot);
                let peer = SocketAddr::from((std::net::Ipv4Addr::UNSPECIFIED, 0));
                match outcome {
                    Ok(link) => enqueue(&common, link, peer, &ready),
                    Err((why, what)) => common.refuse(why, None, &what),
                }
            });
        }
    }

    /// Notes session `token` as started; `false` if it was already.
    fn remember(&mut self, token: &str) -> bool {
        if !self.started.insert(token.to_owned()) {
            return false;
        }
        self.order.push_back(token.to_owned());
        if self.order.len() > REMEMBERED
            && let Some(old) = self.order.pop_front()
        {
            self.started.remove(&old);
        }
        true
    }

    /// A link for session `token`, its Hello waiting in its inbox.
    fn start(&self, token: &str, at: StdInstant, hello: Vec<u8>) -> Result<Link, NetError> {
        let (role, hub) = self.common.setup();
        let keys = Keys::of(&self.name, token, role);
        let path = ZenohPath::open(&self.session, &keys, Some((at, hello)))
            .map_err(|e| zenoh_error(format!("declaring a link's keys: {e}")))?;
        let (id, entry, link) = Link::start_zenoh(
            &self.common.config,
            role,
            &hub,
            path,
            self.common.sharing_for(role),
        )?;
        if !hub.send(Msg::Add(id, Box::new(entry))) {
            return Err(NetError::Io(std::io::Error::other(
                "the link's hub thread has stopped",
            )));
        }
        Ok(link)
    }
}

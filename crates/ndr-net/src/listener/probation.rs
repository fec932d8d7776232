//! Newcomers on probation: connections that came while their source held
//! every slot it may, each of a handshake that has said as much as they
//! and moved lately, and that had not yet sent their whole first message.
//!
//! Such a newcomer may be an attacker's silent connection or a real peer
//! whose first message is a moment behind its connection; neither can be
//! told from the other until that moment has passed. So it waits, without
//! a slot, up to [`PROBATION`] for its first message: whole, it goes back
//! to the gate to take a silent connection's slot; still silent, it is
//! turned away (told why, on a plain link). At most a fixed number wait at
//! once; a newcomer to a full probation takes the place of the one waiting
//! longest, so that however fast stale connections come back, a real
//! peer's first message has many of their arrivals' time to come.

use std::collections::VecDeque;
use std::net::SocketAddr;
use std::time::Duration as StdDuration;

use ndr_core::wire::CloseReason;
use tokio::net::TcpStream;
use tokio::task::{AbortHandle, Id, JoinError, JoinSet};

use super::first;
use super::handshake::tell;

/// How long a newcomer on probation may take to send its whole first
/// message: a real peer sends it with its connection.
pub(super) const PROBATION: StdDuration = StdDuration::from_millis(100);

/// How a newcomer's probation ended.
pub(super) enum Ended {
    /// It sent its whole first message: back to the gate for a slot.
    Spoke(TcpStream, SocketAddr),
    /// It said too little in time, and was turned away.
    Silent(SocketAddr),
    /// It closed first.
    Left(SocketAddr),
}

/// The newcomers on probation.
pub(super) struct Probation {
    waiting: JoinSet<Ended>,
    /// Oldest first, for the next to give way.
    order: VecDeque<(Id, AbortHandle, SocketAddr)>,
    max: usize,
    tls: bool,
}

impl Probation {
    /// At most `max` (at least one) at once; `tls` if the listener has
    /// TLS (nothing can be said to a peer before its TLS handshake).
    pub(super) fn new(max: usize, tls: bool) -> Probation {
        Probation {
            waiting: JoinSet::new(),
            order: VecDeque::new(),
            max: max.max(1),
            tls,
        }
    }

    pub(super) fn is_empty(&self) -> bool {
        self.waiting.is_empty()
    }

    /// Puts `stream` on probation; the peer of the one it displaced, if
    /// probation was full (turned away as it ends).
    pub(super) fn admit(&mut self, stream: TcpStream, peer: SocketAddr) -> Option<SocketAddr> {
        let displaced = if self.order.len() >= self.max {
            self.order.pop_front().map(|(_, abort, peer)| {
                abort.abort();
                peer
            })
        } else {
            None
        };
        let task = self.waiting.spawn(wait(stream, peer, self.tls));
        self.order.push_back((task.id(), task, peer));
        displaced
    }

    /// The next probation that ended (not one displaced: that one was
    /// counted then).
    pub(super) async fn next(&mut self) -> Option<Ended> {
        loop {
            let done = self.waiting.join_next_with_id().await?;
            if let Some(ended) = self.ended(done) {
                return Some(ended);
            }
        }
    }

    fn ended(&mut self, done: Result<(Id, Ended), JoinError>) -> Option<Ended> {
        let id = match &done {
            Ok((id, _)) => *id,
            Err(e) => e.id(),
        };
        self.order.retain(|(task, _, _)| *task != id);
        done.ok().map(|(_, ended)| ended)
    }
}

/// A newcomer's connection while it waits: turned away as it is dropped,
/// unless taken back.
struct OnProbation {
    stream: Option<TcpStream>,
    tls: bool,
}

impl Drop for OnProbation {
    fn drop(&mut self) {
        if let Some(stream) = self.stream.take() {
            refuse(stream, !self.tls);
        }
    }
}

/// Waits up to [`PROBATION`] for the peer's whole first message.
async fn wait(stream: TcpStream, peer: SocketAddr, tls: bool) -> Ended {
    let mut held = OnProbation {
        stream: Some(stream),
        tls,
    };
    let Some(stream) = held.stream.as_ref() else {
        return Ended::Left(peer);
    };
    let spoke = tokio::time::timeout(PROBATION, first::wait_whole(stream, tls, |_, _| {})).await;
    match spoke {
        Ok(Ok(true)) => match held.stream.take() {
            Some(stream) => Ended::Spoke(stream, peer),
            None => Ended::Left(peer),
        },
        // Gone: nothing to say to it.
        Ok(Ok(false) | Err(_)) => {
            held.stream = None;
            Ended::Left(peer)
        }
        // Turned away as `held` drops.
        Err(_) => Ended::Silent(peer),
    }
}

/// Turns a newcomer away for its source's cap: on a plain link with a
/// Close saying so; under TLS, where nothing can be said before its
/// handshake, with a reset (this side keeps no TIME_WAIT for it).
pub(super) fn refuse(stream: TcpStream, plain: bool) {
    if plain {
        tell(stream, CloseReason::EvictedSource);
    } else {
        let _ = stream.set_zero_linger();
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::listener::first::tests::hello;
    use ndr_core::wire::{self, Payload};
    use tokio::io::{AsyncReadExt, AsyncWriteExt};
    use tokio::net::TcpListener;

    /// A client and the listener's side of its connection.
    async fn pair(listener: &TcpListener) -> (TcpStream, TcpStream, SocketAddr) {
        let client = TcpStream::connect(listener.local_addr().expect("address"))
            .await
            .expect("connect");
        let (accepted, peer) = listener.accept().await.expect("accept");
        (client, accepted, peer)
    }

    /// The Close reason `client` read before its end of stream.
    async fn told(mut client: TcpStream) -> Option<CloseReason> {
        let mut got = Vec::new();
        let read = tokio::time::timeout(StdDuration::from_secs(2), client.read_to_end(&mut got));
        read.await.ok()?.ok()?;
        let frame = wire::Frame::new_checked(got.as_slice()).ok()?;
        match frame.payload() {
            Payload::Close(c) => Some(c.reason),
            _ => None,
        }
    }

    #[tokio::test]
    async fn a_newcomer_that_speaks_goes_back_one_silent_is_turned_away_and_a_full_probation_gives_way_to_the_newest()
     {
        let listener = TcpListener::bind("127.0.0.1:0").await.expect("bind");
        let mut probation = Probation::new(2, false);
        let (first, accepted, first_peer) = pair(&listener).await;
        assert_eq!(probation.admit(accepted, first_peer), None);
        let (mut speaker, accepted, speaker_peer) = pair(&listener).await;
        assert_eq!(probation.admit(accepted, speaker_peer), None);
        // A third: the one waiting longest gives way, and is told why.
        let (silent, accepted, silent_peer) = pair(&listener).await;
        assert_eq!(probation.admit(accepted, silent_peer), Some(first_peer));
        assert_eq!(told(first).await, Some(CloseReason::EvictedSource));
        // The second speaks at once: back to the gate with its stream.
        speaker.write_all(&hello()).await.expect("write");
        match probation.next().await {
            Some(Ended::Spoke(_, peer)) => assert_eq!(peer, speaker_peer),
            _ => panic!("the speaker goes back to the gate"),
        }
        // The third says nothing: turned away after its probation.
        match probation.next().await {
            Some(Ended::Silent(peer)) => assert_eq!(peer, silent_peer),
            _ => panic!("the silent one is turned away"),
        }
        assert_eq!(told(silent).await, Some(CloseReason::EvictedSource));
        assert!(probation.is_empty());
    }
}

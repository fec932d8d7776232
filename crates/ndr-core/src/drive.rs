//! The application's turn of the drive contract (steps 3 and 4 in the crate
//! doc), for drivers that run the application in line with the endpoint:
//! the simulator, the [`Pair`](crate::pair::Pair) and the fuzz harness.
//!
//! The events come first and the frames after them, so that a sample set
//! while answering a release goes out in the frame of the tick that
//! released it. A driver that hands releases to another thread (the hub)
//! follows the same order without this function.

use crate::endpoint::{Endpoint, Event, LinkError};
use crate::storage::Storage;
use crate::time::Instant;

/// What runs beside an endpoint during its turn: the application, and the
/// wire its frames go to.
pub trait Turn<S: Storage> {
    /// What ends the driver's loop.
    type Error;

    /// An event for the application, in the order the endpoint raised it.
    /// Answering a release with [`Endpoint::set_sample`] here puts the
    /// answer in this turn's frame.
    fn event(
        &mut self,
        endpoint: &mut Endpoint<S>,
        event: Event<S::Values>,
    ) -> Result<(), Self::Error>;

    /// After the last event, before the first frame: the application's last
    /// word on the sample this turn sends (an operator sets its command
    /// here whether or not anything was released).
    fn sample(&mut self, endpoint: &mut Endpoint<S>) -> Result<(), Self::Error> {
        let _ = endpoint;
        Ok(())
    }

    /// A frame for the peer.
    fn transmit(&mut self, frame: &[u8]) -> Result<(), Self::Error>;

    /// [`Endpoint::poll_transmit`] failed (a buffer too small for the
    /// frame); the turn ends after this.
    fn failed(&mut self, error: LinkError) -> Result<(), Self::Error>;
}

/// Drains `endpoint`'s events into `turn`, then its frames, at `now` (the
/// endpoint's clock). `buf` holds one frame: [`MAX_FRAME_LEN`] bytes
/// always suffice.
///
/// [`MAX_FRAME_LEN`]: crate::wire::MAX_FRAME_LEN
pub fn turn<S: Storage, T: Turn<S>>(
    endpoint: &mut Endpoint<S>,
    now: Instant,
    buf: &mut [u8],
    turn: &mut T,
) -> Result<(), T::Error> {
    while let Some(event) = endpoint.poll_event() {
        turn.event(endpoint, event)?;
    }
    turn.sample(endpoint)?;
    loop {
        match endpoint.poll_transmit(now, buf) {
            Ok(Some(n)) => turn.transmit(buf.get(..n).unwrap_or_default())?,
            Ok(None) => return Ok(()),
            // The same buffer would fail again: the turn ends here.
            Err(e) => return turn.failed(e),
        }
    }
}

//! Seats: who on a link may command the robot, and in which term.
//!
//! A remote serves one controller and any number of observers, each on a
//! link of its own; which link holds control, and in which numbered term,
//! is decided across the links by a [`Floor`](crate::floor::Floor). This
//! module is one link's part: the seat its Hellos agree on, the term the
//! link holds control in (if any), and the fencing that follows. A base
//! sends commands only while it holds a term (probes otherwise), each frame
//! stamped with that term; a remote hands its application only commands of
//! the term its link holds now, and counts the others.

use super::{Endpoint, Event, LinkError, Phase, Tx};
use crate::storage::Storage;
use crate::wire::{CloseReason, Control, ControlOp, Kind, Role, Seat};

/// One link's seat and term.
#[derive(Clone, Copy, Debug)]
pub(super) struct Seating {
    /// The seat the base asked for (a base: its own; a remote: the peer's,
    /// once its Hello came).
    pub(super) asked: Seat,
    /// The seat the remote's Hello gave, once the Hellos are exchanged.
    pub(super) given: Option<Seat>,
    /// The term this link holds control in.
    pub(super) held: Option<u16>,
    /// The term this side's frames carry: a base's, the one it holds (0
    /// when none); a remote's, the robot's current term.
    pub(super) announced: u16,
    /// A remote whose Hello gave control grants it at its first start; one
    /// whose driver made an offer waits for the driver's grant.
    pub(super) auto_grant: bool,
}

impl Seating {
    pub(super) fn new(role: Role, seat: Seat) -> Self {
        Seating {
            asked: seat,
            given: None,
            held: None,
            // A remote driven alone (one base, no floor) grants term 1.
            announced: match role {
                Role::Base => 0,
                Role::Remote => 1,
            },
            auto_grant: true,
        }
    }
}

impl<S: Storage> Endpoint<S> {
    /// The seats of a base's Hello as this side sees them: a remote takes
    /// the ask and decides; a base checks the answer fits its ask.
    pub(super) fn seat_hello(&mut self, asked_or_given: Seat) -> Result<(), LinkError> {
        match self.config.role {
            Role::Remote => {
                self.seating.asked = asked_or_given;
                let given = asked_or_given.given(self.config.seat);
                self.seating.given = Some(given.unwrap_or(Seat::Observe));
                given.map(drop).ok_or(LinkError::Busy)
            }
            Role::Base => {
                // Refused control: the remote's Close `busy` follows; its
                // Hello says as much already.
                if self.seating.asked == Seat::Control && asked_or_given == Seat::Observe {
                    return Err(LinkError::PeerClosed {
                        reason: CloseReason::Busy,
                    });
                }
                let fits = match (self.seating.asked, asked_or_given) {
                    (_, Seat::WaitForControl) => false,
                    (Seat::Observe, seat) => seat == Seat::Observe,
                    (Seat::Control, seat) => seat == Seat::Control,
                    (Seat::WaitForControl, _) => true,
                };
                if !fits {
                    return Err(LinkError::Unexpected {
                        kind: Kind::Hello,
                        phase: "a Hello whose seat does not answer the one asked",
                    });
                }
                self.seating.given = Some(asked_or_given);
                Ok(())
            }
        }
    }

    /// The first start of a remote whose Hello gave control: the link
    /// passed its initialization pattern, its base's commands apply from
    /// now, in the term announced.
    pub(super) fn grant_at_start(&mut self) {
        if self.config.role == Role::Remote
            && self.seating.auto_grant
            && self.seating.given == Some(Seat::Control)
            && self.seating.held.is_none()
        {
            let term = self.seating.announced.max(1);
            self.hold_term(term, false);
        }
    }

    /// Remote: the link's base holds control in `term` from now; `tell`
    /// sends it Control `grant` (a base given control in the Hello took
    /// the term its header announced, and needs none).
    fn hold_term(&mut self, term: u16, tell: bool) {
        self.seating.held = Some(term);
        self.seating.announced = term;
        self.seating.given = Some(Seat::Control);
        self.stats.grants += 1;
        if tell {
            self.queue_tx(Tx::Control {
                op: ControlOp::Grant,
                ns: 0,
                period: crate::time::Duration::ZERO,
            });
        }
        self.emit(Event::ControlGranted { term });
    }

    /// Remote: the term this link's base holds control in, `None` if it
    /// holds none. Base: the term this side holds.
    #[must_use]
    pub fn term(&self) -> Option<u16> {
        self.seating.held
    }

    /// The seat the Hellos agreed on (`None` before): a base given
    /// [`Seat::Observe`] that asked to wait for control may still be
    /// granted it ([`Event::ControlGranted`]).
    #[must_use]
    pub fn seat(&self) -> Option<Seat> {
        self.seating.given
    }

    /// The seat the base asked for: a base's own, a remote's peer's (once
    /// its Hello came).
    #[must_use]
    pub fn seat_asked(&self) -> Seat {
        self.seating.asked
    }

    /// Remote, before the handshake: the seat offered to a base that asks
    /// for control ([`Config::seat`](super::Config::seat)), and the term:
    /// offering control, the one the base will hold (not 0); offering
    /// observation, the robot's now. The driver calls it when it learns
    /// who holds control before the base's Hello is handled; it then
    /// grants control itself ([`grant`](Self::grant)) once its floor has
    /// admitted the base and the link has passed its initialization
    /// pattern — until then the base's commands are refused
    /// ([`Stats::commands_before_grant`](super::Stats)).
    ///
    /// # Errors
    /// [`LinkError::NotController`] on a base, after the handshake, or
    /// offering control in term 0.
    pub fn offer(&mut self, seat: Seat, term: u16) -> Result<(), LinkError> {
        if self.config.role != Role::Remote
            || self.phase != Phase::Handshake
            || (seat == Seat::Control && term == 0)
        {
            return Err(LinkError::NotController);
        }
        self.config.seat = seat;
        self.seating.announced = term;
        self.seating.auto_grant = false;
        Ok(())
    }

    /// Remote: the robot's current term, which this link's frames announce
    /// (an observer sees the terms change).
    pub fn set_term(&mut self, term: u16) {
        if self.config.role == Role::Remote && self.seating.held.is_none() {
            self.seating.announced = term;
        }
    }

    /// Remote: gives this link's base control in `term` (a base that asked
    /// for it, waiting as an observer). Its commands apply from the first
    /// one stamped with `term`; it gets Control `grant`.
    ///
    /// # Errors
    /// [`LinkError::NotController`] if the base asked only to observe, the
    /// link has not passed its initialization pattern (it is not running),
    /// or `term` is 0; [`LinkError::Closed`] on a closed link.
    pub fn grant(&mut self, term: u16) -> Result<(), LinkError> {
        if self.phase == Phase::Closed {
            return Err(LinkError::Closed);
        }
        if self.config.role != Role::Remote
            || self.seating.asked == Seat::Observe
            || self.phase != Phase::Running
            || term == 0
        {
            return Err(LinkError::NotController);
        }
        self.hold_term(term, true);
        Ok(())
    }

    /// Remote: takes control from this link's base (another base is
    /// taking it, or it yielded); `term` is the robot's term now. Its
    /// commands still queued, and any it sends on, are refused and
    /// counted ([`Stats::commands_refused_stale_term`](super::Stats)).
    pub fn revoke(&mut self, term: u16) {
        if self.config.role != Role::Remote || self.phase == Phase::Closed {
            return;
        }
        if self.seating.held.take().is_some() {
            self.seating.given = Some(Seat::Observe);
            self.queue_tx(Tx::Control {
                op: ControlOp::Revoke,
                ns: 0,
                period: crate::time::Duration::ZERO,
            });
        }
        self.seating.announced = term;
    }

    /// Remote: tells this link's base, which holds control, that another
    /// base waits for it ([`Event::ControlRequested`] on its side).
    pub fn request_control(&mut self) -> Result<(), LinkError> {
        if self.config.role != Role::Remote || self.seating.held.is_none() {
            return Err(LinkError::NotController);
        }
        self.queue_tx(Tx::Control {
            op: ControlOp::Request,
            ns: 0,
            period: crate::time::Duration::ZERO,
        });
        Ok(())
    }

    #[cfg(test)]
    /// Stamps this base's frames with `term` and sends its samples as if
    /// it held it: a base that ignores the floor (a stale or rogue peer).
    pub(crate) fn force_term(&mut self, term: u16) {
        self.seating.held = Some(term);
        self.seating.announced = term;
    }

    /// Base: gives control up. Commands stop at once (probes go out
    /// instead); the link stays, as an observer's.
    ///
    /// # Errors
    /// [`LinkError::NotController`] if this side holds no control;
    /// [`LinkError::Closed`] on a closed link.
    pub fn yield_control(&mut self) -> Result<(), LinkError> {
        if self.phase == Phase::Closed {
            return Err(LinkError::Closed);
        }
        let Some(term) = self.seating.held.filter(|_| self.config.role == Role::Base) else {
            return Err(LinkError::NotController);
        };
        self.seating.held = None;
        self.seating.announced = 0;
        self.seating.given = Some(Seat::Observe);
        self.queue_tx(Tx::Control {
            op: ControlOp::Yield,
            ns: 0,
            period: crate::time::Duration::ZERO,
        });
        self.emit(Event::ControlLost { term });
        Ok(())
    }

    /// Whether this side's ticks send samples: a remote always (its
    /// states), a base only while it holds control (probes otherwise).
    pub(super) fn sends_samples(&self) -> bool {
        self.config.role == Role::Remote || self.seating.held.is_some()
    }

    /// A Control frame of the seats' (`grant`, `revoke`, `yield`,
    /// `request`) in term `term`; `false` if `control` is none of them.
    pub(super) fn receive_seat_control(
        &mut self,
        control: Control,
        term: u16,
    ) -> Result<bool, LinkError> {
        if self.phase == Phase::Handshake {
            return match control.op {
                ControlOp::Grant | ControlOp::Revoke | ControlOp::Yield | ControlOp::Request => {
                    Err(self.unexpected(Kind::Control))
                }
                _ => Ok(false),
            };
        }
        match (self.config.role, control.op) {
            (Role::Base, ControlOp::Grant) => self.take_term(term)?,
            (Role::Base, ControlOp::Revoke) => {
                if let Some(held) = self.seating.held.take() {
                    self.seating.announced = 0;
                    self.seating.given = Some(Seat::Observe);
                    self.emit(Event::ControlLost { term: held });
                }
            }
            (Role::Base, ControlOp::Request) => {
                if self.seating.held.is_some() {
                    self.emit(Event::ControlRequested);
                }
            }
            (Role::Remote, ControlOp::Yield) => {
                // A yield that crossed a revoke is moot.
                if let Some(held) = self.seating.held.take() {
                    self.seating.given = Some(Seat::Observe);
                    self.emit(Event::ControlYielded { term: held });
                }
            }
            (_, ControlOp::Grant | ControlOp::Revoke | ControlOp::Yield | ControlOp::Request) => {
                return Err(self.unexpected(Kind::Control));
            }
            _ => return Ok(false),
        }
        Ok(true)
    }

    /// Base, its handshake done: given control at once, the remote's
    /// Hello's term is the one its commands carry (the remote applies them
    /// once its side of the link passed the initialization pattern).
    pub(super) fn seated(&mut self, term: u16) -> Result<(), LinkError> {
        if self.config.role == Role::Base && self.seating.given == Some(Seat::Control) {
            self.take_term(term)?;
        }
        Ok(())
    }

    /// Base: holds control in `term` from now.
    fn take_term(&mut self, term: u16) -> Result<(), LinkError> {
        if self.seating.asked == Seat::Observe || term == 0 {
            return Err(LinkError::Unexpected {
                kind: Kind::Control,
                phase: "a grant of control to a base that asked to observe, or of term 0",
            });
        }
        if self.seating.held == Some(term) {
            return Ok(());
        }
        self.seating.held = Some(term);
        self.seating.announced = term;
        self.seating.given = Some(Seat::Control);
        self.stats.grants += 1;
        // Copies of samples sent in an earlier term must not ride in this
        // term's datagrams.
        if let Some(d) = &mut self.dgram {
            d.forget_sent();
        }
        self.emit(Event::ControlGranted { term });
        Ok(())
    }

    /// Remote: whether a command stamped `term` arriving now may be
    /// queued; a refused one is counted.
    pub(super) fn admit_command(&mut self, term: u16) -> bool {
        if self.config.role != Role::Remote {
            return true;
        }
        match self.seating.held {
            Some(held) if held == term => true,
            _ if term == 0 => {
                self.stats.commands_refused_observer += 1;
                false
            }
            // Given control in the Hello, its grant still on its way.
            None if !self.seating.auto_grant
                && self.seating.given == Some(Seat::Control)
                && term == self.seating.announced =>
            {
                self.stats.commands_before_grant += 1;
                false
            }
            _ => {
                self.stats.commands_refused_stale_term += 1;
                false
            }
        }
    }

    /// Remote: whether a command of `term` leaving the regulator now may
    /// reach the application (control may have changed hands since it was
    /// queued); a refused one is counted.
    pub(super) fn apply_command(&mut self, term: u16) -> bool {
        if self.config.role != Role::Remote || self.seating.held == Some(term) {
            return true;
        }
        self.stats.commands_refused_stale_term += 1;
        false
    }
}

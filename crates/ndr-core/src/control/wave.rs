//! Wave variables (Niemeyer and Slotine, ICRA 1997) for a bilateral,
//! force-reflecting loop, and the energy bookkeeping of their channel.

use super::{ControlError, finite};

/// The master's side of a tick: the force reflected to the device, and the
/// wave to send.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct MasterPort {
    /// The force the channel applies against the master's motion.
    pub force: f64,
    /// The forward wave `u` to send.
    pub wave: f64,
}

/// The slave's side of a tick: the velocity to command, and the wave to send.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct SlavePort {
    /// The velocity the slave's local controller should track.
    pub velocity: f64,
    /// The backward wave `v` to send.
    pub wave: f64,
}

/// Wave variables (Niemeyer and Slotine, ICRA 1997) for a bilateral,
/// force-reflecting loop, and the energy bookkeeping of their channel.
///
/// A port with velocity `ẋ` and force `F` is encoded, for a wave impedance
/// `b > 0`, as the forward and backward waves
///
/// ```text
/// u = (b·ẋ + F)/√(2b)        v = (b·ẋ − F)/√(2b)        ẋ·F = ½(u² − v²)
/// ```
///
/// The master sends `u` and receives `v`; the slave receives `u` and sends
/// `v`. The channel stores what entered it (`½u²` per second at the master,
/// `½v²` at the slave) less what left it (`½v²` at the master, `½u²` at the
/// slave): with each wave delivered once, at any constant delay, what left
/// never exceeds what entered — the channel is passive. A wave delivered
/// twice (a repeat) or stretched over a longer time than it was sent for is
/// energy the channel creates: [`WaveEnergy`] keeps the account, tick by
/// tick, and its [`generated`](WaveEnergy::generated) is the most the
/// channel ever gave beyond what it received.
///
/// The wave transform at impedance `b`.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct WaveTransform {
    b: f64,
    sqrt_2b: f64,
}

impl WaveTransform {
    /// The transform with wave impedance `b` (force per velocity).
    ///
    /// # Errors
    /// [`ControlError::InvalidParameter`] unless `b` is finite and positive.
    pub fn new(b: f64) -> Result<Self, ControlError> {
        if !(b.is_finite() && b > 0.0) {
            return Err(ControlError::InvalidParameter(
                "the wave impedance b (> 0, force per velocity)",
            ));
        }
        Ok(WaveTransform {
            b,
            sqrt_2b: libm::sqrt(2.0 * b),
        })
    }

    /// The wave impedance `b`.
    #[must_use]
    pub fn impedance(&self) -> f64 {
        self.b
    }

    /// `u = (b·ẋ + F)/√(2b)`.
    #[must_use]
    #[inline]
    pub fn forward_wave(&self, velocity: f64, force: f64) -> f64 {
        (self.b * velocity + force) / self.sqrt_2b
    }

    /// `v = (b·ẋ − F)/√(2b)`.
    #[must_use]
    #[inline]
    pub fn backward_wave(&self, velocity: f64, force: f64) -> f64 {
        (self.b * velocity - force) / self.sqrt_2b
    }

    /// The master at velocity `velocity` receives the backward wave `v`:
    /// the force `F = b·ẋ − √(2b)·v` and the wave `u = √(2b)·ẋ − v`.
    ///
    /// # Errors
    /// [`ControlError::NonFiniteInput`] for a NaN or infinite input.
    #[inline]
    pub fn master(&self, velocity: f64, v: f64) -> Result<MasterPort, ControlError> {
        let (x, v) = (finite(velocity)?, finite(v)?);
        Ok(MasterPort {
            force: self.b * x - self.sqrt_2b * v,
            wave: self.sqrt_2b * x - v,
        })
    }

    /// The slave receives the forward wave `u` and meets the force `force`
    /// (its local controller's, on the previous tick): the velocity to
    /// command `ẋ = (√(2b)·u − F)/b` and the wave `v = u − √(2/b)·F`.
    ///
    /// # Errors
    /// [`ControlError::NonFiniteInput`] for a NaN or infinite input.
    #[inline]
    pub fn slave(&self, u: f64, force: f64) -> Result<SlavePort, ControlError> {
        let (u, f) = (finite(u)?, finite(force)?);
        Ok(SlavePort {
            velocity: (self.sqrt_2b * u - f) / self.b,
            wave: u - 2.0 * f / self.sqrt_2b,
        })
    }
}

/// The energy account of a wave channel (both directions): what entered,
/// what left, and the most it ever gave beyond what it received. An empty
/// channel's is the default.
#[derive(Clone, Copy, Debug, Default, PartialEq)]
pub struct WaveEnergy {
    entered: f64,
    left: f64,
    generated: f64,
}

impl WaveEnergy {
    /// A wave entered the channel for `dt` seconds (sent by either side).
    #[inline]
    pub fn sent(&mut self, wave: f64, dt: f64) {
        self.entered += 0.5 * wave * wave * dt;
    }

    /// A wave left the channel for `dt` seconds (decoded by either side).
    #[inline]
    pub fn delivered(&mut self, wave: f64, dt: f64) {
        self.left += 0.5 * wave * wave * dt;
        let deficit = self.left - self.entered;
        if deficit > self.generated {
            self.generated = deficit;
        }
    }

    /// Energy that entered the channel so far.
    #[must_use]
    pub fn entered(&self) -> f64 {
        self.entered
    }

    /// Energy that left it so far.
    #[must_use]
    pub fn left(&self) -> f64 {
        self.left
    }

    /// The most the channel has given beyond what it received, at any
    /// tick: zero for a passive channel.
    #[must_use]
    pub fn generated(&self) -> f64 {
        self.generated
    }
}

#[cfg(test)]
mod tests {
    use std::collections::VecDeque;

    use super::*;

    #[test]
    fn the_waves_carry_the_port_power() {
        let w = WaveTransform::new(3.0).unwrap();
        for (x, f) in [(0.5, 2.0), (-1.0, 0.3), (0.0, -4.0)] {
            let (u, v) = (w.forward_wave(x, f), w.backward_wave(x, f));
            assert!((0.5 * (u * u - v * v) - x * f).abs() < 1e-12);
            // Master: from (ẋ, v) back to (F, u).
            let m = w.master(x, v).unwrap();
            assert!((m.force - f).abs() < 1e-12 && (m.wave - u).abs() < 1e-12);
            // Slave: from (u, F) back to (ẋ, v).
            let s = w.slave(u, f).unwrap();
            assert!((s.velocity - x).abs() < 1e-12 && (s.wave - v).abs() < 1e-12);
        }
    }

    /// Waves through a delay line of `delay` ticks, each delivered once or,
    /// with `repeat`, the last one again when the line has none due.
    fn channel(delay: &dyn Fn(usize) -> usize, repeat: bool) -> WaveEnergy {
        let mut e = WaveEnergy::default();
        let dt = 0.01;
        let mut line: VecDeque<(usize, f64)> = VecDeque::new();
        let mut last = 0.0;
        for k in 0..2000 {
            let wave = libm::sin(k as f64 * 0.05) + 0.3;
            e.sent(wave, dt);
            line.push_back((k + delay(k), wave));
            let mut out = None;
            while line.front().is_some_and(|&(at, _)| at <= k) {
                out = line.pop_front().map(|(_, w)| w);
            }
            match (out, repeat) {
                (Some(w), _) => {
                    last = w;
                    e.delivered(w, dt);
                }
                (None, true) => e.delivered(last, dt),
                (None, false) => {}
            }
            assert!(e.entered() - e.left() >= -1e-12 || repeat);
        }
        e
    }

    #[test]
    fn a_delay_line_is_passive_and_repeats_are_not() {
        let constant = channel(&|_| 7, false);
        assert_eq!(constant.generated(), 0.0);
        assert!(constant.entered() - constant.left() > 0.0);
        // A delay that falls and rises: waves bunch up, then a gap. Each
        // once: passive. The gap filled with repeats: energy from nowhere.
        let varying = |k: usize| if (k / 100).is_multiple_of(2) { 30 } else { 2 };
        assert_eq!(channel(&varying, false).generated(), 0.0);
        assert!(channel(&varying, true).generated() > 0.1);
    }

    #[test]
    fn bad_impedances_and_inputs_are_refused() {
        assert!(WaveTransform::new(0.0).is_err());
        assert!(WaveTransform::new(f64::NAN).is_err());
        let w = WaveTransform::new(1.0).unwrap();
        assert_eq!(w.master(f64::NAN, 0.0), Err(ControlError::NonFiniteInput));
        assert_eq!(
            w.slave(0.0, f64::INFINITY),
            Err(ControlError::NonFiniteInput)
        );
    }
}

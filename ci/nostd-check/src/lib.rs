//! Links every part of ndr-core into a `no_std`, allocator-free static library.
#![no_std]
#![forbid(unsafe_code)]

use ndr_core::endpoint::{Config, Endpoint, Event};
use ndr_core::{Envelope, LowPass};
use ndr_core::Kalman3;
use ndr_core::{NetworkPredictor, PredictorConfig};
use ndr_core::regulator::{Regulator, Tick};
use ndr_core::{InitPattern, Sizing};
use ndr_core::time::{Duration, Instant};
use ndr_core::storage::Inline;
use ndr_core::wire::{self, Frame, Header, MAX_FRAME_LEN, Message, Payload, Role};
use ndr_core::{Arx2, Estimator, Rls, Tf2};

/// Runs one pass of each building block; the result keeps the optimizer honest.
pub extern "C" fn ndr_nostd_exercise(x: f64) -> f64 {
    let t = Duration::from_millis(200);
    let mut acc = 0.0;
    if let Ok(mut r) = Regulator::<f64, 8>::new(2) {
        let _ = r.push(x);
        let _ = r.push(x + 1.0);
        if let Tick::Released(v) = r.tick() {
            acc += v;
        }
    }
    let mut pattern: InitPattern = InitPattern::new();
    let _ = pattern.record_nrtt(Duration::from_secs_f64(x.abs()));
    if let Some(s) = pattern.stats() {
        acc += Sizing::default().nominal_size(s.mt, t) as f64;
    }
    if let (Ok(mut lp), Ok(mut env)) = (LowPass::new(t * 25, t), Envelope::new(1.00005)) {
        acc += lp.update(x).unwrap_or(0.0) + env.update(x).unwrap_or(0.0);
    }
    if let Ok(mut k) = Kalman3::new(1.0, t, 50) {
        acc += k.step(x).unwrap_or(0.0) + k.predict_ahead();
    }
    if let Ok(mut p) = NetworkPredictor::new(PredictorConfig::paper(t)) {
        p.observe_nrtt(t);
        p.observe_gap(t);
        if let Some(pred) = p.step() {
            acc += pred.nrtt_ahead;
        }
    }
    if let Ok(mut rls) = Rls::<4>::new(0.99, 100.0) {
        acc += rls.update(&[x, 1.0, 0.0, -x], 2.0 * x).unwrap_or(0.0);
    }
    if let (Ok(arx), Ok(plant)) = (Arx2::new(0.99, 100.0), Tf2::low_pass(6.0, 0.7, 1.0, 0.01)) {
        acc += plant.dc_gain();
        if let Ok(mut est) = Estimator::<16>::new(3, 4, arx) {
            if let Ok(e) = est.step(x, Some(x)) {
                acc += e.x3e + e.x3p;
            }
        }
    }
    let header = Header {
        term: 0,
        seq: 1,
        sent_at: Instant::from_nanos(7),
        echo: None,
        released: None,
    };
    let mut buf = [0u8; 128];
    if let Ok(n) = wire::encode(&header, &Message::Data(&[x, x]), &mut buf) {
        if let Ok(frame) = Frame::new_checked(&buf[..n]) {
            if let Payload::Data(ch) = frame.payload() {
                acc += ch.iter().sum::<f64>();
            }
        }
    }
    // A base and a remote endpoint in inline storage, wired back to back.
    let config = |role| Config::new(role).with_width(2);
    if let (Ok(mut base), Ok(mut remote)) = (
        Endpoint::<Inline<2, 16>>::new(config(Role::Base), Instant::ZERO),
        Endpoint::<Inline<2, 16>>::new(config(Role::Remote), Instant::ZERO),
    ) {
        let _ = base.set_sample(&[x, x]);
        let mut frame = [0u8; MAX_FRAME_LEN];
        for k in 0..50u64 {
            let now = Instant::from_millis(k * 10);
            base.handle_timeout(now);
            remote.handle_timeout(now);
            while let Ok(Some(n)) = base.poll_transmit(now, &mut frame) {
                let _ = remote.handle_frame(now, &frame[..n]);
            }
            while let Ok(Some(n)) = remote.poll_transmit(now, &mut frame) {
                let _ = base.handle_frame(now, &frame[..n]);
            }
            while let Some(event) = remote.poll_event() {
                if let Event::Released(r) = event {
                    acc += r.values().iter().sum::<f64>();
                }
            }
        }
    }
    acc
}

#[panic_handler]
fn panic(_: &core::panic::PanicInfo<'_>) -> ! {
    loop {}
}

//! Property tests of the NDR queue: FIFO order, and nothing lost without a counter.

#[allow(unused_imports)]
use std::{borrow::ToOwned, boxed::Box, string::String, string::ToString, vec::Vec};
#[allow(unused_imports)]
use std::{eprintln, format, println, vec};

use crate::regulator::{Regulator, Tick};
use proptest::prelude::*;

#[derive(Clone, Debug)]
enum Op {
    Push,
    Tick,
    TickIfDue(u64),
    Discard,
    Resize(usize),
    Restart,
}

fn op() -> impl Strategy<Value = Op> {
    prop_oneof![
        4 => Just(Op::Push),
        4 => Just(Op::Tick),
        1 => (0u64..64).prop_map(Op::TickIfDue),
        1 => Just(Op::Discard),
        1 => (0usize..12).prop_map(Op::Resize),
        1 => Just(Op::Restart),
    ]
}

proptest! {
    #![proptest_config(ProptestConfig::with_cases(2000))]

    #[test]
    fn fifo_and_conservation(ns in 0usize..8, ops in proptest::collection::vec(op(), 0..200)) {
        let mut r: Regulator<u64, 8> = Regulator::new(ns).unwrap();
        let mut next_in = 0u64;
        let mut out = Vec::new(); // released or discarded, in order of leaving
        let mut rejected = Vec::new();
        for op in ops {
            match op {
                Op::Push => {
                    if let Err(full) = r.push(next_in) {
                        prop_assert_eq!(r.len(), 8);
                        rejected.push(full.into_inner());
                    }
                    next_in += 1;
                }
                Op::Tick => match r.tick() {
                    Tick::Released(s) => out.push(s),
                    Tick::Prefilling { have, need } => prop_assert!(have < need && have == r.len()),
                    Tick::Underflow => prop_assert!(r.is_empty()),
                },
                Op::TickIfDue(slot) => {
                    let head = r.front().copied();
                    match r.tick_if(|&s| s <= slot) {
                        Tick::Released(s) => {
                            prop_assert!(s <= slot);
                            prop_assert_eq!(Some(s), head);
                            out.push(s);
                        }
                        Tick::Underflow => prop_assert!(head.is_none_or(|h| h > slot)),
                        Tick::Prefilling { .. } => {}
                    }
                }
                Op::Discard => {
                    if let Some(s) = r.discard_front() {
                        out.push(s);
                    }
                }
                Op::Resize(ns) => {
                    let ok = r.set_nominal(ns).is_ok();
                    prop_assert_eq!(ok, ns < 8);
                }
                Op::Restart => r.restart_prefill(),
            }
            let c = r.counters();
            prop_assert_eq!(c.arrived, c.released + r.len() as u64 + c.rejected + c.discarded);
            prop_assert_eq!(c.arrived, next_in);
        }
        // Everything that left, plus what is held, is every accepted sample, in push order.
        let held: Vec<u64> = r.iter().copied().collect();
        let mut accepted: Vec<u64> = out.clone();
        accepted.extend(held);
        let expected: Vec<u64> = (0..next_in).filter(|s| !rejected.contains(s)).collect();
        prop_assert_eq!(accepted, expected);
        let c = r.counters();
        prop_assert_eq!(c.rejected, rejected.len() as u64);
        if let Some(occ) = r.occupancy() {
            prop_assert!(occ.min <= occ.max && occ.max <= 8);
            prop_assert!(occ.mean >= occ.min as f64 && occ.mean <= occ.max as f64);
        }
    }
}

//! The endpoint's cases on inline storage (arrays, no heap), and what only
//! inline storage does.

#[allow(unused_imports)]
use std::{borrow::ToOwned, boxed::Box, string::String, string::ToString, vec::Vec};
#[allow(unused_imports)]
use std::{eprintln, format, println, vec};

use crate::endpoint::Endpoint;
use crate::storage::Inline;
use crate::time::Instant;
use crate::wire::Role;

type Store = Inline<4, 256>;

// Each storage runs its own copy of the cases, `super::Store` apart.
#[allow(clippy::duplicate_mod)]
#[path = "common/endpoint_cases.rs"]
mod cases;

#[test]
fn an_endpoint_without_adaptive_room_is_smaller_and_refuses_only_the_adaptive_playout() {
    use crate::endpoint::ConfigError;
    use crate::playout::{Builtin, NoAdaptive, NoRoom, Playout};
    type Lean = Endpoint<Inline<4, 16, Builtin<NoAdaptive>>>;
    let mut c = cases::config(Role::Remote);
    c.playout = Playout::ADAPTIVE;
    let refused = Lean::new(c, Instant::ZERO).err();
    assert_eq!(refused, Some(ConfigError::NoRoom(NoRoom::Adaptive)));
    assert!(
        refused
            .unwrap()
            .to_string()
            .contains("default `Adaptive` slot")
    );
    assert!(Endpoint::<Inline<4, 16>>::new(c, Instant::ZERO).is_ok());
    for playout in [
        Playout::Fifo,
        Playout::NetEq,
        Playout::Ramjee1,
        Playout::Ramjee4,
    ] {
        c.playout = playout;
        assert!(Lean::new(c, Instant::ZERO).is_ok(), "{playout}");
    }
    let (lean, full) = (size_of::<Lean>(), size_of::<Endpoint<Inline<4, 16>>>());
    // The histogram's 6.5 KiB and the window's counters, less NetEQ's 2 KiB
    // that the target's room holds anyway.
    assert!(lean + 4 * 1024 <= full, "{lean} {full}");
}

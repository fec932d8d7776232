//! The fingerprint of a link's channel layout.

/// FNV-1a's 64-bit offset basis and prime.
const BASIS: u64 = 0xcbf2_9ce4_8422_2325;
const PRIME: u64 = 0x0000_0100_0000_01b3;

/// The fingerprint of a link's channel layout: what each command and state
/// value means, so that a robot refuses an operator built for another
/// robot, or for another version of this one (docs/wire.md, "Layout").
///
/// The application names its channels; both peers send the fingerprint of
/// those names in their Hello and refuse a peer whose fingerprint differs.
/// `0` means "no layout given", and matches only another `0`.
///
/// ```
/// use ndr_core::fingerprint;
///
/// let arm = fingerprint(
///     &["q1", "q2"],
///     &["q1", "q2", "dq1", "dq2"],
/// );
/// assert_ne!(arm, 0);
/// // The order and the side of each name count.
/// assert_ne!(arm, fingerprint(&["q2", "q1"], &["q1", "q2", "dq1", "dq2"]));
/// assert_ne!(arm, fingerprint(&["q1", "q2", "q1"], &["q2", "dq1", "dq2"]));
/// ```
///
/// It is FNV-1a (64 bits) over each command name's
/// UTF-8 bytes followed by a `0x00`, then a `0x01`, then each state name's
/// bytes followed by a `0x00`; a result of `0` (which means "none") is
/// taken as `1`.
#[must_use]
pub fn fingerprint(commands: &[&str], states: &[&str]) -> u64 {
    let mut h = BASIS;
    let mut eat = |bytes: &[u8]| {
        for &b in bytes {
            h = (h ^ u64::from(b)).wrapping_mul(PRIME);
        }
    };
    for name in commands {
        eat(name.as_bytes());
        eat(&[0]);
    }
    eat(&[1]);
    for name in states {
        eat(name.as_bytes());
        eat(&[0]);
    }
    h.max(1)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn the_fingerprint_is_fnv_1a_over_the_names() {
        // FNV-1a of the single byte 0x01 (no names at all).
        assert_eq!(fingerprint(&[], &[]), 0xaf63_bc4c_8601_b62c);
        // A name's terminator keeps "ab" + "c" apart from "a" + "bc".
        assert_ne!(
            fingerprint(&["ab", "c"], &[]),
            fingerprint(&["a", "bc"], &[])
        );
        assert_ne!(fingerprint(&["x"], &[]), fingerprint(&[], &["x"]));
    }
}

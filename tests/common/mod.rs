//! What every regulated link over loopback must show (shared by the plain
//! and the TLS link tests).

use ndr::net::LinkStats;

/// Both sides' fresh samples came once each and in order, and the base's
/// round trip is constant: at T = 10 ms on loopback with ns = 2, GRTT is
/// 2·ns·T to (2·ns + 2)·T depending on the phase between the two sides'
/// tick grids (a frame read in the same pass as a tick's deadline still
/// counts for that tick); whatever the phase, its std is ≤ 1 ms.
pub fn assert_regulated(base_seqs: &[u64], remote_seqs: &[u64], base: &LinkStats) {
    for (name, seqs) in [("base", base_seqs), ("remote", remote_seqs)] {
        assert!(seqs.len() > 250, "{name}: {}", seqs.len());
        assert!(
            seqs.windows(2).all(|w| w[1] == w[0] + 1),
            "{name}: gap or repeat"
        );
    }
    let grtt = base.endpoint.grtt;
    assert!(grtt.count() > 200, "{grtt:?}");
    assert!(grtt.std() <= 1e-3, "GRTT std {} s: {grtt:?}", grtt.std());
    assert!(
        grtt.mean() >= 0.039 && grtt.mean() <= 0.061,
        "GRTT mean {}",
        grtt.mean()
    );
}

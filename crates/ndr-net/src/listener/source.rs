//! Where connections come from, for the cap on pending handshakes per
//! source that both the TCP accept loop and the QUIC listener apply.

use std::net::IpAddr;

/// An IPv4 address, or an IPv6 /64 (one host may own a whole /64).
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash)]
pub(super) enum Source {
    V4(std::net::Ipv4Addr),
    V6Prefix(u64),
}

impl Source {
    pub(super) fn of(ip: IpAddr) -> Source {
        match ip.to_canonical() {
            IpAddr::V4(v4) => Source::V4(v4),
            IpAddr::V6(v6) => Source::V6Prefix((v6.to_bits() >> 64) as u64),
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn sources_are_addresses_and_ipv6_prefixes() {
        let a: IpAddr = "192.0.2.1".parse().expect("v4");
        let mapped: IpAddr = "::ffff:192.0.2.1".parse().expect("mapped");
        assert_eq!(Source::of(a), Source::of(mapped));
        let (x, y, z): (IpAddr, IpAddr, IpAddr) = (
            "2001:db8:1:2::1".parse().expect("v6"),
            "2001:db8:1:2:ffff::9".parse().expect("v6"),
            "2001:db8:1:3::1".parse().expect("v6"),
        );
        assert_eq!(Source::of(x), Source::of(y));
        assert_ne!(Source::of(x), Source::of(z));
    }
}

//! When bytes arrived: the kernel's receive timestamp where the platform
//! gives one, else the moment the reader got them. The kernel's stamp leaves
//! out the reader's wake-up (tens of µs for a thread that slept a period),
//! which would otherwise count as network delay.

use std::io::{self, Read as _};
use std::os::fd::AsFd;
use std::time::Instant as StdInstant;

use mio::net::TcpStream as MioStream;

/// Asks the kernel to stamp received data; `false` if it will not.
#[cfg(target_os = "linux")]
pub(crate) fn enable(socket: &impl AsFd) -> bool {
    nix::sys::socket::setsockopt(socket, nix::sys::socket::sockopt::ReceiveTimestampns, &true)
        .is_ok()
}

#[cfg(not(target_os = "linux"))]
pub(crate) fn enable(_: &impl AsFd) -> bool {
    false
}

/// Reads what is available into `buf` without blocking, with its
/// arrival time (`WouldBlock` when there is nothing).
pub(crate) fn read_now(
    socket: &MioStream,
    buf: &mut [u8],
    kernel: bool,
) -> io::Result<(usize, StdInstant)> {
    if kernel {
        let (n, stamp) = stamped(socket, buf)?;
        Ok((n, stamp.unwrap_or_else(StdInstant::now)))
    } else {
        let mut reader = socket;
        Ok((reader.read(buf)?, StdInstant::now()))
    }
}

#[cfg(target_os = "linux")]
fn stamped(socket: &MioStream, buf: &mut [u8]) -> io::Result<(usize, Option<StdInstant>)> {
    use std::os::fd::AsRawFd;

    use nix::sys::socket::{ControlMessageOwned, MsgFlags, recvmsg};

    /// Room for one control message (`SCM_TIMESTAMPNS` needs 32 bytes
    /// on 64-bit Linux), aligned as `cmsghdr` wants, on the stack: nix's
    /// `cmsg_space!` would allocate at every read.
    #[repr(C, align(8))]
    struct Control([u8; 64]);

    let mut iov = [io::IoSliceMut::new(buf)];
    let mut cmsg = Control([0; 64]);
    let msg = recvmsg::<()>(
        socket.as_raw_fd(),
        &mut iov,
        Some(&mut cmsg.0),
        MsgFlags::empty(),
    )
    .map_err(io::Error::from)?;
    let kernel = msg.cmsgs().ok().and_then(|mut c| {
        c.find_map(|m| match m {
            ControlMessageOwned::ScmTimestampns(ts) => Some(ts),
            _ => None,
        })
    });
    Ok((msg.bytes, kernel.and_then(kernel_instant)))
}

/// A kernel receive stamp (`SCM_TIMESTAMPNS`, on the wall clock) as an
/// instant on the monotonic clock; `None` if the wall clock cannot vouch
/// for it ([`monotonic`]).
#[cfg(target_os = "linux")]
pub(crate) fn kernel_instant(ts: nix::sys::time::TimeSpec) -> Option<StdInstant> {
    use std::time::{Duration, SystemTime, UNIX_EPOCH};

    let sec = u64::try_from(ts.tv_sec()).ok()?;
    let nsec = u32::try_from(ts.tv_nsec()).ok()?;
    let wall = UNIX_EPOCH + Duration::new(sec, nsec);
    monotonic(wall, SystemTime::now, StdInstant::now)
}

/// A kernel stamp on the wall clock as a monotonic instant: its age on the
/// wall clock, taken from the monotonic clock read right after. The wall
/// clock is read first, so that a thread preempted between the two reads
/// makes the arrival that much later, never earlier: a too early arrival
/// of a frame the peer echoes would let it bound the clocks' offset too
/// high, and take an honest frame for one from the future. A stamp from
/// the future or older than a second means the wall clock moved: `None`,
/// and the reader's own time instead.
#[cfg_attr(not(target_os = "linux"), allow(dead_code))]
fn monotonic(
    stamp: std::time::SystemTime,
    wall: impl FnOnce() -> std::time::SystemTime,
    mono: impl FnOnce() -> StdInstant,
) -> Option<StdInstant> {
    let wall_now = wall();
    let now = mono();
    let age = wall_now.duration_since(stamp).ok()?;
    (age < std::time::Duration::from_secs(1))
        .then(|| now.checked_sub(age))
        .flatten()
}

#[cfg(not(target_os = "linux"))]
fn stamped(socket: &MioStream, buf: &mut [u8]) -> io::Result<(usize, Option<StdInstant>)> {
    let mut reader = socket;
    reader.read(buf).map(|n| (n, None))
}

#[cfg(test)]
mod tests {
    use std::cell::Cell;
    use std::time::{Duration, SystemTime};

    use super::*;

    #[test]
    fn a_reader_preempted_between_its_clock_reads_never_dates_an_arrival_early() {
        // A frame arrived at `arrival`; the reader reads one clock 10 ms
        // later and is preempted 5 ms before it reads the other.
        let base = StdInstant::now();
        let offset = Duration::from_secs(1_000_000);
        let arrival = base + Duration::from_millis(50);
        let stamp = SystemTime::UNIX_EPOCH + offset + Duration::from_millis(50);
        let real = Cell::new(Duration::from_millis(60));
        let tick = |t: &Cell<Duration>| {
            let now = t.get();
            t.set(now + Duration::from_millis(5));
            now
        };
        let wall = || SystemTime::UNIX_EPOCH + offset + tick(&real);
        let mono = || base + tick(&real);
        let got = monotonic(stamp, wall, mono).expect("a fresh stamp");
        assert!(got >= arrival, "{:?} early", arrival - got);
        assert!(got - arrival <= Duration::from_millis(5));
        // Stamps the wall clock cannot vouch for are left to the reader.
        let real = Cell::new(Duration::from_millis(1_100));
        let wall = || SystemTime::UNIX_EPOCH + offset + tick(&real);
        let mono = || base + tick(&real);
        assert_eq!(monotonic(stamp, wall, mono), None);
    }
}

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
    use std::time::{Duration, SystemTime, UNIX_EPOCH};

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
    // The stamp is on the wall clock: turn it into an age, then into a
    // monotonic instant. A stamp from the future or older than a second
    // means the wall clock moved; trust the read time then.
    let stamp = kernel.and_then(|ts| {
        let sec = u64::try_from(ts.tv_sec()).ok()?;
        let nsec = u32::try_from(ts.tv_nsec()).ok()?;
        let wall = UNIX_EPOCH + Duration::new(sec, nsec);
        let (now, wall_now) = (StdInstant::now(), SystemTime::now());
        let age = wall_now.duration_since(wall).ok()?;
        (age < Duration::from_secs(1))
            .then(|| now.checked_sub(age))
            .flatten()
    });
    Ok((msg.bytes, stamp))
}

#[cfg(not(target_os = "linux"))]
fn stamped(socket: &MioStream, buf: &mut [u8]) -> io::Result<(usize, Option<StdInstant>)> {
    let mut reader = socket;
    reader.read(buf).map(|n| (n, None))
}

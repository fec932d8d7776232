//! Real-time scheduling of the hub threads, as robot stacks do it: a
//! `SCHED_FIFO` priority, the process's memory locked, optionally a CPU of
//! its own.
//!
//! On a loaded machine a thread of the default policy waits behind the
//! other runnable threads, and no spin margin shortens that wait: only a
//! real-time policy takes the release clock's tail from the scheduler
//! (docs/guide/realtime.md). Each hub thread therefore asks, as it starts,
//! for what [`Realtime`] says ([`LinkConfig::realtime`](crate::LinkConfig::realtime)):
//!
//! - `SCHED_FIFO` at [`Realtime::priority`] (needs `CAP_SYS_NICE`, or an
//!   `RLIMIT_RTPRIO` at or above the priority);
//! - `mlockall(MCL_CURRENT | MCL_FUTURE | MCL_ONFAULT)`, once per process, so
//!   that a page the link has touched is never paged out (needs
//!   `CAP_IPC_LOCK` or an unlimited `RLIMIT_MEMLOCK`: under a finite limit,
//!   locking future mappings would make allocations fail once the limit is
//!   reached, so it is not tried). `MCL_ONFAULT` locks pages as they are
//!   touched instead of committing every mapping (each thread's whole stack)
//!   at once;
//! - the CPU [`Realtime::cpu`], if set.
//!
//! [`RealtimeMode::Try`] (the default) takes what the host grants and logs
//! one warning per process naming what was refused and how to grant it;
//! the hub then runs as it would without (the default policy).
//! [`RealtimeMode::Enforce`] refuses to start the hub instead
//! ([`RealtimeError`], in [`NetError::Realtime`](crate::NetError::Realtime));
//! [`RealtimeMode::Off`] asks for nothing.

use core::fmt;
use std::io;
use std::str::FromStr;
use std::sync::OnceLock;
use std::sync::atomic::{AtomicBool, Ordering};
use std::sync::mpsc;

use crate::clock::SchedPolicy;

/// The `SCHED_FIFO` priority a hub asks for by default: just under the
/// kernel's threaded interrupt handlers (50 on `PREEMPT_RT` kernels), so that
/// a spinning hub never holds back the network interrupts that bring its
/// frames.
pub const DEFAULT_RT_PRIORITY: u8 = 49;

/// Whether a hub asks for real-time scheduling, and what it does when the
/// host refuses.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, Hash)]
#[non_exhaustive]
pub enum RealtimeMode {
    /// Ask; refuse to start the hub (an error) if anything is refused.
    Enforce,
    /// Ask; on a refusal log one warning and run without what was refused.
    #[default]
    Try,
    /// Ask for nothing: the hub keeps its creator's policy.
    Off,
}

impl RealtimeMode {
    /// The names [`FromStr`] takes.
    pub const NAMES: [&'static str; 3] = ["enforce", "try", "off"];
}

impl fmt::Display for RealtimeMode {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        f.write_str(match self {
            RealtimeMode::Enforce => "enforce",
            RealtimeMode::Try => "try",
            RealtimeMode::Off => "off",
        })
    }
}

impl FromStr for RealtimeMode {
    type Err = RealtimeError;

    fn from_str(s: &str) -> Result<Self, Self::Err> {
        match s.trim().to_ascii_lowercase().as_str() {
            "enforce" => Ok(RealtimeMode::Enforce),
            "try" => Ok(RealtimeMode::Try),
            "off" => Ok(RealtimeMode::Off),
            _ => Err(RealtimeError::BadMode(s.to_owned())),
        }
    }
}

/// The real-time scheduling a hub thread asks for as it starts.
///
/// ```
/// use ndr_net::realtime::{Realtime, RealtimeMode};
///
/// let rt = Realtime::default();
/// assert_eq!(rt.mode, RealtimeMode::Try);
/// let pinned = Realtime::enforce().with_priority(80)?.on_cpu(2);
/// assert_eq!((pinned.priority, pinned.cpu), (80, Some(2)));
/// assert!(Realtime::off().with_priority(0).is_err());
/// # Ok::<(), ndr_net::realtime::RealtimeError>(())
/// ```
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash)]
#[non_exhaustive]
pub struct Realtime {
    /// Whether to ask, and what a refusal does.
    pub mode: RealtimeMode,
    /// The `SCHED_FIFO` priority, 1 to 99 (higher preempts lower).
    pub priority: u8,
    /// The CPU to pin the hub thread to (a [`HubPool`](crate::HubPool): its
    /// first hub; the others on the CPUs after it); `None`: any.
    pub cpu: Option<usize>,
}

impl Default for Realtime {
    fn default() -> Self {
        Realtime {
            mode: RealtimeMode::Try,
            priority: DEFAULT_RT_PRIORITY,
            cpu: None,
        }
    }
}

impl Realtime {
    /// Asks for nothing.
    #[must_use]
    pub fn off() -> Self {
        Realtime {
            mode: RealtimeMode::Off,
            ..Realtime::default()
        }
    }

    /// The default priority, refusing to run without it.
    #[must_use]
    pub fn enforce() -> Self {
        Realtime {
            mode: RealtimeMode::Enforce,
            ..Realtime::default()
        }
    }

    /// The same in `mode`.
    #[must_use]
    pub fn with_mode(self, mode: RealtimeMode) -> Self {
        Realtime { mode, ..self }
    }

    /// The same at `priority`.
    ///
    /// # Errors
    ///
    /// [`RealtimeError::BadPriority`] outside 1 to 99.
    pub fn with_priority(self, priority: u8) -> Result<Self, RealtimeError> {
        if (1..=99).contains(&priority) {
            Ok(Realtime { priority, ..self })
        } else {
            Err(RealtimeError::BadPriority(priority))
        }
    }

    /// The same, pinned to `cpu`.
    #[must_use]
    pub fn on_cpu(self, cpu: usize) -> Self {
        Realtime {
            cpu: Some(cpu),
            ..self
        }
    }

    /// Asks for the same for the calling thread: an application's control
    /// loop, which otherwise wakes from `recv` behind every other runnable
    /// thread of a loaded host. Give it a priority under the hubs'
    /// ([`DEFAULT_RT_PRIORITY`]) so that it never holds a hub back.
    /// Granted or not, the thread runs on under [`RealtimeMode::Try`] (a
    /// refusal logged once per process); whether `SCHED_FIFO` was granted.
    ///
    /// # Errors
    ///
    /// Under [`RealtimeMode::Enforce`], what the host refused, naming the
    /// privilege to grant.
    pub fn enter_current_thread(self) -> Result<bool, RealtimeError> {
        enter(self).map(|g| g.fifo)
    }

    /// The same, pinned `n` CPUs after its own (a pool's `n`-th hub).
    #[must_use]
    pub(crate) fn shifted(self, n: usize) -> Self {
        Realtime {
            cpu: self.cpu.map(|c| c.saturating_add(n)),
            ..self
        }
    }
}

/// What the host refused (or a setting that cannot be asked for), with
/// what to do about it.
#[derive(Clone, Debug, PartialEq, Eq)]
#[non_exhaustive]
pub enum RealtimeError {
    /// Not `enforce`, `try` or `off`.
    BadMode(String),
    /// A `SCHED_FIFO` priority outside 1 to 99.
    BadPriority(u8),
    /// `SCHED_FIFO` at this priority was refused.
    Priority {
        /// The priority asked for.
        priority: u8,
        /// The process's `RLIMIT_RTPRIO` (`None`: unlimited).
        rtprio_limit: Option<u64>,
        /// What the kernel said.
        reason: String,
    },
    /// Locking the process's memory was refused (or not tried under a
    /// finite `RLIMIT_MEMLOCK` without `CAP_IPC_LOCK`).
    MemoryLock {
        /// The process's `RLIMIT_MEMLOCK` in bytes (`None`: unlimited).
        memlock_limit: Option<u64>,
        /// What the kernel said, if it was asked.
        reason: Option<String>,
    },
    /// Pinning to this CPU was refused (no such CPU, or not in the
    /// process's allowed set).
    Cpu {
        /// The CPU asked for.
        cpu: usize,
        /// What the kernel said.
        reason: String,
    },
    /// Several of the above.
    Several(Vec<RealtimeError>),
}

impl fmt::Display for RealtimeError {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        match self {
            RealtimeError::BadMode(s) => {
                write!(f, "real-time mode {s:?}: expected enforce, try or off")
            }
            RealtimeError::BadPriority(p) => write!(
                f,
                "real-time priority {p}: SCHED_FIFO priorities are 1 to 99"
            ),
            RealtimeError::Priority {
                priority,
                rtprio_limit,
                reason,
            } => {
                let limit = rtprio_limit.map_or_else(|| "unlimited".to_owned(), |l| l.to_string());
                write!(
                    f,
                    "SCHED_FIFO at priority {priority} refused ({reason}): the process lacks \
                     CAP_SYS_NICE and its RLIMIT_RTPRIO is {limit}; grant it with \
                     `sudo setcap cap_sys_nice+ep <binary>`, or raise the limit \
                     (`@group - rtprio {priority}` in /etc/security/limits.conf, \
                     `LimitRTPRIO={priority}` in a systemd unit, `ulimit -r {priority}` as root), \
                     or run as root"
                )
            }
            RealtimeError::MemoryLock {
                memlock_limit,
                reason,
            } => {
                let limit = memlock_limit
                    .map_or_else(|| "unlimited".to_owned(), |l| format!("{} KiB", l / 1024));
                write!(f, "memory lock (mlockall) ")?;
                match reason {
                    Some(r) => write!(f, "refused ({r})")?,
                    None => write!(f, "not tried")?,
                }
                write!(
                    f,
                    ": the process lacks CAP_IPC_LOCK and its RLIMIT_MEMLOCK is {limit}; grant it \
                     with `sudo setcap cap_ipc_lock+ep <binary>`, or lift the limit \
                     (`@group - memlock unlimited` in /etc/security/limits.conf, \
                     `LimitMEMLOCK=infinity` in a systemd unit, `ulimit -l unlimited` as root)"
                )
            }
            RealtimeError::Cpu { cpu, reason } => write!(
                f,
                "pinning to CPU {cpu} refused ({reason}): name a CPU the process may run on \
                 (`taskset -p $$` shows them) or none"
            ),
            RealtimeError::Several(all) => {
                for (i, e) in all.iter().enumerate() {
                    if i > 0 {
                        f.write_str("; ")?;
                    }
                    write!(f, "{e}")?;
                }
                Ok(())
            }
        }
    }
}

impl std::error::Error for RealtimeError {}

impl From<RealtimeError> for io::Error {
    /// An [`io::ErrorKind::PermissionDenied`] holding the error (a
    /// [`NetError`](crate::NetError) made from it is
    /// [`NetError::Realtime`](crate::NetError::Realtime) again).
    fn from(e: RealtimeError) -> Self {
        let kind = match e {
            RealtimeError::BadMode(_) | RealtimeError::BadPriority(_) => {
                io::ErrorKind::InvalidInput
            }
            _ => io::ErrorKind::PermissionDenied,
        };
        io::Error::new(kind, e)
    }
}

/// What a hub thread was granted.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub(crate) struct Granted {
    pub(crate) fifo: bool,
    pub(crate) memory_locked: bool,
    pub(crate) cpu: Option<usize>,
}

/// Starts a thread named `name` that enters `rt` and then runs `body`;
/// returns once it has entered. Under [`RealtimeMode::Enforce`] a refusal is
/// the error and `body` does not run.
pub(crate) fn spawn(
    name: &str,
    stack_size: usize,
    rt: Realtime,
    body: impl FnOnce() + Send + 'static,
) -> io::Result<()> {
    let (tx, rx) = mpsc::sync_channel(1);
    std::thread::Builder::new()
        .name(name.to_owned())
        .stack_size(stack_size)
        .spawn(move || {
            let entered = enter(rt);
            let run = entered.is_ok();
            let _ = tx.send(entered);
            if run {
                body();
            }
        })?;
    match rx.recv() {
        Ok(Ok(_)) => Ok(()),
        Ok(Err(e)) => Err(e.into()),
        Err(_) => Err(io::Error::other(format!(
            "the {name} thread ended before it started"
        ))),
    }
}

/// Asks for `rt` for the calling thread. `Err` only under
/// [`RealtimeMode::Enforce`]; under [`RealtimeMode::Try`] what is refused is
/// logged once per process.
pub(crate) fn enter(rt: Realtime) -> Result<Granted, RealtimeError> {
    if rt.mode == RealtimeMode::Off {
        return Ok(Granted::default());
    }
    let mut granted = Granted::default();
    let mut refused = Vec::new();
    match lock_memory() {
        Ok(()) => granted.memory_locked = true,
        Err(e) => refused.push(e.clone()),
    }
    match set_fifo(rt.priority) {
        Ok(()) => granted.fifo = true,
        Err(e) => refused.push(e),
    }
    if let Some(cpu) = rt.cpu {
        match pin(cpu) {
            Ok(()) => granted.cpu = Some(cpu),
            Err(e) => refused.push(e),
        }
    }
    let error = match refused.len() {
        0 => return Ok(granted),
        1 => refused.swap_remove(0),
        _ => RealtimeError::Several(refused),
    };
    if rt.mode == RealtimeMode::Enforce {
        return Err(error);
    }
    warn_once(&error);
    Ok(granted)
}

/// One warning per process: every hub meets the same refusal.
fn warn_once(error: &RealtimeError) {
    static WARNED: AtomicBool = AtomicBool::new(false);
    if !WARNED.swap(true, Ordering::Relaxed) {
        tracing::warn!(
            "real-time scheduling (--realtime try, the default) not fully granted, so the \
             hub threads run under the default policy where refused and a loaded machine \
             delays their releases: {error}; --realtime off (Python: realtime=\"off\") \
             silences this, --realtime enforce makes it an error"
        );
    }
}

#[cfg(target_os = "linux")]
fn set_fifo(priority: u8) -> Result<(), RealtimeError> {
    use thread_priority::{
        RealtimeThreadSchedulePolicy, ThreadPriority, ThreadPriorityValue, ThreadSchedulePolicy,
    };
    let refused = |reason: String| RealtimeError::Priority {
        priority,
        rtprio_limit: rustix::process::getrlimit(rustix::process::Resource::Rtprio).current,
        reason,
    };
    let value = ThreadPriorityValue::try_from(priority)
        .map_err(|_| RealtimeError::BadPriority(priority))?;
    thread_priority::set_thread_priority_and_policy(
        thread_priority::thread_native_id(),
        ThreadPriority::Crossplatform(value),
        ThreadSchedulePolicy::Realtime(RealtimeThreadSchedulePolicy::Fifo),
    )
    .map_err(|e| match e {
        thread_priority::Error::OS(code) => refused(io::Error::from_raw_os_error(code).to_string()),
        thread_priority::Error::PriorityNotInRange(_) => RealtimeError::BadPriority(priority),
        other => refused(other.to_string()),
    })
}

#[cfg(target_os = "linux")]
fn lock_memory() -> Result<(), RealtimeError> {
    use rustix::mm::{MlockAllFlags, mlockall};
    use rustix::process::{Resource, getrlimit};
    use rustix::thread::{CapabilitySet, capabilities};
    static LOCKED: OnceLock<Result<(), RealtimeError>> = OnceLock::new();
    LOCKED
        .get_or_init(|| {
            let limit = getrlimit(Resource::Memlock).current;
            let may =
                capabilities(None).is_ok_and(|c| c.effective.contains(CapabilitySet::IPC_LOCK));
            if !may && limit.is_some() {
                return Err(RealtimeError::MemoryLock {
                    memlock_limit: limit,
                    reason: None,
                });
            }
            mlockall(MlockAllFlags::CURRENT | MlockAllFlags::FUTURE | MlockAllFlags::ONFAULT)
                .map_err(|e| RealtimeError::MemoryLock {
                    memlock_limit: limit,
                    reason: Some(io::Error::from(e).to_string()),
                })
        })
        .clone()
}

#[cfg(target_os = "linux")]
fn pin(cpu: usize) -> Result<(), RealtimeError> {
    use rustix::thread::{CpuSet, sched_setaffinity};
    if cpu >= CpuSet::MAX_CPU {
        return Err(RealtimeError::Cpu {
            cpu,
            reason: format!("CPUs are numbered below {}", CpuSet::MAX_CPU),
        });
    }
    let mut set = CpuSet::new();
    set.set(cpu);
    sched_setaffinity(None, &set).map_err(|e| RealtimeError::Cpu {
        cpu,
        reason: io::Error::from(e).to_string(),
    })
}

#[cfg(not(target_os = "linux"))]
fn set_fifo(priority: u8) -> Result<(), RealtimeError> {
    Err(RealtimeError::Priority {
        priority,
        rtprio_limit: None,
        reason: "not supported on this platform".to_owned(),
    })
}

#[cfg(not(target_os = "linux"))]
fn lock_memory() -> Result<(), RealtimeError> {
    Err(RealtimeError::MemoryLock {
        memlock_limit: None,
        reason: Some("not supported on this platform".to_owned()),
    })
}

#[cfg(not(target_os = "linux"))]
fn pin(cpu: usize) -> Result<(), RealtimeError> {
    Err(RealtimeError::Cpu {
        cpu,
        reason: "not supported on this platform".to_owned(),
    })
}

/// The scheduling policy of each of this process's threads named `name`
/// (`ndr-hub` for the hubs), read from `/proc/self/task` (Linux only).
///
/// # Errors
///
/// `/proc/self/task` cannot be read.
pub fn thread_policies(name: &str) -> io::Result<Vec<SchedPolicy>> {
    let mut policies = Vec::new();
    for task in std::fs::read_dir("/proc/self/task")?.flatten() {
        let path = task.path();
        let named = std::fs::read_to_string(path.join("comm")).is_ok_and(|n| n.trim() == name);
        if !named {
            continue;
        }
        // The thread may have ended since the listing.
        if let Some(policy) = std::fs::read_to_string(path.join("stat"))
            .ok()
            .and_then(|s| crate::clock::parse_policy(&s))
        {
            policies.push(policy);
        }
    }
    Ok(policies)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn modes_parse_and_print() {
        for name in RealtimeMode::NAMES {
            let mode: RealtimeMode = name.parse().expect("a mode");
            assert_eq!(mode.to_string(), name);
        }
        assert_eq!(" Try ".parse::<RealtimeMode>(), Ok(RealtimeMode::Try));
        let bad = "fifo".parse::<RealtimeMode>().expect_err("not a mode");
        assert!(bad.to_string().contains("enforce, try or off"), "{bad}");
    }

    #[test]
    fn priorities_outside_fifo_range_are_refused() {
        assert_eq!(
            Realtime::default().with_priority(0),
            Err(RealtimeError::BadPriority(0))
        );
        assert_eq!(
            Realtime::default().with_priority(100),
            Err(RealtimeError::BadPriority(100))
        );
        assert_eq!(
            Realtime::default().with_priority(99).map(|r| r.priority),
            Ok(99)
        );
    }

    #[test]
    fn refusals_say_what_to_grant() {
        let fifo = RealtimeError::Priority {
            priority: 49,
            rtprio_limit: Some(0),
            reason: "Operation not permitted".to_owned(),
        }
        .to_string();
        for needle in [
            "CAP_SYS_NICE",
            "RLIMIT_RTPRIO is 0",
            "setcap cap_sys_nice+ep",
            "rtprio 49",
            "ulimit -r",
        ] {
            assert!(fifo.contains(needle), "{needle} in {fifo}");
        }
        let memory = RealtimeError::MemoryLock {
            memlock_limit: Some(8 << 20),
            reason: None,
        }
        .to_string();
        for needle in [
            "CAP_IPC_LOCK",
            "RLIMIT_MEMLOCK is 8192 KiB",
            "not tried",
            "ulimit -l",
        ] {
            assert!(memory.contains(needle), "{needle} in {memory}");
        }
        let io: io::Error = RealtimeError::BadPriority(0).into();
        assert_eq!(io.kind(), io::ErrorKind::InvalidInput);
    }

    #[test]
    fn off_asks_for_nothing() {
        let granted = std::thread::spawn(|| {
            let before = crate::clock::current_thread_policy().expect("a policy");
            let granted = enter(Realtime::off()).expect("nothing to refuse");
            (
                granted,
                before,
                crate::clock::current_thread_policy().expect("a policy"),
            )
        })
        .join()
        .expect("the thread");
        assert_eq!(granted.0, Granted::default());
        assert_eq!(granted.1, granted.2);
    }

    #[test]
    fn a_cpu_past_the_set_is_refused_under_enforce_and_tolerated_under_try() {
        let rt = Realtime::off()
            .with_mode(RealtimeMode::Enforce)
            .on_cpu(usize::MAX / 2);
        // In a thread of its own: what it is granted must not leak into the
        // test harness's threads.
        let (enforced, tried) = std::thread::spawn(move || {
            let enforced = enter(rt);
            let tried = enter(rt.with_mode(RealtimeMode::Try));
            (enforced, tried)
        })
        .join()
        .expect("the thread");
        let e = enforced.expect_err("no such CPU");
        assert!(e.to_string().contains("pinning to CPU"), "{e}");
        assert_eq!(tried.map(|g| g.cpu), Ok(None));
    }

    /// Runs `f` on a thread without `CAP_SYS_NICE` (a thread's capabilities
    /// are its own, and the threads it starts inherit them); `None` if its
    /// limit would grant `SCHED_FIFO` anyway. It keeps `CAP_IPC_LOCK`: once
    /// another test has locked the process's memory for the future, a thread
    /// without it could not map a stack beyond `RLIMIT_MEMLOCK`.
    fn unprivileged<T: Send + 'static>(f: impl FnOnce() -> T + Send + 'static) -> Option<T> {
        use rustix::process::{Resource, getrlimit};
        use rustix::thread::{CapabilitySet, capabilities, set_capabilities};
        if getrlimit(Resource::Rtprio).current.is_none_or(|l| l >= 99) {
            return None;
        }
        std::thread::spawn(move || {
            let mut caps = capabilities(None).expect("the thread's capabilities");
            caps.effective.remove(CapabilitySet::SYS_NICE);
            set_capabilities(None, caps).expect("dropping capabilities");
            f()
        })
        .join()
        .ok()
    }

    #[test]
    fn a_hub_refused_fifo_under_enforce_is_a_realtime_error() {
        let Some(started) = unprivileged(|| {
            let rt = Realtime::enforce().with_priority(99).expect("a priority");
            crate::Hub::with_realtime(crate::clock::DEFAULT_SPIN_MARGIN, rt).map(|_| ())
        }) else {
            return;
        };
        let e = crate::NetError::from(started.expect_err("refused"));
        let crate::NetError::Realtime(rt) = &e else {
            panic!("not a real-time error: {e}");
        };
        let refused_fifo =
            |e: &RealtimeError| matches!(e, RealtimeError::Priority { priority: 99, .. });
        let named = match rt {
            RealtimeError::Several(all) => all.iter().any(refused_fifo),
            one => refused_fifo(one),
        };
        assert!(named, "{e}");
        assert!(e.to_string().contains("CAP_SYS_NICE"), "{e}");
    }

    #[test]
    fn try_runs_on_under_the_default_policy_when_refused() {
        let Some((granted, policy)) = unprivileged(|| {
            let granted = enter(Realtime::default());
            (granted, crate::clock::current_thread_policy())
        }) else {
            return;
        };
        assert!(!granted.expect("try never fails").fifo);
        assert!(!policy.expect("a policy").is_realtime());
    }

    #[test]
    fn a_privileged_thread_gets_fifo_at_its_priority() {
        use rustix::thread::{CapabilitySet, capabilities};
        if !capabilities(None).is_ok_and(|c| c.effective.contains(CapabilitySet::SYS_NICE)) {
            return;
        }
        let (granted, policy) = std::thread::spawn(|| {
            let rt = Realtime::enforce().with_priority(10).expect("a priority");
            (enter(rt), crate::clock::current_thread_policy())
        })
        .join()
        .expect("the thread");
        assert!(granted.expect("granted").fifo);
        assert_eq!(policy.expect("a policy"), SchedPolicy::Fifo(10));
    }
}

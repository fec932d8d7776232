//! The I/O runtime the links of one process run on.

/// The runtime of the links' I/O.
pub fn runtime() -> Result<tokio::runtime::Runtime, String> {
    tokio::runtime::Builder::new_multi_thread()
        .worker_threads(2)
        .thread_name("ndr-io")
        .enable_all()
        .build()
        .map_err(|e| format!("cannot start the I/O runtime: {e}"))
}

/// [`runtime`] whose threads ask for `rt` as they start (`ndr demo`'s
/// relay, which stands for the network).
pub fn runtime_under(rt: ndr::net::Realtime) -> Result<tokio::runtime::Runtime, String> {
    tokio::runtime::Builder::new_multi_thread()
        .worker_threads(2)
        .thread_name("ndr-io")
        .on_thread_start(move || {
            // Refused: warned once, and the thread runs on without.
            let _ = rt.enter_current_thread();
        })
        .enable_all()
        .build()
        .map_err(|e| format!("cannot start the I/O runtime: {e}"))
}

//! `--metrics`: the Prometheus page of a command's links, served over
//! HTTP/1 by hyper on a thread of its own (a single-threaded runtime), so
//! that a scrape competes neither with the links' I/O runtime nor with a
//! hub: it reads the snapshots the hubs publish ([`Metrics`]).

use std::convert::Infallible;
use std::net::SocketAddr;

use http_body_util::Full;
use hyper::body::{Bytes, Incoming};
use hyper::server::conn::http1;
use hyper::service::service_fn;
use hyper::{Method, Request, Response, StatusCode};
use hyper_util::rt::TokioIo;
use ndr::core::wire::Role;
use ndr::net::metrics::{CONTENT_TYPE, LinkLabels, Metrics, WatchId};
use ndr::net::{LinkSender, Transport};

use crate::args::MetricsArgs;

/// What a command's `--metrics` serves: nothing without the flag.
pub struct Served {
    metrics: Option<Metrics>,
}

impl Served {
    /// Starts serving if `--metrics` was given, and says where on stderr
    /// (`command` names the command in that line).
    pub fn start(args: &MetricsArgs, command: &str) -> Result<Served, String> {
        let Some(addr) = args.address()? else {
            return Ok(Served { metrics: None });
        };
        let metrics = Metrics::new();
        let bound = serve(addr, metrics.clone())?;
        eprintln!("ndr {command}: metrics at http://{bound}/metrics");
        Ok(Served {
            metrics: Some(metrics),
        })
    }

    /// Shows a link's figures from now on.
    pub fn watch_link(
        &self,
        peer: SocketAddr,
        role: Role,
        transport: Transport,
        link: &LinkSender,
    ) -> Option<WatchId> {
        let m = self.metrics.as_ref()?;
        Some(m.watch_link(LinkLabels::new(peer.to_string(), role, transport), link))
    }

    /// The watched set itself, for what else a command shows (a listener).
    pub fn metrics(&self) -> Option<&Metrics> {
        self.metrics.as_ref()
    }

    /// Stops showing a link or listener.
    pub fn unwatch(&self, id: Option<WatchId>) {
        if let (Some(m), Some(id)) = (&self.metrics, id) {
            m.unwatch(id);
        }
    }
}

/// Binds `addr` now (an error says so at once) and serves `metrics` on a
/// thread of its own until the process ends; returns the bound address.
fn serve(addr: SocketAddr, metrics: Metrics) -> Result<SocketAddr, String> {
    let listener = std::net::TcpListener::bind(addr)
        .and_then(|l| l.set_nonblocking(true).map(|()| l))
        .map_err(|e| format!("--metrics {addr}: cannot listen there: {e}"))?;
    let bound = listener
        .local_addr()
        .map_err(|e| format!("--metrics {addr}: {e}"))?;
    let rt = tokio::runtime::Builder::new_current_thread()
        .enable_all()
        .build()
        .map_err(|e| format!("--metrics: cannot start its runtime: {e}"))?;
    std::thread::Builder::new()
        .name("ndr-metrics".into())
        .spawn(move || rt.block_on(accept(listener, metrics)))
        .map_err(|e| format!("--metrics: cannot start its thread: {e}"))?;
    Ok(bound)
}

async fn accept(listener: std::net::TcpListener, metrics: Metrics) {
    let listener = match tokio::net::TcpListener::from_std(listener) {
        Ok(l) => l,
        Err(e) => {
            tracing::error!("--metrics: cannot serve: {e}");
            return;
        }
    };
    loop {
        let stream = match listener.accept().await {
            Ok((stream, _)) => stream,
            Err(e) => {
                // Out of file descriptors, say: the next accept may do.
                tracing::warn!("--metrics: accept failed: {e}");
                tokio::time::sleep(std::time::Duration::from_millis(100)).await;
                continue;
            }
        };
        let metrics = metrics.clone();
        tokio::spawn(async move {
            let service = service_fn(move |req| page(req, metrics.clone()));
            if let Err(e) = http1::Builder::new()
                .serve_connection(TokioIo::new(stream), service)
                .await
            {
                tracing::debug!("--metrics: a connection failed: {e}");
            }
        });
    }
}

/// `GET /metrics`: the page; anything else a short error.
async fn page(
    req: Request<Incoming>,
    metrics: Metrics,
) -> Result<Response<Full<Bytes>>, Infallible> {
    let reply = |status, content_type, body: String| {
        let mut r = Response::new(Full::new(Bytes::from(body)));
        *r.status_mut() = status;
        if let Ok(v) = hyper::header::HeaderValue::from_str(content_type) {
            r.headers_mut().insert(hyper::header::CONTENT_TYPE, v);
        }
        Ok(r)
    };
    if req.uri().path() != "/metrics" {
        return reply(
            StatusCode::NOT_FOUND,
            "text/plain",
            "not found: the metrics are at /metrics\n".into(),
        );
    }
    if req.method() != Method::GET && req.method() != Method::HEAD {
        return reply(
            StatusCode::METHOD_NOT_ALLOWED,
            "text/plain",
            "GET /metrics\n".into(),
        );
    }
    reply(StatusCode::OK, CONTENT_TYPE, metrics.encode())
}

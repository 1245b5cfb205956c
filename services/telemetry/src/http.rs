//! The HTTP side of a vint process: `/metrics` (the process's Prometheus registry in the
//! OpenMetrics text format, which Prometheus scrapes natively) and `/healthz` (200 `ok`, or 503
//! with the reason, from the process's own `HealthCheck`).
//!
//! It runs on the axum that tonic already builds on, so a process compiles one HTTP stack. A
//! process may add its own routes to the `Router` before serving it, and serve it as plain HTTP
//! (`serve_http`) or HTTPS (`serve_https`, rustls), within `ListenerLimits` (connections at once,
//! handshake and header-read timeouts). Nothing here authenticates: bind it where only the cluster
//! (Prometheus, probes) can reach it, or put the process's own checks on its routes.

use std::future::Future;
use std::sync::Arc;
use std::sync::atomic::{AtomicU64, Ordering};
use std::time::{Duration, Instant};

use axum::Router;
use axum::http::{StatusCode, header};
use axum::response::{IntoResponse, Response};
use axum::routing::get;
use prometheus_client::registry::Registry;
use tokio::net::TcpListener;

/// The content type of `/metrics`: the OpenMetrics text that prometheus-client writes.
pub const OPENMETRICS_CONTENT_TYPE: &str = "application/openmetrics-text; version=1.0.0; charset=utf-8";

/// What a health check found: healthy, or why not (the body of the 503).
pub type Health = Result<(), String>;

/// How a process judges its own health, asked on every `/healthz` request. A check must answer
/// quickly (a probe times out): bound any I/O it does.
pub trait HealthCheck: Clone + Send + Sync + 'static {
    fn check(&self) -> impl Future<Output = Health> + Send;
}

/// The routes every vint process serves: `/metrics` from `registry`, `/healthz` from `health`.
pub fn router(registry: Arc<Registry>, health: impl HealthCheck) -> Router {
    Router::new()
        .route("/metrics", get(move || metrics(registry.clone())))
        .route("/healthz", get(move || healthz(health.clone())))
}

/// The TLS configuration `serve_https` serves with: a PEM certificate chain (the server's first)
/// and its PEM private key; an error names the file and what is wrong with it.
pub fn tls_server_config(
    cert_path: &std::path::Path,
    key_path: &std::path::Path,
) -> Result<Arc<rustls::ServerConfig>, String> {
    use rustls::pki_types::pem::PemObject;
    use rustls::pki_types::{CertificateDer, PrivateKeyDer};
    let certs = CertificateDer::pem_file_iter(cert_path)
        .and_then(|certs| certs.collect::<Result<Vec<_>, _>>())
        .map_err(|e| format!("{}: not a PEM certificate chain: {e}", cert_path.display()))?;
    let key = PrivateKeyDer::from_pem_file(key_path)
        .map_err(|e| format!("{}: not a PEM private key: {e}", key_path.display()))?;
    let provider = Arc::new(rustls::crypto::aws_lc_rs::default_provider());
    let mut config = rustls::ServerConfig::builder_with_provider(provider)
        .with_safe_default_protocol_versions()
        .and_then(|b| b.with_no_client_auth().with_single_cert(certs, key))
        .map_err(|e| format!("{} with {}: {e}", cert_path.display(), key_path.display()))?;
    config.alpn_protocols = vec![b"http/1.1".to_vec()];
    Ok(Arc::new(config))
}

/// What one HTTP listener allows a client, so that slow or many clients (a slowloris) cannot hold
/// the process's connections or memory: connections open at once (one past it is closed at once),
/// how long a TLS handshake may take, and how long a request's headers may take to arrive (also
/// how long an idle kept-alive connection stays open).
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct ListenerLimits {
    pub max_connections: usize,
    pub handshake_timeout: Duration,
    pub header_read_timeout: Duration,
}

impl Default for ListenerLimits {
    /// 256 connections (Prometheus, probes and a few dashboards need a handful), 10 s for a
    /// handshake and for a request's headers.
    fn default() -> Self {
        ListenerLimits {
            max_connections: 256,
            handshake_timeout: Duration::from_secs(10),
            header_read_timeout: Duration::from_secs(10),
        }
    }
}

/// Serves `router` over HTTPS (HTTP/1.1 in TLS with `tls`) on `listener` until `shutdown`
/// resolves, within `ListenerLimits::default()`. A client that fails its handshake is dropped;
/// the others are not disturbed.
pub async fn serve_https(
    listener: TcpListener,
    router: Router,
    tls: Arc<rustls::ServerConfig>,
    shutdown: impl Future<Output = ()> + Send + 'static,
) -> std::io::Result<()> {
    serve(listener, router, Some(tls), ListenerLimits::default(), shutdown).await
}

/// Serves `router` on `listener` (plain HTTP/1.1) until `shutdown` resolves, within
/// `ListenerLimits::default()`.
pub async fn serve_http(
    listener: TcpListener,
    router: Router,
    shutdown: impl Future<Output = ()> + Send + 'static,
) -> std::io::Result<()> {
    serve(listener, router, None, ListenerLimits::default(), shutdown).await
}

/// Serves `router` on `listener`, in TLS when `tls` is given, within `limits`, until `shutdown`
/// resolves (connections already open finish on their own).
pub async fn serve(
    listener: TcpListener,
    router: Router,
    tls: Option<Arc<rustls::ServerConfig>>,
    limits: ListenerLimits,
    shutdown: impl Future<Output = ()> + Send + 'static,
) -> std::io::Result<()> {
    let acceptor = tls.map(tokio_rustls::TlsAcceptor::from);
    let open = Arc::new(tokio::sync::Semaphore::new(limits.max_connections));
    tokio::pin!(shutdown);
    loop {
        let (stream, peer) = tokio::select! {
            () = &mut shutdown => return Ok(()),
            accepted = listener.accept() => match accepted {
                Ok(accepted) => accepted,
                Err(e) => {
                    tracing::warn!(error = %e, "accepting an HTTP connection failed");
                    continue;
                }
            },
        };
        let Ok(permit) = open.clone().try_acquire_owned() else {
            tracing::warn!(%peer, max = limits.max_connections, "HTTP connection closed: the listener is at its connection limit");
            drop(stream);
            continue;
        };
        let (acceptor, router) = (acceptor.clone(), router.clone());
        tokio::spawn(async move {
            let _permit = permit;
            match acceptor {
                None => serve_connection(stream, router, limits, peer).await,
                Some(acceptor) => match tokio::time::timeout(limits.handshake_timeout, acceptor.accept(stream)).await {
                    Ok(Ok(stream)) => serve_connection(stream, router, limits, peer).await,
                    Ok(Err(e)) => tracing::debug!(%peer, error = %e, "TLS handshake failed"),
                    Err(_) => tracing::debug!(%peer, "TLS handshake timed out"),
                },
            }
        });
    }
}

/// One connection's requests, each one's headers within `limits.header_read_timeout`.
async fn serve_connection<S>(stream: S, router: Router, limits: ListenerLimits, peer: std::net::SocketAddr)
where
    S: tokio::io::AsyncRead + tokio::io::AsyncWrite + Unpin + Send + 'static,
{
    let service = hyper_util::service::TowerToHyperService::new(router);
    let served = hyper::server::conn::http1::Builder::new()
        .timer(hyper_util::rt::TokioTimer::new())
        .header_read_timeout(limits.header_read_timeout)
        .serve_connection(hyper_util::rt::TokioIo::new(stream), service)
        .await;
    if let Err(e) = served {
        tracing::debug!(%peer, error = %e, "HTTP connection ended with an error");
    }
}

async fn metrics(registry: Arc<Registry>) -> Response {
    let mut body = String::new();
    match prometheus_client::encoding::text::encode(&mut body, &registry) {
        Ok(()) => ([(header::CONTENT_TYPE, OPENMETRICS_CONTENT_TYPE)], body).into_response(),
        Err(e) => (StatusCode::INTERNAL_SERVER_ERROR, format!("encoding the metrics failed: {e}\n")).into_response(),
    }
}

async fn healthz(health: impl HealthCheck) -> Response {
    match health.check().await {
        Ok(()) => (StatusCode::OK, "ok\n").into_response(),
        Err(why) => (StatusCode::SERVICE_UNAVAILABLE, format!("{why}\n")).into_response(),
    }
}

/// Health of a loop that should come around regularly: healthy while its last `beat` is at most
/// `stale_after` old. A loop that is stuck (not merely idle or waiting on a slow peer, which
/// still beat) reads as unhealthy, so an orchestrator restarts the process.
#[derive(Clone, Debug)]
pub struct Liveness {
    what: &'static str,
    started: Instant,
    /// Milliseconds after `started` of the last beat.
    last_beat_ms: Arc<AtomicU64>,
    stale_after: Duration,
}

impl Liveness {
    /// A liveness for the loop named `what`, counted as having beaten now.
    pub fn new(what: &'static str, stale_after: Duration) -> Liveness {
        Liveness { what, started: Instant::now(), last_beat_ms: Arc::default(), stale_after }
    }

    /// The loop came around.
    pub fn beat(&self) {
        let now = u64::try_from(self.started.elapsed().as_millis()).unwrap_or(u64::MAX);
        self.last_beat_ms.fetch_max(now, Ordering::Relaxed);
    }

    /// How long ago the loop last came around.
    pub fn since_last_beat(&self) -> Duration {
        let last = Duration::from_millis(self.last_beat_ms.load(Ordering::Relaxed));
        self.started.elapsed().saturating_sub(last)
    }
}

impl HealthCheck for Liveness {
    async fn check(&self) -> Health {
        let since = self.since_last_beat();
        if since <= self.stale_after {
            Ok(())
        } else {
            Err(format!(
                "the {} last ran {:.1} s ago (limit {:.1} s)",
                self.what,
                since.as_secs_f64(),
                self.stale_after.as_secs_f64()
            ))
        }
    }
}

#[cfg(test)]
mod tests {
    use prometheus_client::metrics::counter::Counter;
    use prometheus_client::metrics::family::Family;
    use prometheus_client::metrics::gauge::Gauge;
    use prometheus_client::metrics::histogram::Histogram;
    use tokio::io::{AsyncReadExt, AsyncWriteExt};

    use super::*;

    /// A check that answers what it was built with.
    #[derive(Clone)]
    struct Fixed(Health);

    impl HealthCheck for Fixed {
        async fn check(&self) -> Health {
            self.0.clone()
        }
    }

    /// Serves `router` on a free port; returns its address.
    async fn serve(router: Router) -> std::net::SocketAddr {
        let listener = TcpListener::bind("127.0.0.1:0").await.unwrap();
        let addr = listener.local_addr().unwrap();
        tokio::spawn(serve_http(listener, router, std::future::pending()));
        addr
    }

    /// A plain HTTP/1.0 GET: status, content type, body.
    async fn get(addr: std::net::SocketAddr, path: &str) -> (u16, String, String) {
        let mut stream = tokio::net::TcpStream::connect(addr).await.unwrap();
        stream.write_all(format!("GET {path} HTTP/1.0\r\nHost: test\r\n\r\n").as_bytes()).await.unwrap();
        let mut raw = String::new();
        stream.read_to_string(&mut raw).await.unwrap();
        let (head, body) = raw.split_once("\r\n\r\n").unwrap();
        let status = head.split(' ').nth(1).unwrap().parse().unwrap();
        let content_type = head.lines().find_map(|l| l.strip_prefix("content-type: ")).unwrap_or_default().to_string();
        (status, content_type, body.to_string())
    }

    type EventCounter = Family<Vec<(String, String)>, Counter>;

    fn registry_with_one_of_each() -> (Registry, EventCounter, Histogram) {
        let mut registry = Registry::default();
        let counter = EventCounter::default();
        let gauge = Gauge::<i64>::default();
        let histogram = Histogram::new(crate::rpc_seconds_buckets());
        registry.register("vint_test_events", "Events seen", counter.clone());
        registry.register("vint_test_depth", "Things waiting", gauge.clone());
        registry.register("vint_test_duration_seconds", "How long a thing took", histogram.clone());
        gauge.set(7);
        (registry, counter, histogram)
    }

    #[tokio::test]
    async fn metrics_are_served_as_openmetrics_text_and_follow_their_counters() {
        let (registry, counter, histogram) = registry_with_one_of_each();
        let addr = serve(router(Arc::new(registry), Fixed(Ok(())))).await;
        counter.get_or_create(&vec![("stage".into(), "grasp".into())]).inc_by(3);
        histogram.observe(0.004);
        histogram.observe(5.0);

        let (status, content_type, body) = get(addr, "/metrics").await;
        assert_eq!(status, 200);
        assert_eq!(content_type, OPENMETRICS_CONTENT_TYPE);
        check_openmetrics(&body).unwrap_or_else(|e| panic!("{e}\n{body}"));
        assert!(body.contains("\nvint_test_events_total{stage=\"grasp\"} 3\n"), "{body}");
        assert!(body.contains("\nvint_test_depth 7\n"), "{body}");
        assert!(body.contains("vint_test_duration_seconds_bucket{le=\"0.004\"} 1\n"), "{body}");
        assert!(body.contains("vint_test_duration_seconds_bucket{le=\"+Inf\"} 2\n"), "{body}");

        counter.get_or_create(&vec![("stage".into(), "grasp".into())]).inc();
        let (_, _, body) = get(addr, "/metrics").await;
        assert!(body.contains("\nvint_test_events_total{stage=\"grasp\"} 4\n"), "{body}");
    }

    /// Clients that open connections and never finish a request (a slowloris) are closed after
    /// the header-read timeout, one past the connection limit is closed at once, and the listener
    /// then serves a whole request as before.
    #[tokio::test]
    async fn slow_clients_are_cut_off_and_cannot_hold_more_than_the_connection_limit() {
        let listener = TcpListener::bind("127.0.0.1:0").await.unwrap();
        let addr = listener.local_addr().unwrap();
        let limits = ListenerLimits {
            max_connections: 2,
            handshake_timeout: Duration::from_millis(300),
            header_read_timeout: Duration::from_millis(300),
        };
        let app = router(Arc::new(Registry::default()), Fixed(Ok(())));
        tokio::spawn(super::serve(listener, app, None, limits, std::future::pending()));
        let mut slow = Vec::new();
        for _ in 0..2 {
            let mut stream = tokio::net::TcpStream::connect(addr).await.unwrap();
            stream.write_all(b"GET /healthz HTTP/1.1\r\nHost: test\r\n").await.unwrap();
            slow.push(stream);
        }
        tokio::time::sleep(Duration::from_millis(50)).await;
        // Both slots are held: a third client is closed without an answer.
        let mut third = tokio::net::TcpStream::connect(addr).await.unwrap();
        let _ = third.write_all(b"GET /healthz HTTP/1.0\r\nHost: test\r\n\r\n").await;
        let mut answer = Vec::new();
        let read = tokio::time::timeout(Duration::from_secs(5), third.read_to_end(&mut answer)).await;
        assert!(read.is_ok() && answer.is_empty(), "a connection past the limit was served: {answer:?}");
        // The slow ones are closed by the server well before the test gives up on them.
        for mut stream in slow {
            let mut rest = Vec::new();
            let closed = tokio::time::timeout(Duration::from_secs(5), stream.read_to_end(&mut rest)).await;
            assert!(closed.is_ok(), "a client that never finished its headers was kept open");
        }
        assert_eq!(get(addr, "/healthz").await.0, 200);
    }

    #[tokio::test]
    async fn healthz_answers_ok_or_503_with_the_reason() {
        let addr = serve(router(Arc::new(Registry::default()), Fixed(Ok(())))).await;
        assert_eq!(get(addr, "/healthz").await.0, 200);
        assert_eq!(get(addr, "/nothing-here").await.0, 404);
        let addr = serve(router(Arc::new(Registry::default()), Fixed(Err("database unreachable".into())))).await;
        let (status, _, body) = get(addr, "/healthz").await;
        assert_eq!((status, body.as_str()), (503, "database unreachable\n"));
    }

    #[tokio::test]
    async fn a_liveness_goes_stale_when_its_loop_stops_beating() {
        let liveness = Liveness::new("lease loop", Duration::from_millis(100));
        assert_eq!(liveness.check().await, Ok(()));
        tokio::time::sleep(Duration::from_millis(150)).await;
        let why = liveness.check().await.unwrap_err();
        assert!(why.starts_with("the lease loop last ran ") && why.ends_with(" s ago (limit 0.1 s)"), "{why}");
        liveness.beat();
        assert_eq!(liveness.check().await, Ok(()));
        assert!(liveness.since_last_beat() < Duration::from_millis(100));
    }

    #[test]
    fn the_format_check_refuses_what_prometheus_would() {
        let ok = "# HELP a_total A.\n# TYPE a counter\na_total{x=\"1\"} 2\n# EOF\n";
        assert_eq!(check_openmetrics(ok), Ok(()));
        for bad in [
            "# TYPE a counter\na_total 2\n",                          // no EOF
            "# TYPE a counter\nb_total 2\n# EOF\n",                   // a sample of another family
            "# TYPE a counter\na_total{x=1} 2\n# EOF\n",              // unquoted label value
            "# TYPE a counter\na_total two\n# EOF\n",                 // not a number
            "# TYPE a counter\n# TYPE a counter\na_total 1\n# EOF\n", // declared twice
            "# TYPE a histogram\na_bucket{le=\"1\"} 2\na_bucket{le=\"+Inf\"} 1\na_count 1\na_sum 1\n# EOF\n",
        ] {
            assert!(check_openmetrics(bad).is_err(), "accepted:\n{bad}");
        }
    }

    /// A strict reading of the OpenMetrics text format, written from the specification and not
    /// from prometheus-client's encoder: every family declared once before its samples, every
    /// sample named after its family with a suffix that fits its type, labels quoted, values
    /// numbers, each histogram's buckets cumulative up to `+Inf` = `_count`, and `# EOF` last.
    fn check_openmetrics(text: &str) -> Result<(), String> {
        let lines: Vec<&str> = text.strip_suffix('\n').ok_or("no final newline")?.split('\n').collect();
        if lines.last() != Some(&"# EOF") {
            return Err("the last line is not # EOF".into());
        }
        let mut declared = std::collections::HashSet::new();
        let mut family: Option<(String, String)> = None;
        let mut histograms = HistogramSeries::new();
        for (n, line) in lines.iter().enumerate() {
            let at = |why: &str| format!("line {}: {why}: {line:?}", n + 1);
            if line.starts_with("# TYPE ") || *line == "# EOF" {
                check_histograms(&histograms).map_err(|e| at(&e))?;
                histograms.clear();
            }
            if *line == "# EOF" {
                break;
            }
            if let Some(rest) = line.strip_prefix("# ") {
                let mut parts = rest.splitn(3, ' ');
                let (kind, name) = (parts.next().unwrap_or(""), parts.next().ok_or_else(|| at("no name"))?);
                check_name(name).map_err(|e| at(&e))?;
                match kind {
                    "TYPE" => {
                        let ty = parts.next().ok_or_else(|| at("no type"))?;
                        if !["counter", "gauge", "histogram", "summary", "info", "stateset", "unknown"].contains(&ty) {
                            return Err(at("unknown type"));
                        }
                        if !declared.insert(name.to_string()) {
                            return Err(at("family declared twice"));
                        }
                        family = Some((name.to_string(), ty.to_string()));
                    }
                    "HELP" | "UNIT" => {}
                    _ => return Err(at("unknown comment")),
                }
                continue;
            }
            let (name, labels, value) = split_sample(line).ok_or_else(|| at("not a sample"))?;
            let (fam, ty) = family.as_ref().ok_or_else(|| at("sample before any TYPE"))?;
            let suffix = name.strip_prefix(fam.as_str()).ok_or_else(|| at("sample outside its family"))?;
            let allowed: &[&str] = match ty.as_str() {
                "counter" => &["_total", "_created"],
                "histogram" => &["_bucket", "_count", "_sum", "_created"],
                _ => &[""],
            };
            if !allowed.contains(&suffix) {
                return Err(at("sample suffix does not fit its type"));
            }
            let value: f64 = value.parse().map_err(|_| at("value is not a number"))?;
            let mut le = None;
            let mut series = Vec::new();
            for (k, v) in split_labels(labels).map_err(|e| at(&e))? {
                check_name(k).map_err(|e| at(&e))?;
                if k == "le" {
                    le = Some(v.to_string());
                } else {
                    series.push(format!("{k}={v}"));
                }
            }
            let entry = histograms.entry(series.join(",")).or_default();
            match suffix {
                "_bucket" => entry.0.push((le.ok_or_else(|| at("bucket without le"))?, value)),
                "_count" if ty == "histogram" => entry.1 = Some(value),
                _ => {}
            }
        }
        Ok(())
    }

    /// A histogram family's series, by their labels but `le`: their buckets (`le`, count) and
    /// their `_count`.
    type HistogramSeries = std::collections::BTreeMap<String, (Vec<(String, f64)>, Option<f64>)>;

    /// Each histogram series: buckets in increasing `le`, cumulative, ending at `+Inf` = `_count`.
    fn check_histograms(histograms: &HistogramSeries) -> Result<(), String> {
        for (series, (buckets, count)) in histograms {
            let Some(count) = count else { continue };
            let bounds: Vec<f64> = buckets
                .iter()
                .map(|(le, _)| le.parse::<f64>().map_err(|_| format!("le {le:?}")))
                .collect::<Result<_, _>>()?;
            if bounds.windows(2).any(|w| w[0] >= w[1]) || buckets.windows(2).any(|w| w[0].1 > w[1].1) {
                return Err(format!("{series}: buckets out of order or not cumulative"));
            }
            match buckets.last() {
                Some((le, n)) if le == "+Inf" && n == count => {}
                _ => return Err(format!("{series}: the +Inf bucket is not _count ({count})")),
            }
        }
        Ok(())
    }

    fn check_name(name: &str) -> Result<(), String> {
        let mut chars = name.chars();
        let first_ok = chars.next().is_some_and(|c| c.is_ascii_alphabetic() || c == '_' || c == ':');
        if first_ok && chars.all(|c| c.is_ascii_alphanumeric() || c == '_' || c == ':') {
            Ok(())
        } else {
            Err(format!("bad name {name:?}"))
        }
    }

    /// `name{labels} value` or `name value`.
    fn split_sample(line: &str) -> Option<(&str, &str, &str)> {
        match line.find('{') {
            Some(open) => {
                let close = line.rfind('}')?;
                Some((&line[..open], &line[open + 1..close], line[close + 1..].strip_prefix(' ')?))
            }
            None => {
                let (name, value) = line.split_once(' ')?;
                Some((name, "", value))
            }
        }
    }

    /// `k="v",k="v"` (values without escapes: vint's label values are plain words).
    fn split_labels(labels: &str) -> Result<Vec<(&str, &str)>, String> {
        if labels.is_empty() {
            return Ok(Vec::new());
        }
        labels
            .split(',')
            .map(|pair| {
                let (k, v) = pair.split_once('=').ok_or_else(|| format!("label without =: {pair:?}"))?;
                let v = v
                    .strip_prefix('"')
                    .and_then(|v| v.strip_suffix('"'))
                    .filter(|v| !v.contains(['"', '\\']))
                    .ok_or_else(|| format!("label value not quoted: {pair:?}"))?;
                Ok((k, v))
            })
            .collect()
    }
}

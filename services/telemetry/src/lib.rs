//! How vint's processes report on themselves: logging (tracing) set-up shared by the coordinator,
//! the workers and the CLI. Metrics exporters belong here too when they come.

/// Logs to stderr, filtered by `RUST_LOG` (default `info`), as text or JSON lines.
pub fn init_tracing(json: bool) {
    use tracing_subscriber::EnvFilter;
    let filter = EnvFilter::try_from_default_env().unwrap_or_else(|_| EnvFilter::new("info"));
    let builder = tracing_subscriber::fmt().with_env_filter(filter).with_writer(std::io::stderr);
    let _ = if json { builder.json().try_init() } else { builder.try_init() };
}

mod redact;
pub use redact::{REDACTED, redact_url};

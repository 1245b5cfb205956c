//! The coordinator's TLS identity (`--tls-cert`, `--tls-key`): PEM files read and checked at
//! start, so that a bad certificate or key stops the coordinator before it listens.

use std::fmt;
use std::path::{Path, PathBuf};

use tonic::transport::{Identity, ServerTlsConfig};

/// A certificate chain and its private key, both PEM.
#[derive(Clone)]
pub struct TlsIdentity {
    cert_pem: Vec<u8>,
    key_pem: Vec<u8>,
}

impl fmt::Debug for TlsIdentity {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        f.debug_struct("TlsIdentity").finish_non_exhaustive()
    }
}

#[derive(Debug, thiserror::Error)]
pub enum TlsError {
    #[error("{flag} {}: cannot read it: {source}", path.display())]
    Read { flag: &'static str, path: PathBuf, source: std::io::Error },
    #[error("--tls-cert {} and --tls-key {}: not a usable PEM certificate and private key: {reason}", cert.display(), key.display())]
    Unusable { cert: PathBuf, key: PathBuf, reason: String },
}

impl TlsIdentity {
    /// Reads `cert` (PEM, the server's certificate first, then any intermediates) and `key`
    /// (PEM private key) and checks that TLS can be served with them.
    pub fn load(cert: &Path, key: &Path) -> Result<TlsIdentity, TlsError> {
        let read = |flag, path: &Path| {
            std::fs::read(path).map_err(|source| TlsError::Read { flag, path: path.to_path_buf(), source })
        };
        let identity = TlsIdentity { cert_pem: read("--tls-cert", cert)?, key_pem: read("--tls-key", key)? };
        tonic::transport::Server::builder().tls_config(identity.server_config()).map_err(|e| {
            let mut reason = e.to_string();
            let mut source = std::error::Error::source(&e);
            while let Some(s) = source {
                reason = format!("{reason}: {s}");
                source = s.source();
            }
            TlsError::Unusable { cert: cert.to_path_buf(), key: key.to_path_buf(), reason }
        })?;
        Ok(identity)
    }

    /// The gRPC listener's TLS: this identity, and a client gets `HANDSHAKE_TIMEOUT` to finish
    /// its handshake (a client that never does would hold its connection otherwise).
    pub fn server_config(&self) -> ServerTlsConfig {
        ServerTlsConfig::new()
            .identity(Identity::from_pem(&self.cert_pem, &self.key_pem))
            .timeout(crate::listener::HANDSHAKE_TIMEOUT)
    }
}

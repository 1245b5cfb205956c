//! How a client reaches a coordinator: the URL (`http://` or `https://`), the certificate
//! authority it trusts for TLS (`--tls-ca`, else the system's roots) and the bearer token it sends
//! with every call (`--token`). `vintctl` and `vint-worker` both connect through here, so the two
//! clients cannot disagree on how a token travels or which URLs mean TLS.
//!
//! It opens no connection by itself and knows nothing of the services' messages.

use std::path::{Path, PathBuf};

use tonic::metadata::{AsciiMetadataValue, MetadataValue};
use tonic::service::Interceptor;
use tonic::service::interceptor::InterceptedService;
use tonic::transport::{Certificate, Channel, ClientTlsConfig, Endpoint};

/// A channel whose every call carries the bearer token (if any).
pub type AuthChannel = InterceptedService<Channel, BearerToken>;

/// Where a coordinator is and how to prove who we are to it.
#[derive(Clone, Default)]
pub struct Remote {
    /// `http://HOST:PORT` or `https://HOST:PORT`.
    pub url: String,
    /// Sent as `authorization: Bearer TOKEN`; `None` sends nothing.
    pub token: Option<String>,
    /// PEM certificate(s) of the authority that signed the coordinator's certificate; without it an
    /// `https://` coordinator must present a certificate the system trusts.
    pub tls_ca: Option<PathBuf>,
}

impl std::fmt::Debug for Remote {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        // The token is a secret: say only whether there is one.
        f.debug_struct("Remote")
            .field("url", &self.url)
            .field("token", &self.token.as_ref().map(|_| "…"))
            .field("tls_ca", &self.tls_ca)
            .finish()
    }
}

#[derive(Debug, thiserror::Error)]
pub enum ConnectError {
    #[error("coordinator URL {url:?}: {reason}")]
    BadUrl { url: String, reason: String },
    #[error("--token (or VINT_TOKEN): must be printable ASCII without spaces (the value is not shown)")]
    BadToken,
    #[error("--tls-ca (or VINT_TLS_CA) {}: cannot read it: {source}", path.display())]
    ReadCa { path: PathBuf, source: std::io::Error },
    #[error(
        "--tls-ca (or VINT_TLS_CA) {} is given but the coordinator URL {url:?} is not https://: TLS needs an https:// URL",
        path.display()
    )]
    CaWithoutHttps { path: PathBuf, url: String },
    #[error("TLS set-up for {url:?}: {source}")]
    Tls { url: String, source: tonic::transport::Error },
}

/// Adds `authorization: Bearer TOKEN` to every call.
#[derive(Clone, Debug, Default)]
pub struct BearerToken(Option<AsciiMetadataValue>);

impl Interceptor for BearerToken {
    fn call(&mut self, mut request: tonic::Request<()>) -> Result<tonic::Request<()>, tonic::Status> {
        if let Some(value) = &self.0 {
            request.metadata_mut().insert("authorization", value.clone());
        }
        Ok(request)
    }
}

impl Remote {
    /// The endpoint for `url`, with TLS when it is `https://` (trusting `tls_ca` or the system's
    /// roots). Connects nothing yet.
    pub fn endpoint(&self) -> Result<Endpoint, ConnectError> {
        let bad = |reason: String| ConnectError::BadUrl { url: self.url.clone(), reason };
        let endpoint = Endpoint::from_shared(self.url.clone()).map_err(|e| bad(e.to_string()))?;
        let https = endpoint.uri().scheme_str() == Some("https");
        match (&self.tls_ca, https) {
            (Some(path), false) => Err(ConnectError::CaWithoutHttps { path: path.clone(), url: self.url.clone() }),
            (None, false) => Ok(endpoint),
            (ca, true) => {
                let tls = match ca {
                    Some(path) => ClientTlsConfig::new().ca_certificate(Certificate::from_pem(read_ca(path)?)),
                    None => ClientTlsConfig::new().with_native_roots(),
                };
                endpoint.tls_config(tls).map_err(|source| ConnectError::Tls { url: self.url.clone(), source })
            }
        }
    }

    /// The interceptor that sends this remote's token.
    pub fn bearer(&self) -> Result<BearerToken, ConnectError> {
        match &self.token {
            None => Ok(BearerToken(None)),
            Some(token) => {
                let token = token.trim();
                if token.is_empty() || !token.bytes().all(|b| b.is_ascii_graphic()) {
                    return Err(ConnectError::BadToken);
                }
                let mut value: AsciiMetadataValue =
                    MetadataValue::try_from(format!("Bearer {token}")).map_err(|_| ConnectError::BadToken)?;
                value.set_sensitive(true);
                Ok(BearerToken(Some(value)))
            }
        }
    }

    /// A channel that connects on first use and sends the token with every call.
    pub fn lazy_channel(&self, endpoint: Endpoint) -> Result<AuthChannel, ConnectError> {
        Ok(InterceptedService::new(endpoint.connect_lazy(), self.bearer()?))
    }
}

fn read_ca(path: &Path) -> Result<Vec<u8>, ConnectError> {
    std::fs::read(path).map_err(|source| ConnectError::ReadCa { path: path.to_path_buf(), source })
}

#[cfg(test)]
mod tests {
    use super::*;

    fn remote(url: &str, token: Option<&str>, tls_ca: Option<&str>) -> Remote {
        Remote { url: url.into(), token: token.map(Into::into), tls_ca: tls_ca.map(PathBuf::from) }
    }

    #[test]
    fn the_token_travels_as_a_bearer_header_and_only_when_given() {
        let mut with = remote("http://127.0.0.1:1", Some("tok-0123456789abcdef"), None).bearer().unwrap();
        let request = with.call(tonic::Request::new(())).unwrap();
        assert_eq!(request.metadata().get("authorization").unwrap(), "Bearer tok-0123456789abcdef");
        let mut without = remote("http://127.0.0.1:1", None, None).bearer().unwrap();
        assert!(without.call(tonic::Request::new(())).unwrap().metadata().get("authorization").is_none());
    }

    #[test]
    fn a_token_with_spaces_or_control_characters_is_refused_without_showing_it() {
        for token in ["two words", "tab\there", "", "tök"] {
            let e = remote("http://127.0.0.1:1", Some(token), None).bearer().unwrap_err();
            assert!(matches!(e, ConnectError::BadToken), "{token:?}");
            assert!(token.is_empty() || !e.to_string().contains(token), "{e}");
        }
    }

    #[test]
    fn a_ca_without_an_https_url_is_an_error_and_a_missing_ca_file_is_named() {
        let e = remote("http://127.0.0.1:1", None, Some("/tmp/ca.pem")).endpoint().unwrap_err();
        assert!(matches!(e, ConnectError::CaWithoutHttps { .. }), "{e}");
        let e = remote("https://127.0.0.1:1", None, Some("/nonexistent/ca.pem")).endpoint().unwrap_err();
        assert!(e.to_string().contains("/nonexistent/ca.pem"), "{e}");
        assert!(remote("http://127.0.0.1:1", None, None).endpoint().is_ok());
    }

    #[test]
    fn debug_output_hides_the_token() {
        let shown = format!("{:?}", remote("http://h:1", Some("secret-token-0123456789"), None));
        assert!(!shown.contains("secret-token"), "{shown}");
    }
}

//! Content-addressed artifact storage over `object_store`: a local directory (embedded default)
//! or S3 (cluster).
//!
//! An artifact's key is derived from its SHA-256 (`sha256/ab/abcdef…`), never chosen by a caller,
//! so keys cannot escape the store and a retried upload of the same content is a no-op: writes use
//! `PutMode::Create` and treat "already exists" as success. Reads verify the hash.

use std::path::Path;
use std::sync::Arc;

use bytes::Bytes;
use object_store::aws::AmazonS3Builder;
use object_store::local::LocalFileSystem;
use object_store::path::Path as ObjectPath;
use object_store::{ObjectStore, ObjectStoreExt, PutMode, PutOptions, PutPayload};
use sha2::{Digest, Sha256};

#[derive(Debug, thiserror::Error)]
pub enum ArtifactError {
    /// The URL, with any password redacted.
    #[error("unsupported artifact store URL {0:?}: expected file:///absolute/dir or s3://bucket[/prefix]")]
    UnsupportedUrl(String),
    #[error("object store: {0}")]
    Store(#[from] object_store::Error),
    #[error("I/O on {path}: {source}")]
    Io { path: String, source: std::io::Error },
    #[error("artifact {key} is corrupt: expected sha256 {expected}, read {actual}")]
    HashMismatch { key: String, expected: String, actual: String },
    #[error("{0:?} is not a sha256 hex digest")]
    BadDigest(String),
}

pub type Result<T, E = ArtifactError> = std::result::Result<T, E>;

/// What an upload produced.
#[derive(Clone, Debug, PartialEq, Eq)]
pub struct StoredObject {
    pub sha256: String,
    pub size: u64,
    pub key: String,
}

#[derive(Clone, Debug)]
pub struct ArtifactStore {
    inner: Arc<dyn ObjectStore>,
    /// Key prefix inside the bucket (S3) or directory (local).
    prefix: String,
    url: String,
}

/// The object key of content with this digest.
pub fn key_for(sha256: &str) -> Result<String> {
    if sha256.len() != 64 || !sha256.bytes().all(|b| b.is_ascii_hexdigit() && !b.is_ascii_uppercase()) {
        return Err(ArtifactError::BadDigest(sha256.to_string()));
    }
    Ok(format!("sha256/{}/{}", &sha256[..2], sha256))
}

pub fn sha256_hex(bytes: &[u8]) -> String {
    hex::encode(Sha256::digest(bytes))
}

impl ArtifactStore {
    /// Opens `file:///abs/dir` (created if missing) or `s3://bucket[/prefix]`; S3 credentials,
    /// region and endpoint come from the usual `AWS_*` environment variables
    /// (`AWS_ENDPOINT_URL` and `AWS_ALLOW_HTTP=true` for S3-compatible servers).
    pub fn open(url: &str) -> Result<ArtifactStore> {
        if let Some(dir) = url.strip_prefix("file://") {
            if !dir.starts_with('/') {
                return Err(ArtifactError::UnsupportedUrl(vint_telemetry::redact_url(url)));
            }
            std::fs::create_dir_all(dir).map_err(|source| ArtifactError::Io { path: dir.to_string(), source })?;
            let fs = LocalFileSystem::new_with_prefix(dir)?;
            return Ok(ArtifactStore { inner: Arc::new(fs), prefix: String::new(), url: url.to_string() });
        }
        if let Some(rest) = url.strip_prefix("s3://") {
            let (bucket, prefix) = rest.split_once('/').unwrap_or((rest, ""));
            if bucket.is_empty() {
                return Err(ArtifactError::UnsupportedUrl(vint_telemetry::redact_url(url)));
            }
            let s3 = AmazonS3Builder::from_env().with_bucket_name(bucket).build()?;
            let prefix = prefix.trim_matches('/').to_string();
            return Ok(ArtifactStore { inner: Arc::new(s3), prefix, url: url.to_string() });
        }
        Err(ArtifactError::UnsupportedUrl(vint_telemetry::redact_url(url)))
    }

    pub fn url(&self) -> &str {
        &self.url
    }

    fn location(&self, key: &str) -> ObjectPath {
        if self.prefix.is_empty() { ObjectPath::from(key) } else { ObjectPath::from(format!("{}/{key}", self.prefix)) }
    }

    /// Stores `bytes` under their content key. Storing the same content again changes nothing.
    pub async fn put_bytes(&self, bytes: Bytes) -> Result<StoredObject> {
        let sha256 = sha256_hex(&bytes);
        let key = key_for(&sha256)?;
        let size = bytes.len() as u64;
        let opts = PutOptions { mode: PutMode::Create, ..Default::default() };
        match self.inner.put_opts(&self.location(&key), PutPayload::from(bytes), opts).await {
            Ok(_) | Err(object_store::Error::AlreadyExists { .. }) => {}
            Err(e) => return Err(e.into()),
        }
        Ok(StoredObject { sha256, size, key })
    }

    /// Stores a file's content (artifacts are at most a few MB: images and arrays of one view).
    pub async fn put_file(&self, path: &Path) -> Result<StoredObject> {
        let bytes = tokio::fs::read(path)
            .await
            .map_err(|source| ArtifactError::Io { path: path.display().to_string(), source })?;
        self.put_bytes(Bytes::from(bytes)).await
    }

    /// Reads an artifact and checks it against its digest.
    pub async fn get(&self, sha256: &str) -> Result<Bytes> {
        let key = key_for(sha256)?;
        let bytes = self.inner.get(&self.location(&key)).await?.bytes().await?;
        let actual = sha256_hex(&bytes);
        if actual != sha256 {
            return Err(ArtifactError::HashMismatch { key, expected: sha256.to_string(), actual });
        }
        Ok(bytes)
    }

    /// Reads an artifact into `dest` (written whole through a temporary file, then renamed).
    pub async fn get_to_file(&self, sha256: &str, dest: &Path) -> Result<()> {
        let bytes = self.get(sha256).await?;
        let io = |source| ArtifactError::Io { path: dest.display().to_string(), source };
        if let Some(parent) = dest.parent() {
            tokio::fs::create_dir_all(parent).await.map_err(io)?;
        }
        let tmp = dest.with_extension("partial");
        tokio::fs::write(&tmp, &bytes).await.map_err(io)?;
        tokio::fs::rename(&tmp, dest).await.map_err(io)?;
        Ok(())
    }

    /// Number of stored objects (for tests and stats; lists the whole store).
    pub async fn count_objects(&self) -> Result<usize> {
        use futures::TryStreamExt;
        let prefix = if self.prefix.is_empty() { None } else { Some(ObjectPath::from(self.prefix.as_str())) };
        let objects: Vec<_> = self.inner.list(prefix.as_ref()).try_collect().await?;
        Ok(objects.len())
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn local() -> (ArtifactStore, tempfile::TempDir) {
        let dir = tempfile::tempdir().unwrap();
        (ArtifactStore::open(&format!("file://{}", dir.path().display())).unwrap(), dir)
    }

    #[tokio::test]
    async fn same_content_same_key_and_one_object() {
        let (store, _d) = local();
        let a = store.put_bytes(Bytes::from_static(b"depth")).await.unwrap();
        let b = store.put_bytes(Bytes::from_static(b"depth")).await.unwrap();
        assert_eq!(a, b);
        assert_eq!(store.count_objects().await.unwrap(), 1);
        assert_eq!(store.get(&a.sha256).await.unwrap(), Bytes::from_static(b"depth"));
    }

    #[tokio::test]
    async fn corrupted_content_is_detected() {
        let (store, dir) = local();
        let a = store.put_bytes(Bytes::from_static(b"mask")).await.unwrap();
        std::fs::write(dir.path().join(&a.key), b"MASK").unwrap();
        assert!(matches!(store.get(&a.sha256).await, Err(ArtifactError::HashMismatch { .. })));
    }

    #[test]
    fn keys_cannot_be_chosen_or_escape_the_store() {
        assert!(key_for("../../etc/passwd").is_err());
        assert!(key_for(&"A".repeat(64)).is_err());
        assert_eq!(key_for(&"ab".repeat(32)).unwrap(), format!("sha256/ab/{}", "ab".repeat(32)));
    }

    #[test]
    fn relative_and_unknown_urls_are_rejected() {
        assert!(ArtifactStore::open("file://relative/dir").is_err());
        assert!(ArtifactStore::open("gs://bucket").is_err());
        assert!(ArtifactStore::open("s3://").is_err());
    }
}

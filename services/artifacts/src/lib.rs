//! Content-addressed artifact storage over `object_store`: a local directory (embedded default)
//! or S3 (cluster).
//!
//! An artifact's key is derived from its SHA-256 (`sha256/ab/abcdef…`), never chosen by a caller,
//! so keys cannot escape the store and a retried upload of the same content is a no-op: writes use
//! `PutMode::Create`, and an object that already exists is read back and checked against its hash:
//! intact, the write is done; corrupt (a disk's bit rot, a truncated copy), it is rewritten with
//! the bytes being stored, so storing the content again repairs it. Reads verify the hash.
//!
//! A key that arrives from outside (a worker's completion, a row read back from the database) is
//! checked by `check_key` against the one shape the store makes; every object location passes
//! through it too, so no key can name a path outside the store's prefix.

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
    #[error("artifact key {key:?}: {rule}")]
    BadKey { key: String, rule: &'static str },
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

/// Extra tries of an upload that failed with a transport or server error. object_store retries
/// on its own only the requests it knows to be idempotent, so a connection dropped mid-request or
/// mid-response fails a PUT (and with it a whole task: a render re-rendered, an attempt of the
/// task's budget spent). An upload here is idempotent: its key is its content's hash and it is
/// written create-if-absent, so a retry finds the object (`AlreadyExists`) or writes the same bytes.
const PUT_RETRIES: u32 = 2;

/// The object key of content with this digest.
pub fn key_for(sha256: &str) -> Result<String> {
    if sha256.len() != 64 || !sha256.bytes().all(|b| b.is_ascii_hexdigit() && !b.is_ascii_uppercase()) {
        return Err(ArtifactError::BadDigest(sha256.to_string()));
    }
    Ok(format!("sha256/{}/{}", &sha256[..2], sha256))
}

/// Checks that `key` is one the store makes: `sha256/<first two hex digits>/<64 lowercase hex
/// digits>`. Anything else — empty, absolute, with a backslash, an empty, `.` or `..` segment, or
/// any other shape — is `BadKey` naming the rule it breaks.
pub fn check_key(key: &str) -> Result<()> {
    let bad = |rule| Err(ArtifactError::BadKey { key: key.to_string(), rule });
    if key.is_empty() {
        return bad("must not be empty");
    }
    if key.contains('\\') {
        return bad("must not contain a backslash");
    }
    if key.starts_with('/') {
        return bad("must be relative to the store, not an absolute path");
    }
    let segments: Vec<&str> = key.split('/').collect();
    if segments.contains(&"") {
        return bad("must not have an empty segment");
    }
    if segments.iter().any(|s| *s == "." || *s == "..") {
        return bad("must not have a '.' or '..' segment");
    }
    match segments[..] {
        ["sha256", _, digest] if key_for(digest).is_ok_and(|k| k == key) => Ok(()),
        _ => bad("must be sha256/<first two digits>/<64 lowercase hex digits>, the content key the store makes"),
    }
}

pub fn sha256_hex(bytes: &[u8]) -> String {
    hex::encode(Sha256::digest(bytes))
}

/// An object as the store lists it.
#[derive(Clone, Debug, PartialEq, Eq)]
pub struct ListedObject {
    pub key: String,
    pub size: u64,
    pub modified_ms: i64,
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

    /// Where `key` lives under the store's prefix; a key of any other shape than the store's is
    /// refused here, whoever passed it.
    fn location(&self, key: &str) -> Result<ObjectPath> {
        check_key(key)?;
        Ok(if self.prefix.is_empty() {
            ObjectPath::from(key)
        } else {
            ObjectPath::from(format!("{}/{key}", self.prefix))
        })
    }

    /// Stores `bytes` under their content key. Storing the same content again changes nothing.
    pub async fn put_bytes(&self, bytes: Bytes) -> Result<StoredObject> {
        let sha256 = sha256_hex(&bytes);
        let key = key_for(&sha256)?;
        let size = bytes.len() as u64;
        let opts = PutOptions { mode: PutMode::Create, ..Default::default() };
        let location = self.location(&key)?;
        let mut tries = 0;
        loop {
            match self.inner.put_opts(&location, PutPayload::from(bytes.clone()), opts.clone()).await {
                Ok(_) => break,
                Err(object_store::Error::AlreadyExists { .. }) => {
                    if !self.holds_intact(&location, &sha256).await? {
                        tracing::warn!(%key, "a stored object does not match its hash; rewriting it");
                        let overwrite = PutOptions { mode: PutMode::Overwrite, ..Default::default() };
                        self.inner.put_opts(&location, PutPayload::from(bytes.clone()), overwrite).await?;
                    }
                    break;
                }
                Err(e @ object_store::Error::Generic { .. }) if tries < PUT_RETRIES => {
                    tries += 1;
                    tracing::warn!(%key, error = %e, "upload failed; trying again");
                    tokio::time::sleep(std::time::Duration::from_millis(200 * u64::from(tries))).await;
                }
                Err(e) => return Err(e.into()),
            }
        }
        Ok(StoredObject { sha256, size, key })
    }

    /// Whether the object at `location` exists and hashes to `sha256`.
    async fn holds_intact(&self, location: &ObjectPath, sha256: &str) -> Result<bool> {
        match self.inner.get(location).await {
            Ok(found) => Ok(sha256_hex(&found.bytes().await?) == sha256),
            Err(object_store::Error::NotFound { .. }) => Ok(false),
            Err(e) => Err(e.into()),
        }
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
        let bytes = self.inner.get(&self.location(&key)?).await?.bytes().await?;
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

    /// Every stored object's key (relative to the store's prefix), size and last-modified time
    /// (Unix ms); lists the whole store.
    pub async fn list_objects(&self) -> Result<Vec<ListedObject>> {
        use futures::TryStreamExt;
        let prefix = if self.prefix.is_empty() { None } else { Some(ObjectPath::from(self.prefix.as_str())) };
        let objects: Vec<_> = self.inner.list(prefix.as_ref()).try_collect().await?;
        let strip = if self.prefix.is_empty() { String::new() } else { format!("{}/", self.prefix) };
        Ok(objects
            .into_iter()
            .map(|m| ListedObject {
                key: m.location.as_ref().strip_prefix(strip.as_str()).unwrap_or(m.location.as_ref()).to_string(),
                size: m.size,
                modified_ms: m.last_modified.timestamp_millis(),
            })
            .collect())
    }

    /// Deletes the object under `key` (a content key: any other shape is refused). Deleting an
    /// object that is not there is not an error.
    pub async fn delete(&self, key: &str) -> Result<()> {
        match self.inner.delete(&self.location(key)?).await {
            Ok(()) | Err(object_store::Error::NotFound { .. }) => Ok(()),
            Err(e) => Err(e.into()),
        }
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

    #[tokio::test]
    async fn storing_the_content_again_repairs_a_corrupt_object() {
        let (store, dir) = local();
        let a = store.put_bytes(Bytes::from_static(b"depth image")).await.unwrap();
        std::fs::write(dir.path().join(&a.key), b"depth imagE").unwrap();
        assert!(matches!(store.get(&a.sha256).await, Err(ArtifactError::HashMismatch { .. })));
        let again = store.put_bytes(Bytes::from_static(b"depth image")).await.unwrap();
        assert_eq!(again, a);
        assert_eq!(store.get(&a.sha256).await.unwrap(), Bytes::from_static(b"depth image"));
        assert_eq!(store.count_objects().await.unwrap(), 1);
    }

    /// An in-memory store whose first `failures` puts fail as a dropped connection would, after
    /// the object is written (the worst case: stored, but the client never hears so).
    #[derive(Debug)]
    struct DroppingStore {
        inner: object_store::memory::InMemory,
        failures: std::sync::atomic::AtomicU32,
        puts: std::sync::atomic::AtomicU32,
    }

    impl std::fmt::Display for DroppingStore {
        fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
            write!(f, "DroppingStore")
        }
    }

    #[async_trait::async_trait]
    impl ObjectStore for DroppingStore {
        async fn put_opts(
            &self,
            location: &ObjectPath,
            payload: PutPayload,
            opts: PutOptions,
        ) -> object_store::Result<object_store::PutResult> {
            use std::sync::atomic::Ordering::SeqCst;
            self.puts.fetch_add(1, SeqCst);
            let written = self.inner.put_opts(location, payload, opts).await;
            if self.failures.fetch_update(SeqCst, SeqCst, |n| n.checked_sub(1)).is_ok() {
                return Err(object_store::Error::Generic { store: "dropping", source: "connection reset".into() });
            }
            written
        }
        async fn put_multipart_opts(
            &self,
            location: &ObjectPath,
            opts: object_store::PutMultipartOptions,
        ) -> object_store::Result<Box<dyn object_store::MultipartUpload>> {
            self.inner.put_multipart_opts(location, opts).await
        }
        async fn get_opts(
            &self,
            location: &ObjectPath,
            options: object_store::GetOptions,
        ) -> object_store::Result<object_store::GetResult> {
            self.inner.get_opts(location, options).await
        }
        fn delete_stream(
            &self,
            locations: futures::stream::BoxStream<'static, object_store::Result<ObjectPath>>,
        ) -> futures::stream::BoxStream<'static, object_store::Result<ObjectPath>> {
            self.inner.delete_stream(locations)
        }
        fn list(
            &self,
            prefix: Option<&ObjectPath>,
        ) -> futures::stream::BoxStream<'static, object_store::Result<object_store::ObjectMeta>> {
            self.inner.list(prefix)
        }
        async fn list_with_delimiter(
            &self,
            prefix: Option<&ObjectPath>,
        ) -> object_store::Result<object_store::ListResult> {
            self.inner.list_with_delimiter(prefix).await
        }
        async fn copy_opts(
            &self,
            from: &ObjectPath,
            to: &ObjectPath,
            options: object_store::CopyOptions,
        ) -> object_store::Result<()> {
            self.inner.copy_opts(from, to, options).await
        }
    }

    fn dropping(failures: u32) -> (ArtifactStore, Arc<DroppingStore>) {
        let inner = Arc::new(DroppingStore {
            inner: object_store::memory::InMemory::new(),
            failures: failures.into(),
            puts: 0.into(),
        });
        (ArtifactStore { inner: inner.clone(), prefix: String::new(), url: "memory://".into() }, inner)
    }

    #[tokio::test]
    async fn an_upload_whose_connection_dropped_is_tried_again() {
        let (store, inner) = dropping(PUT_RETRIES);
        let a = store.put_bytes(Bytes::from_static(b"rgb")).await.unwrap();
        assert_eq!(inner.puts.load(std::sync::atomic::Ordering::SeqCst), PUT_RETRIES + 1);
        assert_eq!(store.get(&a.sha256).await.unwrap(), Bytes::from_static(b"rgb"));
        assert_eq!(store.count_objects().await.unwrap(), 1);
    }

    #[tokio::test]
    async fn an_upload_that_keeps_failing_gives_up() {
        let (store, inner) = dropping(PUT_RETRIES + 1);
        assert!(matches!(store.put_bytes(Bytes::from_static(b"rgb")).await, Err(ArtifactError::Store(_))));
        assert_eq!(inner.puts.load(std::sync::atomic::Ordering::SeqCst), PUT_RETRIES + 1);
    }

    #[test]
    fn keys_cannot_be_chosen_or_escape_the_store() {
        assert!(key_for("../../etc/passwd").is_err());
        assert!(key_for(&"A".repeat(64)).is_err());
        assert_eq!(key_for(&"ab".repeat(32)).unwrap(), format!("sha256/ab/{}", "ab".repeat(32)));
    }

    fn rule_of(key: &str) -> &'static str {
        match check_key(key) {
            Err(ArtifactError::BadKey { rule, .. }) => rule,
            other => panic!("{key:?} should be refused, got {other:?}"),
        }
    }

    #[test]
    fn only_the_content_keys_the_store_makes_pass_check_key() {
        let digest = "ab".repeat(32);
        let good = key_for(&digest).unwrap();
        assert!(check_key(&good).is_ok());
        assert!(rule_of("").contains("empty"));
        assert!(rule_of(&format!("sha256\\ab\\{digest}")).contains("backslash"));
        assert!(rule_of(&format!("/{good}")).contains("absolute"));
        assert!(rule_of(&format!("sha256//{digest}")).contains("empty segment"));
        assert!(rule_of(&format!("{good}/")).contains("empty segment"));
        assert!(rule_of(&format!("sha256/ab/../../{digest}")).contains("'..'"));
        assert!(rule_of(&format!("sha256/./{digest}")).contains("'.'"));
        assert!(rule_of("../../etc/passwd").contains("'..'"));
        // Right segments, wrong shape: another fan-out directory, upper case, a short digest, a prefix.
        assert!(rule_of(&format!("sha256/cd/{digest}")).contains("content key"));
        assert!(rule_of(&format!("sha256/AB/{}", "AB".repeat(32))).contains("content key"));
        assert!(rule_of("sha256/ab/abab").contains("content key"));
        assert!(rule_of(&format!("objects/{good}")).contains("content key"));
        assert!(rule_of(&format!("sha512/ab/{digest}")).contains("content key"));
    }

    #[tokio::test]
    async fn a_store_under_a_prefix_keeps_every_object_under_it() {
        let dir = tempfile::tempdir().unwrap();
        let inner = dir.path().join("inner");
        let store = ArtifactStore::open(&format!("file://{}", inner.display())).unwrap();
        let stored = store.put_bytes(Bytes::from_static(b"touch")).await.unwrap();
        assert!(inner.join(&stored.key).is_file());
        assert_eq!(std::fs::read_dir(dir.path()).unwrap().count(), 1, "nothing written beside the store");
        assert!(matches!(store.location("sha256/ab/../../../x"), Err(ArtifactError::BadKey { .. })));
    }

    #[test]
    fn relative_and_unknown_urls_are_rejected() {
        assert!(ArtifactStore::open("file://relative/dir").is_err());
        assert!(ArtifactStore::open("gs://bucket").is_err());
        assert!(ArtifactStore::open("s3://").is_err());
    }
}

//! A task's outputs packed in one row (`outputs.files`, migration 0013): a few dozen bytes a file
//! instead of a row of ~300 with its index entry, which made `artifacts` most of a sample's bytes
//! (docs/benchmarks.md).
//!
//! Every read of outputs goes by task (a task's outputs, a task's inputs through `task_deps`, a
//! sample's files through its package task), so nothing is lost by packing them. What a row can
//! derive is not stored: the object key is the hash's (`vint_artifacts::key_for`), the time is the
//! task's.
//!
//! The format (version 1), little to read and nothing to guess:
//!
//! ```text
//! 0x01                                  version
//! varint M, then M × (varint len, utf-8)  the media types the files use, in first-use order
//! varint N, then N files in strictly increasing byte order of their names:
//!   varint shared   bytes the name shares with the previous file's name (0 for the first)
//!   varint len, utf-8  the rest of the name
//!   varint          the file's media type (an index into the list above)
//!   varint          the file's size in bytes
//!   32 bytes        its SHA-256
//! ```
//!
//! Varints are unsigned LEB128 (7 bits a byte, low first). A package task's names share their
//! sample's id with the name before (`mug.trx3.g000012.v05/rgb.png`, `…/depth.npy`), so a name
//! costs a few bytes; a file ~50 in all (measured: docs/plan.md), most of it its hash.

use std::collections::BTreeMap;

use sqlx::Row;

use crate::jobs::json_text;
use crate::sql::sql;
use crate::{ArtifactRecord, NewArtifact, Result, Store, StoreError};

const VERSION: u8 = 1;
const DIGEST_BYTES: usize = 32;

/// Packs `files` (in any order) into one row's bytes. Refuses a name given twice, a digest that is
/// not 64 lowercase hex digits, and an object key other than the digest's.
pub(crate) fn pack(task_id: &str, files: &[NewArtifact]) -> Result<Vec<u8>> {
    let refuse = |what: String| StoreError::Invalid(format!("outputs of task {task_id}: {what}"));
    let mut sorted: Vec<&NewArtifact> = files.iter().collect();
    sorted.sort_by(|a, b| a.name.cmp(&b.name));
    let mut media: Vec<&str> = Vec::new();
    let mut out = vec![VERSION];
    for f in &sorted {
        if !media.contains(&f.media_type.as_str()) {
            media.push(&f.media_type);
        }
    }
    put_varint(&mut out, media.len() as u64);
    for m in &media {
        put_str(&mut out, m);
    }
    put_varint(&mut out, sorted.len() as u64);
    let mut previous = "";
    for f in sorted {
        if f.name.is_empty() {
            return Err(refuse("a file has an empty name".into()));
        }
        if f.name == previous {
            return Err(refuse(format!("{:?} is named twice", f.name)));
        }
        let digest = digest_bytes(&f.sha256)
            .ok_or_else(|| refuse(format!("{:?}: sha256 {:?} is not 64 lowercase hex digits", f.name, f.sha256)))?;
        let key = vint_artifacts::key_for(&f.sha256).map_err(|e| refuse(e.to_string()))?;
        if f.object_key != key {
            return Err(refuse(format!(
                "{:?}: object key {:?} is not its content's ({key:?}): objects are stored by hash",
                f.name, f.object_key
            )));
        }
        let shared = shared_prefix(previous, &f.name);
        put_varint(&mut out, shared as u64);
        put_str(&mut out, &f.name[shared..]);
        let index = media.iter().position(|m| *m == f.media_type).unwrap_or_default();
        put_varint(&mut out, index as u64);
        put_varint(&mut out, f.size);
        out.extend_from_slice(&digest);
        previous = &f.name;
    }
    Ok(out)
}

/// The files packed in `bytes`, in name order, as records of task `task_id` (key `task_key`).
pub(crate) fn unpack(task_id: &str, task_key: &str, bytes: &[u8]) -> Result<Vec<ArtifactRecord>> {
    let corrupt = |what: &str| StoreError::Corrupt(format!("outputs of task {task_id}: {what}"));
    let mut r = Reader { bytes, at: 0 };
    if r.byte().ok_or_else(|| corrupt("empty"))? != VERSION {
        return Err(corrupt("unknown format version"));
    }
    let media_count = r.count().ok_or_else(|| corrupt("truncated media types"))?;
    let mut media = Vec::with_capacity(media_count);
    for _ in 0..media_count {
        media.push(r.string().ok_or_else(|| corrupt("bad media type"))?);
    }
    let count = r.count().ok_or_else(|| corrupt("truncated file count"))?;
    let mut files: Vec<ArtifactRecord> = Vec::with_capacity(count);
    let mut previous = String::new();
    for _ in 0..count {
        let shared = r.count().filter(|&n| n <= previous.len()).ok_or_else(|| corrupt("bad name prefix"))?;
        let rest = r.string().ok_or_else(|| corrupt("bad name"))?;
        let head = previous.get(..shared).ok_or_else(|| corrupt("name prefix splits a character"))?;
        let name = format!("{head}{rest}");
        if name <= previous {
            return Err(corrupt("names out of order"));
        }
        let media_type =
            r.count().and_then(|i| media.get(i)).cloned().ok_or_else(|| corrupt("bad media type index"))?;
        let size = r.varint().ok_or_else(|| corrupt("bad size"))?;
        let digest = r.take(DIGEST_BYTES).ok_or_else(|| corrupt("truncated digest"))?;
        let sha256 = hex::encode(digest);
        let object_key = vint_artifacts::key_for(&sha256).map_err(|e| corrupt(&e.to_string()))?;
        files.push(ArtifactRecord {
            task_id: task_id.to_string(),
            task_key: task_key.to_string(),
            name: name.clone(),
            sha256,
            size,
            media_type,
            object_key,
        });
        previous = name;
    }
    if r.at != bytes.len() {
        return Err(corrupt("bytes after the last file"));
    }
    Ok(files)
}

/// The samples files of these names belong to: the first path segments that are sample ids
/// (`OBJECT.HAND.gNNNNNN.vNN`; a package task's grasp records sit under grasp ids, which are not).
pub(crate) fn sample_ids<'a>(names: impl Iterator<Item = &'a str>) -> std::collections::BTreeSet<&'a str> {
    names
        .filter_map(|n| n.split_once('/').map(|(first, _)| first))
        .filter(|first| first.parse::<vint_core::sample::SampleId>().is_ok())
        .collect()
}

/// Total bytes of `files` (the row's `bytes` column, which the dashboard sums).
pub(crate) fn total_size(files: &[NewArtifact]) -> i64 {
    files.iter().map(|f| f.size).fold(0u64, u64::saturating_add).min(i64::MAX as u64) as i64
}

/// Tasks whose legacy rows one transaction of the upgrade packs.
const UPGRADE_BATCH: i64 = 500;

impl Store {
    /// Packs the rows of the table `artifacts` (one a file, before migration 0013) into `outputs`,
    /// a batch of tasks a transaction, then drops the table: `Store::migrate` runs it after the
    /// migrations; a database without the table (new, or upgraded already) is left as it is. An
    /// interrupted upgrade resumes where it stopped.
    pub(crate) async fn pack_legacy_artifacts(&self) -> Result<u64> {
        if sqlx::query(sql(self.backend, "legacy_artifacts_exists")?)
            .fetch_one(&self.pool)
            .await?
            .try_get::<i64, _>("n")?
            == 0
        {
            return Ok(0);
        }
        let mut packed = 0u64;
        loop {
            let mut tx = self.pool.begin().await?;
            let ids: Vec<String> = sqlx::query(sql(self.backend, "legacy_artifact_tasks")?)
                .bind(UPGRADE_BATCH)
                .fetch_all(&mut *tx)
                .await?
                .iter()
                .map(|r| r.try_get("task_id"))
                .collect::<std::result::Result<_, _>>()?;
            if ids.is_empty() {
                break;
            }
            let ids_json = json_text(&ids)?;
            let mut by_task: BTreeMap<String, Vec<NewArtifact>> = BTreeMap::new();
            for row in
                sqlx::query(sql(self.backend, "legacy_artifacts_of")?).bind(&ids_json).fetch_all(&mut *tx).await?
            {
                by_task.entry(row.try_get("task_id")?).or_default().push(NewArtifact {
                    name: row.try_get("name")?,
                    sha256: row.try_get("sha256")?,
                    size: u64::try_from(row.try_get::<i64, _>("size")?).unwrap_or_default(),
                    media_type: row.try_get("media_type")?,
                    object_key: row.try_get("object_key")?,
                });
            }
            let mut rows = Vec::with_capacity(by_task.len());
            for (task, files) in &by_task {
                rows.push(serde_json::json!({
                    "task": task, "files": hex::encode(pack(task, files)?), "count": files.len(),
                    "bytes": total_size(files), "samples": sample_ids(files.iter().map(|f| f.name.as_str())).len(),
                }));
            }
            sqlx::query(sql(self.backend, "insert_packed_legacy_outputs")?)
                .bind(json_text(&rows)?)
                .execute(&mut *tx)
                .await?;
            sqlx::query(sql(self.backend, "delete_legacy_artifacts")?).bind(&ids_json).execute(&mut *tx).await?;
            tx.commit().await?;
            packed += by_task.len() as u64;
        }
        sqlx::query(sql(self.backend, "drop_legacy_artifacts")?).execute(&self.pool).await?;
        Ok(packed)
    }
}

fn shared_prefix(a: &str, b: &str) -> usize {
    let mut n = a.bytes().zip(b.bytes()).take_while(|(x, y)| x == y).count();
    while !b.is_char_boundary(n) {
        n -= 1;
    }
    n
}

pub(crate) fn digest_bytes(sha256: &str) -> Option<[u8; DIGEST_BYTES]> {
    if sha256.len() != 2 * DIGEST_BYTES || !sha256.bytes().all(|b| matches!(b, b'0'..=b'9' | b'a'..=b'f')) {
        return None;
    }
    let mut digest = [0u8; DIGEST_BYTES];
    hex::decode_to_slice(sha256, &mut digest).ok()?;
    Some(digest)
}

fn put_varint(out: &mut Vec<u8>, mut v: u64) {
    while v >= 0x80 {
        out.push((v as u8) | 0x80);
        v >>= 7;
    }
    out.push(v as u8);
}

fn put_str(out: &mut Vec<u8>, s: &str) {
    put_varint(out, s.len() as u64);
    out.extend_from_slice(s.as_bytes());
}

struct Reader<'a> {
    bytes: &'a [u8],
    at: usize,
}

impl Reader<'_> {
    fn byte(&mut self) -> Option<u8> {
        let b = *self.bytes.get(self.at)?;
        self.at += 1;
        Some(b)
    }

    fn take(&mut self, n: usize) -> Option<&[u8]> {
        let end = self.at.checked_add(n)?;
        let slice = self.bytes.get(self.at..end)?;
        self.at = end;
        Some(slice)
    }

    /// An unsigned LEB128 of at most 10 bytes that fits 64 bits.
    fn varint(&mut self) -> Option<u64> {
        let mut v = 0u64;
        for shift in (0..70).step_by(7) {
            let b = self.byte()?;
            let part = u64::from(b & 0x7f);
            if shift == 63 && part > 1 {
                return None;
            }
            v |= part << shift;
            if b & 0x80 == 0 {
                return Some(v);
            }
        }
        None
    }

    /// A varint that counts something in this row: no more than its remaining bytes.
    fn count(&mut self) -> Option<usize> {
        let n = usize::try_from(self.varint()?).ok()?;
        (n <= self.bytes.len()).then_some(n)
    }

    fn string(&mut self) -> Option<String> {
        let len = self.count()?;
        String::from_utf8(self.take(len)?.to_vec()).ok()
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn file(name: &str, fill: char, size: u64, media: &str) -> NewArtifact {
        let sha256: String = std::iter::repeat_n(fill, 64).collect();
        let object_key = vint_artifacts::key_for(&sha256).unwrap();
        NewArtifact { name: name.into(), sha256, size, media_type: media.into(), object_key }
    }

    #[test]
    fn files_round_trip_in_name_order_with_derived_keys() {
        let files = vec![
            file("mug.trx3.g000012.v05/rgb.png", 'a', 123_456, "image/png"),
            file("mug.trx3.g000012.v05/depth.npy", 'b', u64::MAX, "application/x-npy"),
            file("mug.trx3.g000012/grasp.json", 'c', 0, "application/json"),
            file("é/ü.json", 'd', 1, "application/json"),
        ];
        let packed = pack("j/package/x", &files).unwrap();
        let back = unpack("j/package/x", "package/x", &packed).unwrap();
        let mut expected = files.clone();
        expected.sort_by(|a, b| a.name.cmp(&b.name));
        assert_eq!(back.len(), expected.len());
        for (b, e) in back.iter().zip(&expected) {
            assert_eq!(
                (&b.name, &b.sha256, b.size, &b.media_type, &b.object_key),
                (&e.name, &e.sha256, e.size, &e.media_type, &e.object_key)
            );
            assert_eq!((b.task_id.as_str(), b.task_key.as_str()), ("j/package/x", "package/x"));
        }
        // Front coding: less than the names in full, the digests, sizes and media types.
        let names: usize = files.iter().map(|f| f.name.len()).sum();
        let media = "image/png".len() + "application/x-npy".len() + "application/json".len();
        assert!(packed.len() + 40 < names + 4 * (32 + 10) + media, "{} bytes", packed.len());
        assert_eq!(unpack("t", "k", &pack("t", &[]).unwrap()).unwrap(), vec![]);
    }

    /// Two files packed: the format as `scripts/packed_outputs.py` reads it, pinned (its test,
    /// `tests/python/test_packed_outputs.py`, reads this constant from this file).
    const GOLDEN: &str = "0102116170706c69636174696f6e2f782d6e707909696d6167652f706e6702001e6d75672e747278332e673030303031322e7630352f64657074682e6e70790001bbbbbbbbbbbbbbbbbbbbbbbbbbbbbbbbbbbbbbbbbbbbbbbbbbbbbbbbbbbbbbbb15077267622e706e6701ac02aaaaaaaaaaaaaaaaaaaaaaaaaaaaaaaaaaaaaaaaaaaaaaaaaaaaaaaaaaaaaaaa";

    #[test]
    fn the_format_is_pinned() {
        let files = [
            file("mug.trx3.g000012.v05/rgb.png", 'a', 300, "image/png"),
            file("mug.trx3.g000012.v05/depth.npy", 'b', 1, "application/x-npy"),
        ];
        assert_eq!(hex::encode(pack("t", &files).unwrap()), GOLDEN);
    }

    #[test]
    fn bad_outputs_are_refused_with_the_file_and_rule() {
        let twice = [file("a.json", 'a', 1, "m"), file("a.json", 'b', 1, "m")];
        assert!(pack("t", &twice).unwrap_err().to_string().contains("\"a.json\" is named twice"));
        let mut upper = file("a.json", 'a', 1, "m");
        upper.sha256 = upper.sha256.to_uppercase();
        assert!(pack("t", &[upper]).unwrap_err().to_string().contains("64 lowercase hex"));
        let mut moved = file("a.json", 'a', 1, "m");
        moved.object_key = "elsewhere/a".into();
        assert!(pack("t", &[moved]).unwrap_err().to_string().contains("is not its content's"));
    }

    #[test]
    fn every_truncation_and_a_trailing_byte_are_corrupt() {
        let packed =
            pack("t", &[file("a/b.png", 'a', 300, "image/png"), file("a/c.png", 'f', 1, "image/png")]).unwrap();
        for n in 0..packed.len() {
            assert!(unpack("t", "k", &packed[..n]).is_err(), "truncated at {n}");
        }
        let mut longer = packed.clone();
        longer.push(0);
        assert!(unpack("t", "k", &longer).is_err());
        let mut version = packed;
        version[0] = 2;
        assert!(unpack("t", "k", &version).unwrap_err().to_string().contains("version"));
    }
}

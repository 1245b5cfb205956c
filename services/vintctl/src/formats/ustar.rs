//! The POSIX ustar archive format (POSIX.1-1988, as `pax` describes it), written with fixed
//! metadata so that equal members give equal bytes: regular files only, mode 0644, uid and gid 0,
//! mtime 0, no user or group names. A path longer than 100 bytes is split at a slash into the
//! header's prefix (155 bytes) and name fields.
//!
//! Shared by the WebDataset and BOP-webdataset shard writers.

use std::io::{self, Read, Write};

use anyhow::bail;

pub const BLOCK: usize = 512;
const NAME_LEN: usize = 100;
const PREFIX_LEN: usize = 155;
/// 11 octal digits.
const MAX_SIZE: u64 = (1 << 33) - 1;

/// The header block of a regular file `path` of `size` bytes.
pub fn header(path: &str, size: u64) -> anyhow::Result<[u8; BLOCK]> {
    if size > MAX_SIZE {
        bail!("member {path:?} is {size} bytes; ustar holds at most {MAX_SIZE}");
    }
    let Some((prefix, name)) = split_path(path) else {
        bail!("member path {path:?} does not fit a ustar header (100 bytes, or 155 + 100 split at a slash)");
    };
    let mut h = [0u8; BLOCK];
    h[..name.len()].copy_from_slice(name.as_bytes());
    octal(&mut h[100..108], 0o644);
    octal(&mut h[108..116], 0);
    octal(&mut h[116..124], 0);
    octal(&mut h[124..136], size);
    octal(&mut h[136..148], 0);
    h[156] = b'0';
    h[257..263].copy_from_slice(b"ustar\0");
    h[263..265].copy_from_slice(b"00");
    octal(&mut h[329..337], 0);
    octal(&mut h[337..345], 0);
    h[345..345 + prefix.len()].copy_from_slice(prefix.as_bytes());
    // The checksum is the byte sum of the header with its own field read as spaces, written as
    // six octal digits, a NUL and a space.
    h[148..156].fill(b' ');
    let sum: u32 = h.iter().map(|&b| u32::from(b)).sum();
    octal(&mut h[148..155], u64::from(sum));
    h[155] = b' ';
    Ok(h)
}

/// `(prefix, name)` for `path`: the whole path as the name when it fits, else split at the
/// first slash that leaves a name of at most 100 bytes and a prefix of at most 155.
fn split_path(path: &str) -> Option<(&str, &str)> {
    if path.is_empty() || path.contains('\0') {
        return None;
    }
    if path.len() <= NAME_LEN {
        return Some(("", path));
    }
    path.match_indices('/')
        .map(|(i, _)| (&path[..i], &path[i + 1..]))
        .find(|(prefix, name)| prefix.len() <= PREFIX_LEN && name.len() <= NAME_LEN && !name.is_empty())
}

/// Writes `value` in octal, zero-padded, into all of `field` but its last byte (a NUL).
fn octal(field: &mut [u8], value: u64) {
    let digits = field.len() - 1;
    let text = format!("{value:0digits$o}");
    field[..digits].copy_from_slice(&text.as_bytes()[text.len() - digits..]);
    field[digits] = 0;
}

/// Zero bytes that pad `size` bytes of data to a whole block.
pub fn padding(size: u64) -> usize {
    let rest = (size % BLOCK as u64) as usize;
    if rest == 0 { 0 } else { BLOCK - rest }
}

/// A ustar archive being written member by member.
pub struct Writer<W: Write> {
    out: W,
    written: u64,
}

impl<W: Write> Writer<W> {
    pub fn new(out: W) -> Self {
        Writer { out, written: 0 }
    }

    /// Appends a regular file `path` of exactly `size` bytes read from `body`.
    pub fn append(&mut self, path: &str, size: u64, body: &mut impl Read) -> anyhow::Result<()> {
        self.out.write_all(&header(path, size)?)?;
        let read = io::copy(&mut body.take(size), &mut self.out)?;
        if read != size {
            bail!("member {path:?}: expected {size} bytes, read {read}");
        }
        let pad = padding(size);
        self.out.write_all(&[0u8; BLOCK][..pad])?;
        self.written += BLOCK as u64 + size + pad as u64;
        Ok(())
    }

    /// Ends the archive (two zero blocks), flushes it, and returns its size in bytes.
    pub fn finish(mut self) -> anyhow::Result<u64> {
        self.out.write_all(&[0u8; 2 * BLOCK])?;
        self.out.flush()?;
        Ok(self.written + 2 * BLOCK as u64)
    }
}

/// Reading an archive back by hand, for the tests of the formats that write one.
#[cfg(test)]
pub mod testing {
    /// Reads a ustar field: the bytes up to the first NUL.
    pub fn field(h: &[u8], range: std::ops::Range<usize>) -> String {
        let bytes = &h[range];
        let end = bytes.iter().position(|&b| b == 0).unwrap_or(bytes.len());
        String::from_utf8(bytes[..end].to_vec()).unwrap()
    }

    pub fn octal_field(h: &[u8], range: std::ops::Range<usize>) -> u64 {
        u64::from_str_radix(field(h, range).trim(), 8).unwrap()
    }

    /// The members of a ustar archive read back by hand: (path, mode, uid, gid, mtime, data).
    pub fn read_archive(bytes: &[u8]) -> Vec<(String, u64, u64, u64, u64, Vec<u8>)> {
        assert_eq!(bytes.len() % 512, 0, "an archive is whole blocks");
        let mut members = Vec::new();
        let mut at = 0;
        loop {
            let h = &bytes[at..at + 512];
            if h.iter().all(|&b| b == 0) {
                assert!(bytes[at..].iter().all(|&b| b == 0), "nothing after the end marker");
                assert!(bytes.len() - at >= 1024, "two zero blocks end the archive");
                break;
            }
            let stored = octal_field(h, 148..156);
            let sum: u64 =
                h.iter().enumerate().map(|(i, &b)| if (148..156).contains(&i) { 32 } else { u64::from(b) }).sum();
            assert_eq!(stored, sum, "header checksum");
            assert_eq!(&h[257..263], b"ustar\0");
            assert_eq!(&h[263..265], b"00");
            assert_eq!(h[156], b'0', "a regular file");
            let (name, prefix) = (field(h, 0..100), field(h, 345..500));
            let path = if prefix.is_empty() { name } else { format!("{prefix}/{name}") };
            let size = octal_field(h, 124..136) as usize;
            let data = bytes[at + 512..at + 512 + size].to_vec();
            let padded = size.div_ceil(512) * 512;
            assert!(bytes[at + 512 + size..at + 512 + padded].iter().all(|&b| b == 0), "zero padding");
            members.push((
                path,
                octal_field(h, 100..108),
                octal_field(h, 108..116),
                octal_field(h, 116..124),
                octal_field(h, 136..148),
                data,
            ));
            at += 512 + padded;
        }
        members
    }
}

#[cfg(test)]
mod tests {
    use super::testing::read_archive;
    use super::*;

    #[test]
    fn ustar_members_read_back_with_valid_checksums_padding_and_fixed_metadata() {
        let bodies: [(&str, Vec<u8>); 4] = [
            ("a/b.rgb.png", vec![7u8; 1000]),
            ("empty.json", Vec::new()),
            ("exact.npy", vec![1u8; 512]),
            ("one.txt", b"x".to_vec()),
        ];
        let mut out = Vec::new();
        let mut w = Writer::new(&mut out);
        for (path, body) in &bodies {
            w.append(path, body.len() as u64, &mut body.as_slice()).unwrap();
        }
        let size = w.finish().unwrap();
        assert_eq!(size, out.len() as u64);
        // headers 4 × 512, data 1024 + 0 + 512 + 512, end 1024
        assert_eq!(out.len(), 4 * 512 + 2048 + 1024);
        let members = read_archive(&out);
        assert_eq!(members.len(), 4);
        for ((path, mode, uid, gid, mtime, data), (want_path, want_body)) in members.iter().zip(&bodies) {
            assert_eq!(path, want_path);
            assert_eq!((*mode, *uid, *gid, *mtime), (0o644, 0, 0, 0));
            assert_eq!(data, want_body);
        }
    }

    #[test]
    fn a_body_shorter_than_its_size_is_an_error() {
        let mut tar = Writer::new(Vec::new());
        let err = tar.append("x.bin", 10, &mut [1u8; 4].as_slice()).unwrap_err();
        assert!(err.to_string().contains("expected 10 bytes, read 4"), "{err}");
    }

    #[test]
    fn padding_fills_to_whole_blocks() {
        assert_eq!(padding(0), 0);
        assert_eq!(padding(1), 511);
        assert_eq!(padding(512), 0);
        assert_eq!(padding(513), 511);
    }
}

//! A reader for the `.npy` files a dataset holds (NumPy's format, version 1–3): little-endian
//! float32, uint8 or uint16 arrays in C order — what the engines write with `numpy.save`.
//!
//! The header is a Python dict literal, e.g. `{'descr': '<f4', 'fortran_order': False, 'shape':
//! (128, 128), }`, padded with spaces and a newline; the data follows it.

use anyhow::{Context, anyhow, bail};

const MAGIC: &[u8] = b"\x93NUMPY";

/// An array's elements, widened to f64 (exact for all three element types).
#[derive(Debug, Clone, PartialEq)]
pub struct Array {
    /// `f4`, `u1` or `u2`.
    pub dtype: &'static str,
    pub shape: Vec<usize>,
    pub values: Vec<f64>,
}

impl Array {
    /// Whether the elements are floating point (depth in metres) rather than integer labels.
    pub fn is_float(&self) -> bool {
        self.dtype == "f4"
    }
}

pub fn parse(bytes: &[u8]) -> anyhow::Result<Array> {
    let rest = bytes.strip_prefix(MAGIC).ok_or_else(|| anyhow!("not a .npy file (no \\x93NUMPY magic)"))?;
    let (&major, rest) = rest.split_first().ok_or_else(|| anyhow!("truncated .npy header"))?;
    let rest = rest.get(1..).ok_or_else(|| anyhow!("truncated .npy header"))?; // minor version
    let (header_len, rest) = match major {
        1 => {
            let len = rest.get(..2).ok_or_else(|| anyhow!("truncated .npy header"))?;
            (usize::from(u16::from_le_bytes([len[0], len[1]])), &rest[2..])
        }
        2 | 3 => {
            let len = rest.get(..4).ok_or_else(|| anyhow!("truncated .npy header"))?;
            (u32::from_le_bytes([len[0], len[1], len[2], len[3]]) as usize, &rest[4..])
        }
        v => bail!(".npy format version {v} is not supported (1, 2 or 3)"),
    };
    let header = rest.get(..header_len).ok_or_else(|| anyhow!("truncated .npy header"))?;
    let header = std::str::from_utf8(header).context(".npy header is not text")?;
    let data = &rest[header_len..];

    let descr = quoted_value(header, "descr")?;
    if dict_value(header, "fortran_order")?.starts_with("True") {
        bail!(".npy array is in Fortran order; only C order is supported");
    }
    let shape = shape(dict_value(header, "shape")?)?;
    let (dtype, size) = match descr {
        "<f4" => ("f4", 4),
        "|u1" | "<u1" => ("u1", 1),
        "<u2" => ("u2", 2),
        other => bail!(".npy dtype {other:?} is not supported (little-endian float32, uint8 or uint16)"),
    };
    let count: usize = shape.iter().product();
    if data.len() != count * size {
        bail!(".npy data holds {} bytes, the header's shape {shape:?} of {descr} needs {}", data.len(), count * size);
    }
    let values = match dtype {
        "f4" => data.chunks_exact(4).map(|c| f64::from(f32::from_le_bytes([c[0], c[1], c[2], c[3]]))).collect(),
        "u2" => data.chunks_exact(2).map(|c| f64::from(u16::from_le_bytes([c[0], c[1]]))).collect(),
        _ => data.iter().map(|&b| f64::from(b)).collect(),
    };
    Ok(Array { dtype, shape, values })
}

/// The text after `'key':` up to the end of the header.
fn dict_value<'h>(header: &'h str, key: &str) -> anyhow::Result<&'h str> {
    let quoted = format!("'{key}':");
    let at = header.find(&quoted).ok_or_else(|| anyhow!(".npy header has no {key:?}: {header:?}"))?;
    Ok(header[at + quoted.len()..].trim_start())
}

fn quoted_value<'h>(header: &'h str, key: &str) -> anyhow::Result<&'h str> {
    let value = dict_value(header, key)?;
    let inner = value.strip_prefix('\'').ok_or_else(|| anyhow!(".npy header: {key} is not a string"))?;
    let end = inner.find('\'').ok_or_else(|| anyhow!(".npy header: unterminated {key}"))?;
    Ok(&inner[..end])
}

/// `(128, 128)`, `(5,)` or `()` as dimensions.
fn shape(value: &str) -> anyhow::Result<Vec<usize>> {
    let inner = value.strip_prefix('(').and_then(|v| v.split_once(')')).map(|(inner, _)| inner);
    let inner = inner.ok_or_else(|| anyhow!(".npy header: shape is not a tuple: {value:?}"))?;
    inner
        .split(',')
        .map(str::trim)
        .filter(|d| !d.is_empty())
        .map(|d| d.parse::<usize>().map_err(|_| anyhow!(".npy header: bad dimension {d:?} in shape")))
        .collect()
}

/// Test helper: the bytes `numpy.save` writes for a C-order array (version 1 header padded to 64).
#[cfg(test)]
pub fn encode(descr: &str, shape: &[usize], data: &[u8]) -> Vec<u8> {
    encode_in_order(descr, false, shape, data)
}

#[cfg(test)]
fn encode_in_order(descr: &str, fortran: bool, shape: &[usize], data: &[u8]) -> Vec<u8> {
    let dims: Vec<String> = shape.iter().map(ToString::to_string).collect();
    let tuple = if dims.len() == 1 { format!("({},)", dims[0]) } else { format!("({})", dims.join(", ")) };
    let order = if fortran { "True" } else { "False" };
    let mut header = format!("{{'descr': '{descr}', 'fortran_order': {order}, 'shape': {tuple}, }}");
    while !(MAGIC.len() + 4 + header.len() + 1).is_multiple_of(64) {
        header.push(' ');
    }
    header.push('\n');
    let mut out = MAGIC.to_vec();
    out.extend([1, 0]);
    out.extend((header.len() as u16).to_le_bytes());
    out.extend(header.as_bytes());
    out.extend(data);
    out
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn reads_float32_uint8_and_uint16_arrays() {
        let floats: Vec<u8> = [0.5f32, -1.25, 3.0, 0.0, 1e-3, 7.5].iter().flat_map(|v| v.to_le_bytes()).collect();
        let a = parse(&encode("<f4", &[2, 3], &floats)).expect("float32");
        assert_eq!((a.dtype, a.shape.as_slice()), ("f4", &[2usize, 3][..]));
        assert_eq!(a.values, [0.5, -1.25, 3.0, 0.0, f64::from(1e-3f32), 7.5]);
        assert!(a.is_float());
        let bytes = parse(&encode("|u1", &[3], &[0, 7, 255])).expect("uint8");
        assert_eq!((bytes.is_float(), bytes.values), (false, vec![0.0, 7.0, 255.0]));
        let wide = parse(&encode("<u2", &[1, 2], &[1, 1, 255, 255])).expect("uint16");
        assert_eq!(wide.values, [257.0, 65535.0]);
    }

    #[test]
    fn refuses_what_it_cannot_read_and_says_why() {
        let message = |bytes: &[u8]| format!("{:#}", parse(bytes).expect_err("must fail"));
        assert!(message(b"PK\x03\x04").contains("not a .npy file"));
        assert!(message(&encode("<f8", &[1], &[0; 8])).contains("dtype \"<f8\""));
        assert!(message(&encode(">f4", &[1], &[0; 4])).contains("dtype \">f4\""));
        assert!(message(&encode("<f4", &[2, 2], &[0; 12])).contains("needs 16"));
        assert!(message(&encode_in_order("<f4", true, &[2, 2], &[0; 16])).contains("Fortran order"));
        assert!(message(&encode("<f4", &[2, 2], &[0; 16])[..20]).contains("truncated"));
    }

    #[test]
    fn reads_version_2_headers() {
        let mut bytes = encode("|u1", &[2], &[4, 5]);
        // Version 2: a four-byte header length.
        let header_len = u16::from_le_bytes([bytes[8], bytes[9]]);
        bytes.splice(6..10, [2u8, 0].into_iter().chain(u32::from(header_len).to_le_bytes()));
        assert_eq!(parse(&bytes).expect("v2").values, [4.0, 5.0]);
    }
}

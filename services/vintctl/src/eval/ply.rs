//! The vertices of a PLY model (ascii or binary, either byte order): all ADD and ADD-S need.
//! Faces and other elements are read only to step over them.

use std::fmt;

#[derive(Debug)]
pub enum PlyError {
    NotPly,
    Header(String),
    NoVertices,
    Truncated { element: String, record: usize },
    Ascii(String),
}

impl fmt::Display for PlyError {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        match self {
            PlyError::NotPly => write!(f, "not a PLY file (it must start with `ply`)"),
            PlyError::Header(why) => write!(f, "PLY header: {why}"),
            PlyError::NoVertices => write!(f, "PLY has no `vertex` element with x, y and z properties"),
            PlyError::Truncated { element, record } => {
                write!(f, "PLY data ends early (element {element}, record {record})")
            }
            PlyError::Ascii(why) => write!(f, "PLY ascii data: {why}"),
        }
    }
}

impl std::error::Error for PlyError {}

#[derive(Clone, Copy, PartialEq)]
enum Encoding {
    Ascii,
    Little,
    Big,
}

#[derive(Clone, Copy)]
enum Scalar {
    I8,
    U8,
    I16,
    U16,
    I32,
    U32,
    F32,
    F64,
}

impl Scalar {
    fn parse(name: &str) -> Option<Scalar> {
        Some(match name {
            "char" | "int8" => Scalar::I8,
            "uchar" | "uint8" => Scalar::U8,
            "short" | "int16" => Scalar::I16,
            "ushort" | "uint16" => Scalar::U16,
            "int" | "int32" => Scalar::I32,
            "uint" | "uint32" => Scalar::U32,
            "float" | "float32" => Scalar::F32,
            "double" | "float64" => Scalar::F64,
            _ => return None,
        })
    }

    fn size(self) -> usize {
        match self {
            Scalar::I8 | Scalar::U8 => 1,
            Scalar::I16 | Scalar::U16 => 2,
            Scalar::I32 | Scalar::U32 | Scalar::F32 => 4,
            Scalar::F64 => 8,
        }
    }

    /// The value at the start of `bytes` (which holds at least `size()` bytes).
    fn read(self, bytes: &[u8], encoding: Encoding) -> f64 {
        macro_rules! num {
            ($t:ty, $n:expr) => {{
                let mut a = [0u8; $n];
                a.copy_from_slice(&bytes[..$n]);
                f64::from(if encoding == Encoding::Big { <$t>::from_be_bytes(a) } else { <$t>::from_le_bytes(a) })
            }};
        }
        match self {
            Scalar::I8 => num!(i8, 1),
            Scalar::U8 => num!(u8, 1),
            Scalar::I16 => num!(i16, 2),
            Scalar::U16 => num!(u16, 2),
            Scalar::I32 => num!(i32, 4),
            Scalar::U32 => num!(u32, 4),
            Scalar::F32 => num!(f32, 4),
            Scalar::F64 => num!(f64, 8),
        }
    }
}

enum Property {
    Scalar { name: String, kind: Scalar },
    List { count: Scalar, item: Scalar },
}

struct Element {
    name: String,
    count: usize,
    properties: Vec<Property>,
}

/// The `x y z` of every vertex, in the file's units, in file order.
pub fn vertices(bytes: &[u8]) -> Result<Vec<[f64; 3]>, PlyError> {
    let (encoding, elements, body) = header(bytes)?;
    let mut body = Body { bytes: body, at: 0, encoding, tokens: None };
    for element in &elements {
        if element.name == "vertex" {
            return read_vertices(&mut body, element);
        }
        for record in 0..element.count {
            for property in &element.properties {
                body.skip(property).map_err(|why| short(why, element, record))?;
            }
        }
    }
    Err(PlyError::NoVertices)
}

fn short(why: Short, element: &Element, record: usize) -> PlyError {
    match why {
        Short::End => PlyError::Truncated { element: element.name.clone(), record },
        Short::NotNumber(word) => {
            PlyError::Ascii(format!("{word:?} is not a number (element {}, record {record})", element.name))
        }
    }
}

fn read_vertices(body: &mut Body, element: &Element) -> Result<Vec<[f64; 3]>, PlyError> {
    let column =
        |axis: &str| element.properties.iter().position(|p| matches!(p, Property::Scalar { name, .. } if name == axis));
    let (Some(x), Some(y), Some(z)) = (column("x"), column("y"), column("z")) else {
        return Err(PlyError::NoVertices);
    };
    let mut points = Vec::with_capacity(element.count);
    let mut values = vec![0.0; element.properties.len()];
    for record in 0..element.count {
        for (k, property) in element.properties.iter().enumerate() {
            values[k] = match property {
                Property::Scalar { kind, .. } => body.scalar(*kind).map_err(|why| short(why, element, record))?,
                list @ Property::List { .. } => {
                    body.skip(list).map_err(|why| short(why, element, record))?;
                    0.0
                }
            };
        }
        points.push([values[x], values[y], values[z]]);
    }
    Ok(points)
}

type Header<'a> = (Encoding, Vec<Element>, &'a [u8]);

fn header(bytes: &[u8]) -> Result<Header<'_>, PlyError> {
    const END: &[u8] = b"end_header";
    if !bytes.starts_with(b"ply") {
        return Err(PlyError::NotPly);
    }
    let end = bytes.windows(END.len()).position(|w| w == END).ok_or(PlyError::Header("no end_header".into()))?;
    let mut body_start = end + END.len();
    // The line ends with \n (or \r\n); the body starts right after it.
    while body_start < bytes.len() && bytes[body_start] != b'\n' {
        body_start += 1;
    }
    body_start = (body_start + 1).min(bytes.len());
    let text = std::str::from_utf8(&bytes[..end]).map_err(|_| PlyError::Header("not ASCII".into()))?;
    let mut encoding = None;
    let mut elements: Vec<Element> = Vec::new();
    for line in text.lines().skip(1) {
        let words: Vec<&str> = line.split_whitespace().collect();
        let bad = || PlyError::Header(format!("cannot read line {line:?}"));
        match words.as_slice() {
            [] | ["comment", ..] | ["obj_info", ..] => {}
            ["format", kind, _version] => {
                encoding = Some(match *kind {
                    "ascii" => Encoding::Ascii,
                    "binary_little_endian" => Encoding::Little,
                    "binary_big_endian" => Encoding::Big,
                    _ => return Err(bad()),
                });
            }
            ["element", name, count] => {
                let count = count.parse().map_err(|_| bad())?;
                elements.push(Element { name: (*name).to_string(), count, properties: Vec::new() });
            }
            ["property", "list", count, item, _name] => {
                let (count, item) = (Scalar::parse(count).ok_or_else(bad)?, Scalar::parse(item).ok_or_else(bad)?);
                elements.last_mut().ok_or_else(bad)?.properties.push(Property::List { count, item });
            }
            ["property", kind, name] => {
                let kind = Scalar::parse(kind).ok_or_else(bad)?;
                let property = Property::Scalar { name: (*name).to_string(), kind };
                elements.last_mut().ok_or_else(bad)?.properties.push(property);
            }
            _ => return Err(bad()),
        }
    }
    let encoding = encoding.ok_or(PlyError::Header("no format line".into()))?;
    Ok((encoding, elements, &bytes[body_start..]))
}

/// The data after the header, read in order.
struct Body<'a> {
    bytes: &'a [u8],
    at: usize,
    encoding: Encoding,
    /// Ascii only: the whitespace-separated words of the body.
    tokens: Option<std::str::SplitAsciiWhitespace<'a>>,
}

/// Why the body could not give the next value.
enum Short {
    End,
    NotNumber(String),
}

impl Body<'_> {
    fn scalar(&mut self, kind: Scalar) -> Result<f64, Short> {
        if self.encoding == Encoding::Ascii {
            let word = self.word().ok_or(Short::End)?;
            return word.parse::<f64>().map_err(|_| Short::NotNumber(word.to_string()));
        }
        let size = kind.size();
        let slice = self.bytes.get(self.at..self.at + size).ok_or(Short::End)?;
        self.at += size;
        Ok(kind.read(slice, self.encoding))
    }

    fn word(&mut self) -> Option<&str> {
        if self.tokens.is_none() {
            // Non-UTF-8 bytes in an ascii body cannot be numbers: read as an early end.
            let text = std::str::from_utf8(self.bytes).unwrap_or("");
            self.tokens = Some(text.split_ascii_whitespace());
        }
        self.tokens.as_mut()?.next()
    }

    fn skip(&mut self, property: &Property) -> Result<(), Short> {
        match property {
            Property::Scalar { kind, .. } => self.scalar(*kind).map(|_| ()),
            Property::List { count, item } => {
                let n = self.scalar(*count)?;
                if !(0.0..=f64::from(u32::MAX)).contains(&n) || n.fract() != 0.0 {
                    return Err(Short::NotNumber(format!("list length {n}")));
                }
                for _ in 0..n as usize {
                    self.scalar(*item)?;
                }
                Ok(())
            }
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn binary(order: &str, header_extra: &str, face_first: bool) -> Vec<u8> {
        let big = order == "binary_big_endian";
        let f32b = |v: f32| if big { v.to_be_bytes() } else { v.to_le_bytes() };
        let i32b = |v: i32| if big { v.to_be_bytes() } else { v.to_le_bytes() };
        let faces = "element face 1\nproperty list uchar int vertex_indices\n";
        let vertices = "element vertex 2\nproperty float x\nproperty float y\nproperty float z\nproperty uchar red\n";
        let elements = if face_first { format!("{faces}{vertices}") } else { format!("{vertices}{faces}") };
        let mut out =
            format!("ply\nformat {order} 1.0\ncomment units mm\n{header_extra}{elements}end_header\n").into_bytes();
        let mut face = vec![3u8];
        for i in [0, 1, 1] {
            face.extend_from_slice(&i32b(i));
        }
        let mut verts = Vec::new();
        for (p, colour) in [([1.5f32, -2.0, 3.25], 9u8), ([4.0, 5.0, -6.5], 200)] {
            for v in p {
                verts.extend_from_slice(&f32b(v));
            }
            verts.push(colour);
        }
        if face_first {
            out.extend(face);
            out.extend(verts);
        } else {
            out.extend(verts);
            out.extend(face);
        }
        out
    }

    const EXPECTED: [[f64; 3]; 2] = [[1.5, -2.0, 3.25], [4.0, 5.0, -6.5]];

    #[test]
    fn reads_binary_vertices_in_either_byte_order_past_other_elements() {
        for order in ["binary_little_endian", "binary_big_endian"] {
            for face_first in [false, true] {
                assert_eq!(vertices(&binary(order, "", face_first)).unwrap(), EXPECTED, "{order} {face_first}");
            }
        }
    }

    #[test]
    fn reads_ascii_vertices() {
        let text = "ply\nformat ascii 1.0\nelement vertex 2\nproperty double x\nproperty double y\n\
                    property double z\nelement face 1\nproperty list uchar int vertex_indices\nend_header\n\
                    1.5 -2 3.25\n4 5 -6.5\n3 0 1 1\n";
        assert_eq!(vertices(text.as_bytes()).unwrap(), EXPECTED);
    }

    #[test]
    fn rejects_what_is_not_a_model() {
        assert!(matches!(vertices(b"solid stl"), Err(PlyError::NotPly)));
        let mut short = binary("binary_little_endian", "", false);
        short.truncate(short.len() - 20);
        assert!(matches!(vertices(&short), Err(PlyError::Truncated { .. })));
        let no_xyz = b"ply\nformat ascii 1.0\nelement vertex 1\nproperty float u\nend_header\n1\n";
        assert!(matches!(vertices(no_xyz), Err(PlyError::NoVertices)));
        assert!(matches!(
            vertices(b"ply\nformat ascii 1.0\nelement vertex 1\nproperty float x\n"),
            Err(PlyError::Header(_))
        ));
    }
}

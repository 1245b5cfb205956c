//! Dataset formats other than the native layout: each converts a native dataset directory into
//! its own layout in a fresh staging directory.

pub mod bop;

/// What a conversion wrote.
#[derive(Debug, Clone, Copy, Default, PartialEq, Eq)]
pub struct Converted {
    pub samples: usize,
    pub files: usize,
    pub bytes: u64,
}

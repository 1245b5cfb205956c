//! The dataset formats an export can write (scaffold on wt/wds until the lead's plumbing lands on
//! main; at the merge main's file wins).

pub mod webdataset;

/// What a conversion wrote.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub struct Converted {
    pub samples: usize,
    pub files: usize,
    pub bytes: u64,
}

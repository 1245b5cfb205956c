//! The four pipeline stages and their order.

use std::fmt;
use std::str::FromStr;

/// A pipeline stage. A task belongs to exactly one stage; a worker serves one or more.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash, PartialOrd, Ord)]
pub enum Stage {
    Grasp,
    Render,
    Noise,
    Package,
}

impl Stage {
    pub const ALL: [Stage; 4] = [Stage::Grasp, Stage::Render, Stage::Noise, Stage::Package];

    pub fn as_str(self) -> &'static str {
        match self {
            Stage::Grasp => "grasp",
            Stage::Render => "render",
            Stage::Noise => "noise",
            Stage::Package => "package",
        }
    }

    /// Lease priority: lower first. Downstream stages go first so that samples finish (and free
    /// their intermediate artifacts) before more upstream work starts: depth-first progress.
    pub fn lease_priority(self) -> i64 {
        match self {
            Stage::Package => 0,
            Stage::Noise => 1,
            Stage::Render => 2,
            Stage::Grasp => 3,
        }
    }

    /// Whether the stage runs in a Python engine (as opposed to pure Rust in the worker).
    pub fn has_engine(self) -> bool {
        !matches!(self, Stage::Package)
    }
}

impl fmt::Display for Stage {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        f.write_str(self.as_str())
    }
}

#[derive(Debug, thiserror::Error)]
#[error("unknown stage {0:?}: expected one of grasp, render, noise, package")]
pub struct UnknownStage(pub String);

impl FromStr for Stage {
    type Err = UnknownStage;
    fn from_str(s: &str) -> Result<Self, Self::Err> {
        Stage::ALL.into_iter().find(|st| st.as_str() == s).ok_or_else(|| UnknownStage(s.to_string()))
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn stage_names_round_trip() {
        for st in Stage::ALL {
            assert_eq!(st.as_str().parse::<Stage>().unwrap(), st);
        }
        assert!("paint".parse::<Stage>().is_err());
    }

    #[test]
    fn downstream_stages_lease_first() {
        assert!(Stage::Package.lease_priority() < Stage::Noise.lease_priority());
        assert!(Stage::Noise.lease_priority() < Stage::Render.lease_priority());
        assert!(Stage::Render.lease_priority() < Stage::Grasp.lease_priority());
    }
}

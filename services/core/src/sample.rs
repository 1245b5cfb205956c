//! Sample identity: one view of one accepted grasp of one object by one hand; and the grasp's own
//! identity, which the samples of its views share.

use std::fmt;
use std::str::FromStr;

#[derive(Clone, Debug, PartialEq, Eq, Hash, PartialOrd, Ord)]
pub struct SampleId {
    pub object: String,
    pub hand: String,
    pub grasp_index: u32,
    pub view_index: u32,
}

impl fmt::Display for SampleId {
    /// `tomato_soup_can.trx3.g000003.v01` — names cannot contain dots (see spec validation).
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        write!(f, "{}.{}.g{:06}.v{:02}", self.object, self.hand, self.grasp_index, self.view_index)
    }
}

#[derive(Debug, thiserror::Error)]
#[error("sample id {0:?} is not of the form OBJECT.HAND.gNNNNNN.vNN")]
pub struct BadSampleId(pub String);

impl FromStr for SampleId {
    type Err = BadSampleId;
    fn from_str(s: &str) -> Result<Self, Self::Err> {
        let bad = || BadSampleId(s.to_string());
        let (grasp, view) = s.rsplit_once('.').ok_or_else(bad)?;
        let grasp: GraspId = grasp.parse().map_err(|_| bad())?;
        let view_index = view.strip_prefix('v').and_then(|v| v.parse().ok()).ok_or_else(bad)?;
        Ok(grasp.view(view_index))
    }
}

impl SampleId {
    /// The grasp this sample is a view of.
    pub fn grasp(&self) -> GraspId {
        GraspId { object: self.object.clone(), hand: self.hand.clone(), grasp_index: self.grasp_index }
    }
}

/// One accepted grasp of one object by one hand: `tomato_soup_can.trx3.g000003`. Its samples' ids
/// are this plus `.vNN`.
#[derive(Clone, Debug, PartialEq, Eq, Hash, PartialOrd, Ord)]
pub struct GraspId {
    pub object: String,
    pub hand: String,
    pub grasp_index: u32,
}

impl GraspId {
    pub fn view(&self, view_index: u32) -> SampleId {
        SampleId { object: self.object.clone(), hand: self.hand.clone(), grasp_index: self.grasp_index, view_index }
    }
}

impl fmt::Display for GraspId {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        write!(f, "{}.{}.g{:06}", self.object, self.hand, self.grasp_index)
    }
}

#[derive(Debug, thiserror::Error)]
#[error("grasp id {0:?} is not of the form OBJECT.HAND.gNNNNNN (OBJECT and HAND: 1 to 64 of a-z, 0-9 and _)")]
pub struct BadGraspId(pub String);

impl FromStr for GraspId {
    type Err = BadGraspId;
    fn from_str(s: &str) -> Result<Self, Self::Err> {
        let bad = || BadGraspId(s.to_string());
        let parts: Vec<&str> = s.split('.').collect();
        let [object, hand, grasp] = parts.as_slice() else {
            return Err(bad());
        };
        let grasp_index = grasp.strip_prefix('g').and_then(|g| g.parse().ok()).ok_or_else(bad)?;
        // Ids become directory and tar member names: only the names a spec may give (no `/`, no
        // `..`, nothing absolute), whoever wrote the manifest or the row they are read from.
        if !is_name(object) || !is_name(hand) {
            return Err(bad());
        }
        Ok(GraspId { object: object.to_string(), hand: hand.to_string(), grasp_index })
    }
}

/// A name as a spec gives objects and hands: 1 to 64 of `a-z`, `0-9` and `_`.
fn is_name(s: &str) -> bool {
    !s.is_empty() && s.len() <= 64 && s.bytes().all(|b| b.is_ascii_lowercase() || b.is_ascii_digit() || b == b'_')
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn sample_ids_round_trip() {
        let id = SampleId { object: "tomato_soup_can".into(), hand: "trx3".into(), grasp_index: 3, view_index: 1 };
        assert_eq!(id.to_string(), "tomato_soup_can.trx3.g000003.v01");
        assert_eq!(id.to_string().parse::<SampleId>().unwrap(), id);
    }

    #[test]
    fn a_sample_id_is_its_grasp_id_and_view() {
        let id: SampleId = "mug.allegro.g000012.v05".parse().unwrap();
        assert_eq!(id.grasp().to_string(), "mug.allegro.g000012");
        assert_eq!(id.grasp().view(5), id);
        assert_eq!("mug.allegro.g000012".parse::<GraspId>().unwrap(), id.grasp());
        assert!("mug.allegro.g000012.v05".parse::<GraspId>().is_err());
        assert!("mug.allegro.g000012".parse::<SampleId>().is_err());
    }

    #[test]
    fn malformed_sample_ids_are_rejected() {
        for bad in [
            "",
            "a.b.c",
            "a.b.g1.x1",
            "a.b.gx.v1",
            ".b.g1.v1",
            "a.b.g1.v1.extra",
            "../../etc.b.g1.v1",
            "/etc/passwd.trx3.g000001.v01",
            "a/b.trx3.g000001.v01",
            "a.tr x3.g000001.v01",
            "Mug.trx3.g000001.v01",
        ] {
            assert!(bad.parse::<SampleId>().is_err(), "{bad}");
        }
    }
}

//! "Did you mean …?": the known name nearest to a misspelt one, for spec errors that report an
//! unknown key or an unknown hand, object, modality or HDRI.

/// The candidate `word` most likely meant, if one is close enough. Closeness is edits (insert,
/// delete, replace, swap two neighbours; case ignored), accepted within a third of the longer
/// name's length (at least 2). A cut-off name counts as one edit when one candidate alone starts
/// with it (`hold` → `hold_s`, `tomato_soup` → `tomato_soup_can`), and a candidate the word starts
/// with as at most two (`gripper` → `grip`). The closest wins; ties go to the earlier candidate.
pub fn nearest<'a>(word: &str, candidates: impl IntoIterator<Item = &'a str>) -> Option<&'a str> {
    let candidates: Vec<&str> = candidates.into_iter().filter(|c| *c != word).collect();
    let word = word.to_ascii_lowercase();
    let lower: Vec<String> = candidates.iter().map(|c| c.to_ascii_lowercase()).collect();
    let long_enough = |n: usize| n >= 3;
    let truncations: Vec<usize> =
        (0..lower.len()).filter(|&i| long_enough(word.len()) && lower[i].starts_with(&word)).collect();
    let mut best: Option<(usize, &str)> = None;
    for (i, c) in lower.iter().enumerate() {
        let d = edit_distance(&word, c);
        let closeness = if truncations == [i] {
            1
        } else if long_enough(c.len()) && word.starts_with(c.as_str()) {
            d.min(2)
        } else if d <= (word.len().max(c.len()) / 3).max(2) {
            d
        } else {
            continue;
        };
        if best.is_none_or(|(b, _)| closeness < b) {
            best = Some((closeness, candidates[i]));
        }
    }
    best.map(|(_, c)| c)
}

/// Edits between `a` and `b`: insertions, deletions, substitutions and swaps of two neighbouring
/// characters (optimal string alignment).
fn edit_distance(a: &str, b: &str) -> usize {
    let (a, b): (Vec<char>, Vec<char>) = (a.chars().collect(), b.chars().collect());
    // rows[i][j]: edits between a[..i] and b[..j]; only the last three rows are needed.
    let mut before: Vec<usize> = Vec::new();
    let mut previous: Vec<usize> = (0..=b.len()).collect();
    for i in 1..=a.len() {
        let mut row = vec![i; b.len() + 1];
        for j in 1..=b.len() {
            let substitution = previous[j - 1] + usize::from(a[i - 1] != b[j - 1]);
            row[j] = substitution.min(previous[j] + 1).min(row[j - 1] + 1);
            if i > 1 && j > 1 && a[i - 1] == b[j - 2] && a[i - 2] == b[j - 1] {
                row[j] = row[j].min(before[j - 2] + 1);
            }
        }
        before = std::mem::replace(&mut previous, row);
    }
    previous[b.len()]
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn edit_distance_counts_inserts_deletes_replacements_and_swaps() {
        assert_eq!(edit_distance("", "abc"), 3);
        assert_eq!(edit_distance("hold", "hold_s"), 2);
        assert_eq!(edit_distance("samples", "sampels"), 1, "a swap of neighbours is one edit");
        assert_eq!(edit_distance("kitten", "sitting"), 3);
        assert_eq!(edit_distance("same", "same"), 0);
    }

    #[test]
    fn a_misspelt_key_or_name_finds_what_was_meant() {
        let grasp = [
            "trials_per_pair",
            "accepted_per_pair",
            "chunk_size",
            "timestep_s",
            "lift_height_m",
            "hold_s",
            "max_drop_m",
        ];
        assert_eq!(nearest("hold", grasp), Some("hold_s"));
        assert_eq!(nearest("hold_seconds", grasp), Some("hold_s"));
        assert_eq!(nearest("chunksize", grasp), Some("chunk_size"));
        assert_eq!(nearest("Timestep_S", grasp), Some("timestep_s"), "case is ignored");
        let objects = ["tomato_soup_can", "mustard_bottle", "mug", "large_marker"];
        assert_eq!(nearest("tomato_soup", objects), Some("tomato_soup_can"));
        assert_eq!(nearest("mustard_botle", objects), Some("mustard_bottle"));
        assert_eq!(nearest("forrest", ["city", "forest", "studio"]), Some("forest"));
        assert_eq!(nearest("dpeth", ["rgb", "depth", "depth_noisy"]), Some("depth"));
        assert_eq!(nearest("depth_noisey", ["rgb", "depth", "depth_noisy"]), Some("depth_noisy"));
        assert_eq!(nearest("gripper", ["trx3", "allegro", "grip"]), Some("grip"));
        let object = ["mesh", "unit", "mass_kg", "material", "symmetry"];
        assert_eq!(nearest("mass", object), Some("mass_kg"), "a cut-off name beats a two-letter change");
    }

    #[test]
    fn nothing_is_suggested_when_nothing_is_close() {
        let render = ["resolution", "samples", "denoise", "fov_deg"];
        assert_eq!(nearest("colour_space", render), None);
        assert_eq!(nearest("xyz", ["rgb", "depth"]), None);
        // Two keys extend "shake": neither is assumed; nor is a 2-letter prefix enough.
        assert_eq!(nearest("shake", ["shake_accel_mps2", "shake_directions", "shake_duration_s"]), None);
        assert_eq!(nearest("fo", ["fov_deg", "foo_bar_baz"]), None);
    }
}

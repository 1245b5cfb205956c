//! `vintctl study touch --quick`: the touch-vs-vision study run end to end as a user runs it —
//! vintctl makes the study's dataset, the engines' Python fits and scores both variants.

use vint_tests::*;

#[test]
fn quick_touch_study_writes_both_variants_for_every_view() {
    let tmp = tempfile::tempdir().unwrap();
    let out = tmp.path().join("study");
    let work = tmp.path().join("work");
    let o =
        vintctl(&["study", "touch", "--out", out.to_str().unwrap(), "--quick", "--", "--work", work.to_str().unwrap()]);
    assert!(o.status.success(), "{}\n{}", stdout(&o), stderr(&o));
    for f in ["touch_vs_vision.csv", "touch_vs_vision_summary.csv", "touch_vs_vision.png", "touch_vs_vision.md"] {
        assert!(out.join(f).metadata().map(|m| m.len() > 0).unwrap_or(false), "{f} missing");
    }
    let md = std::fs::read_to_string(out.join("touch_vs_vision.md")).unwrap();
    assert!(md.contains("**Finding.**"), "the report states its finding:\n{md}");

    // One row per (view, variant): both variants, for the same views, as many as the dataset has.
    let csv = std::fs::read_to_string(out.join("touch_vs_vision.csv")).unwrap();
    let header: Vec<&str> = csv.lines().next().unwrap().split(',').collect();
    let col = |name: &str| header.iter().position(|h| *h == name).unwrap_or_else(|| panic!("no column {name}"));
    let (sample, variant) = (col("sample_id"), col("variant"));
    let mut by_variant: std::collections::BTreeMap<String, Vec<String>> = Default::default();
    for line in csv.lines().skip(1) {
        let cells: Vec<&str> = line.split(',').collect();
        by_variant.entry(cells[variant].to_string()).or_default().push(cells[sample].to_string());
    }
    assert_eq!(by_variant.keys().map(String::as_str).collect::<Vec<_>>(), ["vision", "vision_touch"]);
    let samples = verify_dataset(&work.join("data")).len();
    assert!(samples > 0);
    for (name, ids) in &by_variant {
        assert_eq!(ids.len(), samples, "{name}: one row per sample of the study's dataset");
    }
    assert_eq!(by_variant["vision"], by_variant["vision_touch"]);

    // Both estimates are also BOP results files, one line per view.
    for name in ["vision", "vision_touch"] {
        let results = std::fs::read_to_string(work.join("estimates").join(format!("{name}.csv"))).unwrap();
        assert_eq!(results.lines().next(), Some("scene_id,im_id,obj_id,score,R,t,time"));
        assert_eq!(results.lines().count(), samples + 1);
    }
}

//! `vintctl diff A B`: compares two exported datasets (directories with `manifest.jsonl`) file by
//! file, with a tolerance per kind of file, and says which samples differ and by how much.
//!
//! Byte-identity is a promise per machine build; across CPUs (AVX-512 or AVX2 paths in numpy and
//! MuJoCo) and render set-ups, datasets agree within tolerances (docs/reproducibility.md). Every
//! file both manifests list is compared, by type rather than by name, so files the package stage
//! adds later are compared too: `.png` colour images as RGB (`pixels::compare_rgb`),
//! single-channel ones as labels (masks, segmentation) but for a depth file (`depth.png`,
//! `depth_noisy.png`: read as metres by `crate::depth`, the one rule for native depth), `.npy`
//! float arrays as depth in metres and integer ones as labels, `.json` documents number by number (`json`); other files must be
//! identical. Files with the same SHA-256 in both manifests are not read.
//!
//! Owns no dataset layout beyond the manifest's: a line has a `sample_id` (or another `*_id`) and
//! `files` mapping names to `{sha256, …}`; a file lies at its entry's `path`, or at
//! `<name>` when the name has a directory, else at `<sample_id>/<name>`.

mod json;
pub(crate) mod npy;
pub(crate) mod pixels;

use std::collections::{BTreeMap, BTreeSet};
use std::path::{Path, PathBuf};

use anyhow::{Context, anyhow};
use serde::Serialize;

use crate::{CliResult, Failure, bad_input};

// Default tolerances, set from a measurement (docs/reproducibility.md): examples/tiny.toml run with
// numpy's AVX-512 paths on, and again with them off and OpenBLAS on its AVX2 kernels, differed by
// at most 1.2e-8 m in positions, 2.6e-7 in rotations, 1.3e-6 in touch readings, 2.3e-7 relative in
// contact forces, 6.4 µm in depth, not one label pixel; 7 of 72 RGB images differed in 1 to 6
// pixels (≤ 0.04 %), by 1 level but for two single pixels at 7 and 12 levels: at 16 samples per
// pixel one path of 16 going another way moves a pixel by up to 255/16 ≈ 16 levels. The defaults
// sit well above what was measured and well below what matters to a user of the data (0.1 mm,
// ~0.01°, a pixel in a thousand).
pub const DEFAULT_RGB_LEVELS: u16 = 16;
pub const DEFAULT_RGB_SHARE: f64 = 0.001;
pub const DEFAULT_DEPTH_M: f64 = 1e-4;
pub const DEFAULT_DEPTH_INVALID_SHARE: f64 = 0.001;
pub const DEFAULT_LABEL_SHARE: f64 = 0.001;
pub const DEFAULT_POSITION_M: f64 = 1e-4;
pub const DEFAULT_ROTATION: f64 = 1e-4;
pub const DEFAULT_TOUCH: f64 = 1e-3;
pub const DEFAULT_RELATIVE: f64 = 1e-3;

/// The two datasets and the tolerances they are compared with.
#[derive(clap::Args, Debug)]
pub struct DiffArgs {
    /// The reference dataset: a directory with manifest.jsonl (written by `vintctl run` or `export`).
    pub a: PathBuf,
    /// The dataset compared with it.
    pub b: PathBuf,
    #[command(flatten)]
    pub tolerances: Tolerances,
}

/// How far two files of a kind may differ and still count as the same.
#[derive(clap::Args, Debug, Clone, Serialize)]
pub struct Tolerances {
    /// RGB images: the largest difference of any channel, in 8-bit levels.
    #[arg(long, default_value_t = DEFAULT_RGB_LEVELS, value_name = "LEVELS")]
    pub rgb_levels: u16,
    /// RGB images: the largest share (0–1) of pixels that may differ at all.
    #[arg(long, default_value_t = DEFAULT_RGB_SHARE, value_parser = share, value_name = "SHARE")]
    pub rgb_share: f64,
    /// Depth maps: the largest difference in metres where both have a return.
    #[arg(long, default_value_t = DEFAULT_DEPTH_M, value_parser = non_negative, value_name = "METRES")]
    pub depth_m: f64,
    /// Depth maps: the largest share (0–1) of pixels with a return in only one of the two.
    #[arg(long, default_value_t = DEFAULT_DEPTH_INVALID_SHARE, value_parser = share, value_name = "SHARE")]
    pub depth_invalid_share: f64,
    /// Label images (masks, segmentation): the largest share (0–1) of pixels whose label differs.
    #[arg(long, default_value_t = DEFAULT_LABEL_SHARE, value_parser = share, value_name = "SHARE")]
    pub label_share: f64,
    /// JSON: positions, translations and other lengths, in metres (absolute).
    #[arg(long, default_value_t = DEFAULT_POSITION_M, value_parser = non_negative, value_name = "METRES")]
    pub position_m: f64,
    /// JSON: quaternion and rotation-matrix components, unit normals, angles in radians (absolute).
    #[arg(long, default_value_t = DEFAULT_ROTATION, value_parser = non_negative, value_name = "ABS")]
    pub rotation: f64,
    /// JSON: touch readings (absolute; a saturated taxel reads about 1).
    #[arg(long, default_value_t = DEFAULT_TOUCH, value_parser = non_negative, value_name = "ABS")]
    pub touch: f64,
    /// JSON: every other non-integer number, relative to the larger of the two (absolute below 1).
    #[arg(long, default_value_t = DEFAULT_RELATIVE, value_parser = non_negative, value_name = "REL")]
    pub relative: f64,
}

impl Default for Tolerances {
    fn default() -> Self {
        Tolerances {
            rgb_levels: DEFAULT_RGB_LEVELS,
            rgb_share: DEFAULT_RGB_SHARE,
            depth_m: DEFAULT_DEPTH_M,
            depth_invalid_share: DEFAULT_DEPTH_INVALID_SHARE,
            label_share: DEFAULT_LABEL_SHARE,
            position_m: DEFAULT_POSITION_M,
            rotation: DEFAULT_ROTATION,
            touch: DEFAULT_TOUCH,
            relative: DEFAULT_RELATIVE,
        }
    }
}

fn non_negative(text: &str) -> Result<f64, String> {
    match text.parse::<f64>() {
        Ok(v) if v.is_finite() && v >= 0.0 => Ok(v),
        _ => Err(format!("must be a finite number ≥ 0, got {text:?}")),
    }
}

fn share(text: &str) -> Result<f64, String> {
    match text.parse::<f64>() {
        Ok(v) if (0.0..=1.0).contains(&v) => Ok(v),
        _ => Err(format!("must be a share between 0 and 1, got {text:?}")),
    }
}

/// One measured difference and the tolerance it is held to.
#[derive(Debug, Clone, Serialize)]
pub struct Measure {
    pub name: &'static str,
    pub value: f64,
    pub tolerance: f64,
    pub unit: &'static str,
    /// Where the difference is largest (a pixel, a JSON path) or how many pixels it covers.
    #[serde(skip_serializing_if = "Option::is_none")]
    pub at: Option<String>,
}

impl Measure {
    pub fn new(name: &'static str, value: f64, tolerance: f64, unit: &'static str) -> Measure {
        Measure { name, value, tolerance, unit, at: None }
    }

    pub fn at(mut self, at: String) -> Measure {
        self.at = Some(at);
        self
    }

    pub fn within(&self) -> bool {
        self.value <= self.tolerance
    }

    /// How many tolerances away: what ranks the worst difference.
    fn excess(&self) -> f64 {
        if self.tolerance > 0.0 {
            self.value / self.tolerance
        } else if self.value > 0.0 {
            f64::INFINITY
        } else {
            0.0
        }
    }
}

/// How one file of B compares with its counterpart in A.
#[derive(Debug, Clone, Serialize)]
pub struct Finding {
    pub measures: Vec<Measure>,
    /// Differences no tolerance covers: another size or shape, a key on one side only, a file
    /// that cannot be read.
    pub notes: Vec<String>,
}

impl Finding {
    pub fn measured(measures: Vec<Measure>) -> Finding {
        Finding { measures, notes: Vec::new() }
    }

    pub fn structural(note: String) -> Finding {
        Finding { measures: Vec::new(), notes: vec![note] }
    }

    pub fn within(&self) -> bool {
        self.notes.is_empty() && self.measures.iter().all(Measure::within)
    }

    fn worst(&self) -> Option<&Measure> {
        self.measures.iter().max_by(|x, y| x.excess().total_cmp(&y.excess()))
    }
}

/// A file as a manifest lists it.
#[derive(Debug, Clone)]
struct Listed {
    sha256: String,
    /// Relative to the dataset's directory.
    path: PathBuf,
}

/// A dataset's manifest: entry (sample) id → file name → file.
#[derive(Debug)]
struct Manifest {
    dir: PathBuf,
    entries: BTreeMap<String, BTreeMap<String, Listed>>,
}

impl Manifest {
    fn read(dir: &Path, side: &str) -> Result<Manifest, Failure> {
        let path = dir.join("manifest.jsonl");
        let text = std::fs::read_to_string(&path).map_err(|e| {
            bad_input(anyhow!("{side} {}: not a dataset: cannot read manifest.jsonl ({e})", dir.display()))
        })?;
        let mut entries = BTreeMap::new();
        for (number, line) in text.lines().enumerate().filter(|(_, l)| !l.trim().is_empty()) {
            if is_summary_line(line) {
                continue;
            }
            let (id, files) = manifest_line(line)
                .map_err(|e| bad_input(anyhow!("{side} {}: line {}: {e:#}", path.display(), number + 1)))?;
            entries.insert(id, files);
        }
        Ok(Manifest { dir: dir.to_path_buf(), entries })
    }
}

/// A native manifest's `dataset` (dataset.json) and `model` (models/<object>.ply) lines. They are
/// not compared: the models are built from the catalog entries the samples' records name, and
/// dataset.json summarises the grasps and samples that are compared (a grasp accepted on one side
/// only shows up as its samples missing on the other).
fn is_summary_line(line: &str) -> bool {
    serde_json::from_str::<serde_json::Value>(line)
        .ok()
        .and_then(|v| v.as_object().map(|o| o.contains_key("dataset") || o.contains_key("model")))
        .unwrap_or(false)
}

fn manifest_line(line: &str) -> anyhow::Result<(String, BTreeMap<String, Listed>)> {
    let value: serde_json::Value = serde_json::from_str(line).context("not JSON")?;
    let object = value.as_object().ok_or_else(|| anyhow!("not a JSON object"))?;
    let id = object
        .get("sample_id")
        .or_else(|| object.iter().find(|(k, v)| (k.ends_with("_id") || *k == "id") && v.is_string()).map(|(_, v)| v))
        .and_then(serde_json::Value::as_str)
        .ok_or_else(|| anyhow!("no sample_id"))?;
    let files = object.get("files").and_then(|f| f.as_object()).ok_or_else(|| anyhow!("{id}: no files object"))?;
    let mut listed = BTreeMap::new();
    for (name, file) in files {
        let sha256 = file["sha256"].as_str().ok_or_else(|| anyhow!("{id}: {name}: no sha256"))?;
        let path = match file.get("path").and_then(|p| p.as_str()) {
            Some(path) => PathBuf::from(path),
            None if name.contains('/') => PathBuf::from(name),
            None => Path::new(id).join(name),
        };
        if path.is_absolute() || path.components().any(|c| matches!(c, std::path::Component::ParentDir)) {
            anyhow::bail!("{id}: {name}: path {} leaves the dataset", path.display());
        }
        listed.insert(name.clone(), Listed { sha256: sha256.to_string(), path });
    }
    Ok((id.to_string(), listed))
}

/// What a file is compared as, by its type.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize)]
#[serde(rename_all = "snake_case")]
enum Kind {
    Rgb,
    Labels,
    Depth,
    Json,
    /// No tolerance applies: the bytes must be identical.
    Bytes,
}

/// Compares two files' bytes as their type says; the kind tells which rule applied.
fn compare_files(name: &str, a: &[u8], b: &[u8], tolerances: &Tolerances) -> (Kind, Finding) {
    let extension = Path::new(name).extension().and_then(|e| e.to_str()).unwrap_or("");
    let outcome = match extension {
        "png" if crate::depth::is_depth_file(name) => compare_depth_files(name, a, b, tolerances),
        "png" => compare_pngs(a, b, tolerances),
        "npy" => compare_arrays(a, b, tolerances),
        "json" => compare_json(a, b, tolerances),
        _ => Ok((Kind::Bytes, Finding::structural("the bytes differ (no tolerance for this file type)".into()))),
    };
    outcome.unwrap_or_else(|e| (Kind::Bytes, Finding::structural(format!("{e:#}"))))
}

fn compare_pngs(a: &[u8], b: &[u8], tolerances: &Tolerances) -> anyhow::Result<(Kind, Finding)> {
    let ia = pixels::decode_png(a).context("A: cannot decode the PNG")?;
    let ib = pixels::decode_png(b).context("B: cannot decode the PNG")?;
    Ok(if ia.is_colour() {
        (Kind::Rgb, pixels::compare_rgb(&ia, &ib, tolerances))
    } else {
        (Kind::Labels, pixels::compare_labels(&ia, &ib, tolerances))
    })
}

/// Depth PNGs hold whole 0.1 mm steps, so their difference is whole steps too: it is reported as
/// such, not with the rounding of two metre values (one step apart, a pixel that rounded the
/// other way on another CPU, reads 1e-4 m exactly, the default tolerance).
fn compare_depth_files(name: &str, a: &[u8], b: &[u8], tolerances: &Tolerances) -> anyhow::Result<(Kind, Finding)> {
    let da = crate::depth::decode(name, a).context("A")?;
    let db = crate::depth::decode(name, b).context("B")?;
    let mut finding = pixels::compare_depth(&da, &db, tolerances);
    for measure in finding.measures.iter_mut().filter(|m| m.unit == "m") {
        measure.value = crate::depth::whole_steps(measure.value);
    }
    Ok((Kind::Depth, finding))
}

fn compare_arrays(a: &[u8], b: &[u8], tolerances: &Tolerances) -> anyhow::Result<(Kind, Finding)> {
    let xa = npy::parse(a).context("A")?;
    let xb = npy::parse(b).context("B")?;
    Ok(match (xa.is_float(), xb.is_float()) {
        (true, true) => (Kind::Depth, pixels::compare_depth(&xa, &xb, tolerances)),
        (false, false) => (Kind::Labels, pixels::compare_label_arrays(&xa, &xb, tolerances)),
        _ => (Kind::Depth, Finding::structural(format!("dtype {} in A, {} in B", xa.dtype, xb.dtype))),
    })
}

fn compare_json(a: &[u8], b: &[u8], tolerances: &Tolerances) -> anyhow::Result<(Kind, Finding)> {
    let va: serde_json::Value = serde_json::from_slice(a).context("A: not JSON")?;
    let vb: serde_json::Value = serde_json::from_slice(b).context("B: not JSON")?;
    Ok((Kind::Json, json::compare(&va, &vb, tolerances)))
}

/// The modality a file belongs to: its name within a sample (`rgb.png`), or for a file outside
/// the sample directories its directory and type (`grasps/*.json`).
fn modality(name: &str) -> String {
    match name.rsplit_once('/') {
        Some((dir, file)) => match file.rsplit_once('.') {
            Some((_, extension)) => format!("{dir}/*.{extension}"),
            None => format!("{dir}/*"),
        },
        None => name.to_string(),
    }
}

/// A file over tolerance, or unreadable.
#[derive(Debug, Serialize)]
struct Difference {
    sample: String,
    file: String,
    modality: String,
    kind: Kind,
    #[serde(flatten)]
    finding: Finding,
}

#[derive(Debug, Default, Serialize)]
struct ModalitySummary {
    modality: String,
    kind: Option<Kind>,
    /// Files listed in both datasets.
    compared: usize,
    /// Of those, files with the same SHA-256 (not read).
    identical: usize,
    over_tolerance: usize,
    /// The largest difference found, measured against its tolerance, and where.
    worst: Option<Worst>,
}

#[derive(Debug, Clone, Serialize)]
struct Worst {
    sample: String,
    file: String,
    #[serde(flatten)]
    measure: Measure,
}

#[derive(Debug, Serialize)]
struct MissingFile {
    sample: String,
    file: String,
    missing_in: &'static str,
}

#[derive(Debug, Serialize)]
struct Samples {
    in_a: usize,
    in_b: usize,
    compared: usize,
    /// Samples with a file over tolerance, unreadable, or missing on one side.
    differing: Vec<String>,
    only_in_a: Vec<String>,
    only_in_b: Vec<String>,
}

#[derive(Debug, Serialize)]
pub struct Report {
    a: PathBuf,
    b: PathBuf,
    within_tolerance: bool,
    tolerances: Tolerances,
    samples: Samples,
    missing_files: Vec<MissingFile>,
    modalities: Vec<ModalitySummary>,
    differences: Vec<Difference>,
}

impl Report {
    pub fn within_tolerance(&self) -> bool {
        self.within_tolerance
    }
}

/// Compares dataset `b` with dataset `a`.
fn compare(a: &Manifest, b: &Manifest, tolerances: &Tolerances) -> Report {
    let only_in_a: Vec<String> = a.entries.keys().filter(|k| !b.entries.contains_key(*k)).cloned().collect();
    let only_in_b: Vec<String> = b.entries.keys().filter(|k| !a.entries.contains_key(*k)).cloned().collect();
    let mut modalities: BTreeMap<String, ModalitySummary> = BTreeMap::new();
    let (mut missing_files, mut differences) = (Vec::new(), Vec::new());
    let mut differing: BTreeSet<String> = BTreeSet::new();
    let mut seen: BTreeSet<(PathBuf, PathBuf)> = BTreeSet::new(); // files several samples share
    let common: Vec<&String> = a.entries.keys().filter(|k| b.entries.contains_key(*k)).collect();
    for id in &common {
        let (files_a, files_b) = (&a.entries[*id], &b.entries[*id]);
        let names: BTreeSet<&String> = files_a.keys().chain(files_b.keys()).collect();
        for name in names {
            let (fa, fb) = match (files_a.get(name), files_b.get(name)) {
                (Some(fa), Some(fb)) => (fa, fb),
                (fa, _) => {
                    let missing_in = if fa.is_some() { "b" } else { "a" };
                    missing_files.push(MissingFile { sample: (*id).clone(), file: name.clone(), missing_in });
                    differing.insert((*id).clone());
                    continue;
                }
            };
            if !seen.insert((fa.path.clone(), fb.path.clone())) {
                continue;
            }
            let summary = modalities
                .entry(modality(name))
                .or_insert_with(|| ModalitySummary { modality: modality(name), ..ModalitySummary::default() });
            summary.compared += 1;
            if fa.sha256 == fb.sha256 {
                summary.identical += 1;
                continue;
            }
            let (kind, finding) = match (std::fs::read(a.dir.join(&fa.path)), std::fs::read(b.dir.join(&fb.path))) {
                (Ok(xa), Ok(xb)) => compare_files(name, &xa, &xb, tolerances),
                (Err(e), _) => (Kind::Bytes, Finding::structural(format!("A: cannot read {}: {e}", fa.path.display()))),
                (_, Err(e)) => (Kind::Bytes, Finding::structural(format!("B: cannot read {}: {e}", fb.path.display()))),
            };
            summary.kind.get_or_insert(kind);
            if let Some(measure) = finding.worst() {
                let worse = summary.worst.as_ref().is_none_or(|w| measure.excess() > w.measure.excess());
                if worse {
                    summary.worst = Some(Worst { sample: (*id).clone(), file: name.clone(), measure: measure.clone() });
                }
            }
            if !finding.within() {
                summary.over_tolerance += 1;
                differing.insert((*id).clone());
                differences.push(Difference {
                    sample: (*id).clone(),
                    file: name.clone(),
                    modality: modality(name),
                    kind,
                    finding,
                });
            }
        }
    }
    let within_tolerance = differing.is_empty() && only_in_a.is_empty() && only_in_b.is_empty();
    Report {
        a: a.dir.clone(),
        b: b.dir.clone(),
        within_tolerance,
        tolerances: tolerances.clone(),
        samples: Samples {
            in_a: a.entries.len(),
            in_b: b.entries.len(),
            compared: common.len(),
            differing: differing.into_iter().collect(),
            only_in_a,
            only_in_b,
        },
        missing_files,
        modalities: modalities.into_values().collect(),
        differences,
    }
}

pub fn run(args: &DiffArgs, json: bool) -> CliResult {
    let a = Manifest::read(&args.a, "A")?;
    let b = Manifest::read(&args.b, "B")?;
    let report = compare(&a, &b, &args.tolerances);
    if !json {
        print!("{}", text(&report));
    }
    if report.within_tolerance() {
        if json {
            println!("{}", serde_json::to_string_pretty(&report).context("encoding the report")?);
        }
        Ok(())
    } else {
        let count = report.samples.differing.len() + report.samples.only_in_a.len() + report.samples.only_in_b.len();
        let failure =
            Failure { code: 1, error: anyhow!("{count} sample(s) differ beyond tolerance or are missing on one side") };
        // With --json the report is the output, with the error in it: one document on stdout.
        Err(if json {
            failure.with_report(serde_json::to_value(&report).context("encoding the report")?)
        } else {
            failure
        })
    }
}

fn text(report: &Report) -> String {
    use std::fmt::Write;
    let mut out = String::new();
    let s = &report.samples;
    let _ = writeln!(out, "A: {} ({} samples)", report.a.display(), s.in_a);
    let _ = writeln!(out, "B: {} ({} samples)", report.b.display(), s.in_b);
    for (label, list) in [("only in A", &s.only_in_a), ("only in B", &s.only_in_b)] {
        if !list.is_empty() {
            let _ = writeln!(out, "{label}: {}", list.join(", "));
        }
    }
    for missing in &report.missing_files {
        let side = if missing.missing_in == "a" { "A" } else { "B" };
        let _ = writeln!(out, "missing in {side}: {}/{}", missing.sample, missing.file);
    }
    let _ = writeln!(
        out,
        "\n{:<20} {:>6} {:>9} {:>5}  worst difference (tolerance)",
        "modality", "files", "identical", "over"
    );
    for m in &report.modalities {
        let worst =
            m.worst.as_ref().map_or_else(|| "-".to_string(), |w| format!("{} in {}", describe(&w.measure), w.sample));
        let _ =
            writeln!(out, "{:<20} {:>6} {:>9} {:>5}  {worst}", m.modality, m.compared, m.identical, m.over_tolerance);
    }
    if !report.differences.is_empty() {
        let _ = writeln!(out, "\nbeyond tolerance:");
        for d in &report.differences {
            let measures = d.finding.measures.iter().filter(|m| !m.within()).map(describe);
            let all: Vec<String> = measures.chain(d.finding.notes.iter().cloned()).collect();
            let _ = writeln!(out, "  {}/{}: {}", d.sample, d.file, all.join("; "));
        }
    }
    let verdict = if report.within_tolerance {
        format!("{} samples compared: all within tolerance", s.compared)
    } else {
        format!(
            "{} samples compared: {} differ beyond tolerance, {} only in A, {} only in B",
            s.compared,
            s.differing.len(),
            s.only_in_a.len(),
            s.only_in_b.len()
        )
    };
    let _ = writeln!(out, "\n{verdict}");
    out
}

/// `max_abs_levels 40 (≤ 3) at pixel (u=5, v=10)`, `differing_share 0.012 % (≤ 0.100 %): 2 of 16384 pixels`.
fn describe(m: &Measure) -> String {
    let value = match m.unit {
        "share" => format!("{:.3} % (≤ {:.3} %)", m.value * 100.0, m.tolerance * 100.0),
        "levels" => format!("{} (≤ {})", m.value, m.tolerance),
        unit => format!("{:.3e} {unit} (≤ {:.1e})", m.value, m.tolerance),
    };
    match (&m.at, m.unit) {
        (Some(at), "share") => format!("{} {value}: {at}", m.name),
        (Some(at), _) => format!("{} {value} at {at}", m.name),
        (None, _) => format!("{} {value}", m.name),
    }
}

#[cfg(test)]
mod tests {
    use serde_json::json;

    use super::*;

    /// A dataset written file by file, with its manifest.
    struct Dataset {
        dir: tempfile::TempDir,
        lines: BTreeMap<String, BTreeMap<String, serde_json::Value>>,
    }

    impl Dataset {
        fn new() -> Dataset {
            Dataset { dir: tempfile::tempdir().expect("temp dir"), lines: BTreeMap::new() }
        }

        /// Writes `bytes` as `name` of `sample` (a name with a directory lies at the root).
        fn file(&mut self, sample: &str, name: &str, bytes: &[u8]) -> &mut Dataset {
            let path =
                if name.contains('/') { self.dir.path().join(name) } else { self.dir.path().join(sample).join(name) };
            std::fs::create_dir_all(path.parent().expect("parent")).expect("mkdir");
            std::fs::write(&path, bytes).expect("write");
            self.list(sample, name, bytes)
        }

        /// Lists `name` in the manifest without writing it.
        fn list(&mut self, sample: &str, name: &str, bytes: &[u8]) -> &mut Dataset {
            use sha2::Digest;
            let sha = hex::encode(sha2::Sha256::digest(bytes));
            let entry = json!({"sha256": sha, "size": bytes.len(), "media_type": "application/octet-stream"});
            self.lines.entry(sample.into()).or_default().insert(name.into(), entry);
            self
        }

        fn manifest(&self) -> Manifest {
            let text: String = self
                .lines
                .iter()
                .map(|(id, files)| format!("{}\n", json!({"sample_id": id, "files": files})))
                .collect();
            std::fs::write(self.dir.path().join("manifest.jsonl"), text).expect("manifest");
            Manifest::read(self.dir.path(), "A").unwrap_or_else(|f| panic!("{:#}", f.error))
        }
    }

    fn meta(x: f64) -> Vec<u8> {
        json!({"grasp": {"object_pose": {"p": [x, 0.0, 0.05], "q": [1.0, 0.0, 0.0, 0.0]}}}).to_string().into_bytes()
    }

    fn mask(flipped: usize) -> Vec<u8> {
        let mut samples = vec![0u8; 16 * 16];
        samples[..flipped].fill(255);
        pixels::encode_png(16, 16, 1, &samples)
    }

    #[test]
    fn identical_datasets_are_within_tolerance() {
        let mut a = Dataset::new();
        a.file("s1", "meta.json", &meta(0.1)).file("s1", "mask.png", &mask(0));
        let report = compare(&a.manifest(), &a.manifest(), &Tolerances::default());
        assert!(report.within_tolerance(), "{report:#?}");
        assert_eq!((report.modalities[0].compared, report.modalities[0].identical), (1, 1));
    }

    #[test]
    fn files_with_the_same_hash_are_not_read() {
        let mut a = Dataset::new();
        a.file("s1", "mask.png", &mask(0));
        let mut b = Dataset::new();
        b.list("s1", "mask.png", &mask(0)); // listed, never written
        let report = compare(&a.manifest(), &b.manifest(), &Tolerances::default());
        assert!(report.within_tolerance(), "{report:#?}");
    }

    #[test]
    fn samples_and_files_on_one_side_only_are_differences() {
        let mut a = Dataset::new();
        a.file("s1", "meta.json", &meta(0.1)).file("s1", "mask.png", &mask(0)).file("s2", "meta.json", &meta(0.1));
        let mut b = Dataset::new();
        b.file("s1", "meta.json", &meta(0.1)).file("s3", "meta.json", &meta(0.1));
        let report = compare(&a.manifest(), &b.manifest(), &Tolerances::default());
        assert!(!report.within_tolerance());
        assert_eq!(
            (report.samples.only_in_a.as_slice(), report.samples.only_in_b.as_slice()),
            (&["s2".to_string()][..], &["s3".to_string()][..])
        );
        assert_eq!(report.missing_files.len(), 1);
        assert_eq!((report.missing_files[0].file.as_str(), report.missing_files[0].missing_in), ("mask.png", "b"));
        assert_eq!(report.samples.differing, ["s1"]);
    }

    #[test]
    fn a_pose_a_millimetre_off_names_its_sample_file_and_path() {
        let mut a = Dataset::new();
        a.file("s1", "meta.json", &meta(0.1)).file("s2", "meta.json", &meta(0.1));
        let mut b = Dataset::new();
        b.file("s1", "meta.json", &meta(0.1)).file("s2", "meta.json", &meta(0.101));
        let report = compare(&a.manifest(), &b.manifest(), &Tolerances::default());
        assert!(!report.within_tolerance());
        assert_eq!(report.samples.differing, ["s2"]);
        let difference = &report.differences[0];
        assert_eq!(
            (difference.sample.as_str(), difference.file.as_str(), difference.kind),
            ("s2", "meta.json", Kind::Json)
        );
        let worst = report.modalities[0].worst.as_ref().expect("a worst difference");
        assert_eq!((worst.sample.as_str(), worst.measure.at.as_deref()), ("s2", Some("grasp.object_pose.p[0]")));
        let loose = Tolerances { position_m: 0.002, ..Tolerances::default() };
        assert!(compare(&a.manifest(), &b.manifest(), &loose).within_tolerance());
    }

    #[test]
    fn files_outside_the_sample_directories_are_compared_once_by_type() {
        // A grasp's record, shared by its views, as the package stage may list it.
        let record = "grasps/can.trx3.g000001.json";
        let mut a = Dataset::new();
        a.file("s1", record, &meta(0.1)).file("s2", record, &meta(0.1));
        let mut b = Dataset::new();
        b.file("s1", record, &meta(0.2)).file("s2", record, &meta(0.2));
        let report = compare(&a.manifest(), &b.manifest(), &Tolerances::default());
        assert_eq!(report.modalities[0].modality, "grasps/*.json");
        assert_eq!((report.modalities[0].compared, report.modalities[0].over_tolerance), (1, 1));
        assert_eq!(report.differences.len(), 1);
    }

    /// A 16-bit depth PNG of 16×16 pixels, each `units` tenths of a millimetre.
    fn depth_png(units: u16) -> Vec<u8> {
        let mut out = Vec::new();
        let mut encoder = png::Encoder::new(&mut out, 16, 16);
        encoder.set_color(png::ColorType::Grayscale);
        encoder.set_depth(png::BitDepth::Sixteen);
        let mut writer = encoder.write_header().expect("png header");
        writer.write_image_data(&units.to_be_bytes().repeat(256)).expect("png data");
        writer.finish().expect("png end");
        out
    }

    #[test]
    fn a_depth_png_is_compared_as_depth_in_metres_not_as_labels() {
        let mut a = Dataset::new();
        // 5002 and 5003 steps as metres differ by a hair more than 1e-4 m: whole steps do not.
        a.file("s1", "depth.png", &depth_png(5002));
        let mut b = Dataset::new();
        b.file("s1", "depth.png", &depth_png(5003));
        let report = compare(&a.manifest(), &b.manifest(), &Tolerances::default());
        assert!(report.within_tolerance(), "one step is 0.1 mm, the default tolerance: {report:#?}");
        assert_eq!(report.modalities[0].kind, Some(Kind::Depth));
        let mut far = Dataset::new();
        far.file("s1", "depth.png", &depth_png(5020));
        let report = compare(&a.manifest(), &far.manifest(), &Tolerances::default());
        assert!(!report.within_tolerance());
        let worst = report.modalities[0].worst.as_ref().expect("a worst difference");
        assert!((worst.measure.value - 0.0018).abs() < 1e-12, "{worst:?}");
    }

    #[test]
    fn unreadable_files_and_unknown_types_are_differences_that_say_why() {
        let mut a = Dataset::new();
        a.file("s1", "depth.npy", b"not an array").file("s1", "notes.txt", b"a");
        let mut b = Dataset::new();
        b.file("s1", "depth.npy", b"not an array either").file("s1", "notes.txt", b"b");
        let report = compare(&a.manifest(), &b.manifest(), &Tolerances::default());
        let notes: Vec<&str> =
            report.differences.iter().flat_map(|d| d.finding.notes.iter().map(String::as_str)).collect();
        assert_eq!(
            notes,
            ["A: not a .npy file (no \\x93NUMPY magic)", "the bytes differ (no tolerance for this file type)"]
        );
    }

    #[test]
    fn a_directory_without_a_manifest_is_bad_input() {
        let empty = tempfile::tempdir().expect("temp dir");
        let failure = Manifest::read(empty.path(), "B").expect_err("no manifest");
        assert_eq!(failure.code, 2);
        assert!(format!("{:#}", failure.error).contains("not a dataset: cannot read manifest.jsonl"));
        std::fs::write(empty.path().join("manifest.jsonl"), "{\"files\": {}}\n").expect("write");
        let failure = Manifest::read(empty.path(), "B").expect_err("no id");
        assert!(format!("{:#}", failure.error).contains("line 1: no sample_id"), "{:#}", failure.error);
    }

    #[test]
    fn tolerance_flags_refuse_negative_values_and_shares_above_one() {
        assert_eq!(non_negative("0.001"), Ok(0.001));
        assert!(non_negative("-1").unwrap_err().contains("finite number ≥ 0"));
        assert!(non_negative("nan").is_err());
        assert!(share("1.5").unwrap_err().contains("between 0 and 1"));
    }
}

//! `vintctl bop-objects`: a BOP dataset's models as `[object.NAME]` tables of a spec — each model's
//! PLY (millimetres) and the texture it names, its own `obj_id`, and its `models_info.json`
//! symmetries in the spec's metres form — so a dataset of them exports under the dataset's ids.
//! It only reads the models folder and prints TOML; the spec stays the one place the objects are
//! defined, with every number in sight. BOP has no masses: each is given.

use std::collections::BTreeMap;
use std::path::Path;

use anyhow::{Context, anyhow, bail};
use serde_json::Value;
use vint_core::asset;
use vint_core::contract::object::{BOP_OBJ_ID, Material};

use crate::{CliResult, bad_input};

/// The tables for `ids` of the models folder `models` (as the spec will name it: relative to the
/// spec's directory), read from `info` (`models_info.json`) and each model's PLY header.
pub fn tables(
    models: &str,
    info: &Value,
    headers: &BTreeMap<u32, Vec<u8>>,
    masses: &BTreeMap<u32, f64>,
    material: Material,
    prefix: &str,
) -> anyhow::Result<String> {
    let mut out = String::new();
    for (&id, header) in headers {
        let entry = info.get(id.to_string()).ok_or_else(|| anyhow!("models_info.json has no model {id}"))?;
        let mass = masses.get(&id).ok_or_else(|| anyhow!("--mass {id}=KG: BOP gives no masses; give each model's"))?;
        let dir = models.trim_end_matches('/');
        let mesh = format!("{dir}/obj_{id:06}.ply");
        let files: Vec<String> = asset::references(&mesh, header)
            .iter()
            .map(|r| asset::resolve_reference(&mesh, r).ok_or_else(|| anyhow!("{mesh}: {r:?} leaves the folder")))
            .collect::<anyhow::Result<_>>()?;
        let name = format!("{prefix}{id}");
        out.push_str(&format!("[object.{name}]\nmesh = {mesh:?}\nfiles = {files:?}\nunit = \"mm\"\n"));
        out.push_str(&format!("mass_kg = {mass}\nmaterial = {}\nobj_id = {id}\n", serde_json::to_value(material)?));
        out.push_str(&format!("symmetries_continuous = [{}]\n", continuous(entry)?.join(", ")));
        out.push_str(&format!("symmetries_discrete = [{}]\n\n", discrete(entry)?.join(", ")));
    }
    Ok(out)
}

/// `symmetries_continuous` with offsets from millimetres to metres.
fn continuous(entry: &Value) -> anyhow::Result<Vec<String>> {
    let items = entry.get("symmetries_continuous").and_then(Value::as_array).cloned().unwrap_or_default();
    items
        .iter()
        .map(|s| {
            let axis = numbers(&s["axis"], 3, 1.0)?;
            let offset = numbers(&s["offset"], 3, 0.001)?;
            Ok(format!("{{ axis = {}, offset = {} }}", list(&axis), list(&offset)))
        })
        .collect()
}

/// `symmetries_discrete` with the translation (entries 3, 7, 11) from millimetres to metres.
fn discrete(entry: &Value) -> anyhow::Result<Vec<String>> {
    let items = entry.get("symmetries_discrete").and_then(Value::as_array).cloned().unwrap_or_default();
    items
        .iter()
        .map(|m| {
            let mut m = numbers(m, 16, 1.0)?;
            for k in [3, 7, 11] {
                m[k] /= 1000.0;
            }
            Ok(list(&m))
        })
        .collect()
}

fn numbers(v: &Value, n: usize, scale: f64) -> anyhow::Result<Vec<f64>> {
    let items = v.as_array().filter(|a| a.len() == n).ok_or_else(|| anyhow!("expected {n} numbers, got {v}"))?;
    items.iter().map(|x| x.as_f64().map(|x| x * scale).ok_or_else(|| anyhow!("not a number: {x}"))).collect()
}

fn list(values: &[f64]) -> String {
    let shown: Vec<String> = values.iter().map(|x| format!("{:?}", (x * 1e9).round() / 1e9 + 0.0)).collect();
    format!("[{}]", shown.join(", "))
}

/// `ID=KG,ID=KG` (or repeated flags) into a map.
pub fn parse_masses(items: &[String]) -> anyhow::Result<BTreeMap<u32, f64>> {
    let mut out = BTreeMap::new();
    for item in items.iter().flat_map(|s| s.split(',')) {
        let (id, kg) = item.split_once('=').ok_or_else(|| anyhow!("--mass {item:?}: expected ID=KG"))?;
        let id: u32 = id.trim().parse().with_context(|| format!("--mass {item:?}: the id"))?;
        let kg: f64 = kg.trim().parse().with_context(|| format!("--mass {item:?}: the mass"))?;
        out.insert(id, kg);
    }
    Ok(out)
}

/// Reads `models_info.json` and the PLY headers of `ids` under `models`, prints the tables.
pub fn run(models: &Path, ids: &[u32], masses: &[String], material: &str, prefix: &str) -> CliResult {
    let go = || -> anyhow::Result<String> {
        if models.is_absolute() {
            bail!("{}: give the folder relative to the spec's directory (spec paths are)", models.display());
        }
        let masses = parse_masses(masses)?;
        let material: Material = serde_json::from_value(Value::String(material.to_string()))
            .map_err(|_| anyhow!("--material {material:?}: not a material tag (plastic, metal, glass, …)"))?;
        let info_path = models.join("models_info.json");
        let info: Value = serde_json::from_slice(
            &std::fs::read(&info_path).with_context(|| format!("reading {}", info_path.display()))?,
        )
        .with_context(|| format!("parsing {}", info_path.display()))?;
        let mut headers = BTreeMap::new();
        for &id in ids {
            if !(BOP_OBJ_ID.min..=BOP_OBJ_ID.max).contains(&id) {
                bail!("--ids {id}: a kept obj_id must be {}..={}", BOP_OBJ_ID.min, BOP_OBJ_ID.max);
            }
            let ply = models.join(format!("obj_{id:06}.ply"));
            let bytes = std::fs::read(&ply).with_context(|| format!("reading {}", ply.display()))?;
            let end = bytes.windows(10).position(|w| w == b"end_header").map_or(bytes.len(), |p| p + 10);
            headers.insert(id, bytes[..end].to_vec());
        }
        tables(&models.to_string_lossy().replace('\\', "/"), &info, &headers, &masses, material, prefix)
    };
    let text = go().map_err(bad_input)?;
    print!("{text}");
    Ok(())
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn a_models_folder_becomes_tables_with_ids_texture_and_symmetries_in_metres() {
        let info: Value = serde_json::from_str(
            r#"{"1": {"diameter": 172.1, "symmetries_continuous": [{"axis": [0, 0, 1], "offset": [0, 0, 10]}]},
                "5": {"diameter": 201.4, "symmetries_discrete": [[-1, 0, 0, 2, 0, -1, 0, 0, 0, 0, 1, 0, 0, 0, 0, 1]]}}"#,
        )
        .unwrap();
        let header = |id: u32| {
            format!("ply\nformat binary_little_endian 1.0\ncomment TextureFile obj_{id:06}.png\nend_header")
                .into_bytes()
        };
        let headers = BTreeMap::from([(1, header(1)), (5, header(5))]);
        let masses = parse_masses(&["1=0.411,5=0.603".to_string()]).unwrap();
        let text = tables("ycbv/models/", &info, &headers, &masses, Material::Plastic, "ycbv_").unwrap();
        assert_eq!(
            text,
            "[object.ycbv_1]\nmesh = \"ycbv/models/obj_000001.ply\"\nfiles = [\"ycbv/models/obj_000001.png\"]\n\
             unit = \"mm\"\nmass_kg = 0.411\nmaterial = \"plastic\"\nobj_id = 1\n\
             symmetries_continuous = [{ axis = [0.0, 0.0, 1.0], offset = [0.0, 0.0, 0.01] }]\nsymmetries_discrete = []\n\n\
             [object.ycbv_5]\nmesh = \"ycbv/models/obj_000005.ply\"\nfiles = [\"ycbv/models/obj_000005.png\"]\n\
             unit = \"mm\"\nmass_kg = 0.603\nmaterial = \"plastic\"\nobj_id = 5\nsymmetries_continuous = []\n\
             symmetries_discrete = [[-1.0, 0.0, 0.0, 0.002, 0.0, -1.0, 0.0, 0.0, 0.0, 0.0, 1.0, 0.0, 0.0, 0.0, 0.0, 1.0]]\n\n"
        );
        let spec = format!("objects = [\"ycbv_1\", \"ycbv_5\"]\n[dataset]\nname = \"y\"\nseed = 1\n{text}");
        let parsed = vint_core::DatasetSpec::parse(&spec).unwrap();
        assert_eq!(parsed.object_defs["ycbv_5"].obj_id, Some(5));
        let only_one = parse_masses(&["1=0.411".to_string()]).unwrap();
        let missing = tables("m", &info, &headers, &only_one, Material::Plastic, "y").unwrap_err().to_string();
        assert!(missing.contains("--mass 5=KG"), "{missing}");
    }
}

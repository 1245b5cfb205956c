//! Pose estimates in the BOP results CSV format (the BOP toolkit's docs/bop_challenge_*.md):
//! a header `scene_id,im_id,obj_id,score,R,t,time`, then one estimate a line, `R` nine numbers
//! row-major and `t` three numbers in millimetres, each space-separated, `time` in seconds (the
//! toolkit writes -1 when unknown). Every row is checked; a file with any bad row is refused whole,
//! with every problem named by line, field, value and rule.

use std::fmt;

use super::metrics::Pose;

pub const HEADER: &str = "scene_id,im_id,obj_id,score,R,t,time";

/// How far RᵀR may be from the identity, entry by entry: loose enough for rotations printed with
/// a handful of digits, tight enough to refuse a scaled, sheared or garbled matrix.
pub const ROTATION_TOLERANCE: f64 = 1e-3;

/// One row of the file.
#[derive(Clone, Debug)]
pub struct Estimate {
    /// 1-based line number in the file.
    pub line: usize,
    pub scene_id: u32,
    pub im_id: u32,
    pub obj_id: u32,
    pub score: f64,
    pub pose: Pose,
}

/// A row that breaks a rule.
#[derive(Debug, PartialEq)]
pub struct RowError {
    pub line: usize,
    pub field: &'static str,
    pub value: String,
    pub rule: String,
}

impl fmt::Display for RowError {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        write!(f, "line {}: {} = {:?}: {}", self.line, self.field, self.value, self.rule)
    }
}

/// Every bad row of a file.
#[derive(Debug)]
pub struct CsvErrors(pub Vec<RowError>);

/// How many problems the message lists before it says how many more there are.
const LISTED: usize = 20;

impl fmt::Display for CsvErrors {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        let n = self.0.len();
        write!(f, "{n} problem{} in the estimates (BOP results CSV: {HEADER}):", if n == 1 { "" } else { "s" })?;
        for e in self.0.iter().take(LISTED) {
            write!(f, "\n  {e}")?;
        }
        if n > LISTED {
            write!(f, "\n  … and {} more", n - LISTED)?;
        }
        Ok(())
    }
}

impl std::error::Error for CsvErrors {}

/// Every estimate in `text`, in file order; blank lines are skipped.
pub fn parse(text: &str) -> Result<Vec<Estimate>, CsvErrors> {
    let mut lines = text.lines().enumerate().map(|(i, l)| (i + 1, l.trim())).filter(|(_, l)| !l.is_empty());
    let mut errors = Vec::new();
    match lines.next() {
        Some((_, header)) if header.replace(' ', "") == HEADER => {}
        Some((line, header)) => errors.push(RowError {
            line,
            field: "header",
            value: header.to_string(),
            rule: format!("the first line must be the header `{HEADER}`"),
        }),
        None => errors.push(RowError {
            line: 1,
            field: "header",
            value: String::new(),
            rule: format!("the file is empty; it must start with the header `{HEADER}`"),
        }),
    }
    let mut estimates = Vec::new();
    for (line, row) in lines {
        match parse_row(line, row) {
            Ok(e) => estimates.push(e),
            Err(mut e) => errors.append(&mut e),
        }
    }
    if errors.is_empty() { Ok(estimates) } else { Err(CsvErrors(errors)) }
}

fn parse_row(line: usize, row: &str) -> Result<Estimate, Vec<RowError>> {
    let fields: Vec<&str> = row.split(',').map(str::trim).collect();
    if fields.len() != 7 {
        return Err(vec![RowError {
            line,
            field: "row",
            value: row.to_string(),
            rule: format!("a row has 7 comma-separated fields ({HEADER}), this one {}", fields.len()),
        }]);
    }
    let mut errors = Vec::new();
    let mut fail = |field: &'static str, value: &str, rule: String| {
        errors.push(RowError { line, field, value: value.to_string(), rule });
    };
    let mut id = |field: &'static str, value: &str| match value.parse::<u32>() {
        Ok(v) => Some(v),
        Err(_) => {
            fail(field, value, "a non-negative integer".into());
            None
        }
    };
    let (scene_id, im_id, obj_id) = (id("scene_id", fields[0]), id("im_id", fields[1]), id("obj_id", fields[2]));
    let mut number = |field: &'static str, value: &str| match value.parse::<f64>() {
        Ok(v) if v.is_finite() => Some(v),
        _ => {
            fail(field, value, "a finite number".into());
            None
        }
    };
    let score = number("score", fields[3]);
    number("time", fields[6]);
    let r = numbers(fields[4], 9).map_err(|rule| fail("R", fields[4], rule)).ok();
    let t = numbers(fields[5], 3).map_err(|rule| fail("t", fields[5], rule)).ok();
    let r = r.and_then(|r| {
        let m = [[r[0], r[1], r[2]], [r[3], r[4], r[5]], [r[6], r[7], r[8]]];
        rotation_problem(&m).map(|rule| fail("R", fields[4], rule)).map_or(Some(m), |_| None)
    });
    match (scene_id, im_id, obj_id, score, r, t) {
        (Some(scene_id), Some(im_id), Some(obj_id), Some(score), Some(r), Some(t)) if errors.is_empty() => {
            Ok(Estimate { line, scene_id, im_id, obj_id, score, pose: Pose { r, t: [t[0], t[1], t[2]] } })
        }
        _ => Err(errors),
    }
}

/// `count` finite numbers separated by spaces, or the rule they break.
fn numbers(text: &str, count: usize) -> Result<Vec<f64>, String> {
    let rule = || format!("{count} finite numbers separated by spaces");
    let values: Vec<f64> =
        text.split_whitespace().map(str::parse::<f64>).collect::<Result<_, _>>().map_err(|_| rule())?;
    if values.len() != count || values.iter().any(|v| !v.is_finite()) {
        return Err(rule());
    }
    Ok(values)
}

/// Why `r` is not a rotation matrix, if it is not one.
fn rotation_problem(r: &[[f64; 3]; 3]) -> Option<String> {
    let mut worst: f64 = 0.0;
    for i in 0..3 {
        for j in 0..3 {
            let dot: f64 = (0..3).map(|k| r[k][i] * r[k][j]).sum();
            worst = worst.max((dot - if i == j { 1.0 } else { 0.0 }).abs());
        }
    }
    let det = r[0][0] * (r[1][1] * r[2][2] - r[1][2] * r[2][1]) - r[0][1] * (r[1][0] * r[2][2] - r[1][2] * r[2][0])
        + r[0][2] * (r[1][0] * r[2][1] - r[1][1] * r[2][0]);
    if worst > ROTATION_TOLERANCE {
        Some(format!(
            "a rotation matrix, row-major: every entry of RᵀR − I within {ROTATION_TOLERANCE} (this one is off by {worst:.3e})"
        ))
    } else if det <= 0.0 {
        Some(format!("a rotation matrix, row-major: det R = +1 (this one has {det:.4}: a reflection)"))
    } else {
        None
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    const GOOD: &str = "0,3,5,0.9,1 0 0 0 1 0 0 0 1,10 -20 400.5,0.1";

    fn csv(rows: &[&str]) -> String {
        format!("{HEADER}\n{}\n", rows.join("\n"))
    }

    #[test]
    fn reads_a_valid_file() {
        let text = format!("{HEADER}\r\n{GOOD}\r\n\r\n7,0,21,-1.5,0 -1 0 1 0 0 0 0 1,0 0 1,-1\n");
        let estimates = parse(&text).unwrap();
        assert_eq!(estimates.len(), 2);
        let e = &estimates[0];
        assert_eq!((e.line, e.scene_id, e.im_id, e.obj_id, e.score), (2, 0, 3, 5, 0.9));
        assert_eq!(e.pose.t, [10.0, -20.0, 400.5]);
        assert_eq!(estimates[1].line, 4);
        assert_eq!(estimates[1].pose.r, [[0.0, -1.0, 0.0], [1.0, 0.0, 0.0], [0.0, 0.0, 1.0]]);
    }

    #[test]
    fn names_line_field_value_and_rule_for_every_problem() {
        let text = csv(&[
            GOOD,
            "x,3,5,0.9,1 0 0 0 1 0 0 0 1,10 -20 400,0.1",
            "0,3,5,nan,1 0 0 0 1 0 0 0 1,10 -20 400,0.1",
            "0,3,5,0.9,1 0 0 0 1 0 0 0,10 -20 400,0.1",
            "0,3,5,0.9,2 0 0 0 1 0 0 0 1,10 -20 400,0.1",
            "0,3,5,0.9,-1 0 0 0 1 0 0 0 1,10 -20 400,0.1",
            "0,3,5,0.9,1 0 0 0 1 0 0 0 1,10 -20,0.1",
            "0,3,5,0.9",
            "0,-3,5,0.9,1 0 0 0 1 0 0 0 1,10 -20 400,x",
        ]);
        let errors = parse(&text).unwrap_err().0;
        let seen: Vec<(usize, &str, &str)> = errors.iter().map(|e| (e.line, e.field, e.value.as_str())).collect();
        assert_eq!(
            seen,
            [
                (3, "scene_id", "x"),
                (4, "score", "nan"),
                (5, "R", "1 0 0 0 1 0 0 0"),
                (6, "R", "2 0 0 0 1 0 0 0 1"),
                (7, "R", "-1 0 0 0 1 0 0 0 1"),
                (8, "t", "10 -20"),
                (9, "row", "0,3,5,0.9"),
                (10, "im_id", "-3"),
                (10, "time", "x"),
            ]
        );
        assert!(errors[3].rule.contains("RᵀR"), "{}", errors[3].rule);
        assert!(errors[4].rule.contains("reflection"), "{}", errors[4].rule);
        let message = CsvErrors(errors).to_string();
        assert!(
            message.starts_with("9 problems") && message.contains("line 6: R = \"2 0 0 0 1 0 0 0 1\""),
            "{message}"
        );
    }

    #[test]
    fn the_header_is_required() {
        let errors = parse(&format!("{GOOD}\n")).unwrap_err().0;
        assert_eq!((errors[0].line, errors[0].field), (1, "header"));
        assert_eq!(parse("").unwrap_err().0[0].field, "header");
        assert!(parse(&format!("{HEADER}\n")).unwrap().is_empty());
    }
}

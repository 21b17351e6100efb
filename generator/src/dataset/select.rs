//! `--where`: choosing samples by what the manifest says of them, in the query syntax of pandas
//! and SQL users: conditions `FIELD OP VALUE` joined by `and`, e.g.
//! `occluded < 0.2 and low_texture <= 0.5 and category != 'tree'`.
//!
//! Fields: the difficulty facts (`occluded`, `low_texture`, `transparent_mirror`,
//! `disparity_p1`, `disparity_p99`),
//! the left view's disparity summary (`disparity_min`, `disparity_max`, `disparity_mean`,
//! `valid`), `index`, `render_seconds` and `category` (a quoted name, `==`/`!=` only). OP is one of
//! `<`, `<=`, `>`, `>=`, `==`, `!=`. A condition on a fact a line does not carry (a manifest
//! written before difficulty was measured) is an error that names the sample, never a silent
//! "no".

use std::fmt;
use std::str::FromStr;

use anyhow::bail;

use super::ManifestEntry;

/// How a numeric field is read from a line (`None`: the line lacks it).
type ReadField = fn(&ManifestEntry) -> Option<f64>;

/// The numeric fields, with how each is read.
const NUMBERS: &[(&str, ReadField)] = &[
    ("occluded", |e| e.difficulty.map(|d| d.occluded)),
    ("low_texture", |e| e.difficulty.map(|d| d.low_texture)),
    ("disparity_p1", |e| {
        e.difficulty.map(|d| f64::from(d.disparity_p1))
    }),
    ("disparity_p99", |e| {
        e.difficulty.map(|d| f64::from(d.disparity_p99))
    }),
    ("transparent_mirror", |e| {
        e.difficulty.and_then(|d| d.transparent_mirror)
    }),
    ("disparity_min", |e| {
        e.disparity_left.map(|d| f64::from(d.min))
    }),
    ("disparity_max", |e| {
        e.disparity_left.map(|d| f64::from(d.max))
    }),
    ("disparity_mean", |e| e.disparity_left.map(|d| d.mean)),
    ("valid", |e| e.disparity_left.map(|d| d.valid_fraction)),
    ("index", |e| Some(e.index as f64)),
    ("render_seconds", |e| Some(e.render_seconds)),
];

#[derive(Debug, Clone, Copy, PartialEq)]
enum Op {
    Lt,
    Le,
    Gt,
    Ge,
    Eq,
    Ne,
}

impl Op {
    const ALL: [(&'static str, Op); 6] = [
        ("<=", Op::Le),
        (">=", Op::Ge),
        ("==", Op::Eq),
        ("!=", Op::Ne),
        ("<", Op::Lt),
        (">", Op::Gt),
    ];

    fn holds<T: PartialOrd>(self, a: T, b: T) -> bool {
        match self {
            Op::Lt => a < b,
            Op::Le => a <= b,
            Op::Gt => a > b,
            Op::Ge => a >= b,
            Op::Eq => a == b,
            Op::Ne => a != b,
        }
    }
}

#[derive(Debug, Clone)]
enum Condition {
    Number { field: usize, op: Op, value: f64 },
    Category { equal: bool, name: String },
}

/// A parsed `--where` expression.
#[derive(Debug, Clone)]
pub struct Selection {
    text: String,
    conditions: Vec<Condition>,
}

impl fmt::Display for Selection {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        f.write_str(&self.text)
    }
}

impl PartialEq for Selection {
    fn eq(&self, other: &Self) -> bool {
        self.text == other.text
    }
}

fn field_names() -> String {
    let mut names: Vec<&str> = NUMBERS.iter().map(|(n, _)| *n).collect();
    names.push("category");
    names.join(", ")
}

fn parse_condition(text: &str) -> Result<Condition, String> {
    let (at, symbol, op) = Op::ALL
        .iter()
        .filter_map(|(s, op)| text.find(s).map(|at| (at, *s, *op)))
        .min_by_key(|(at, s, _)| (*at, std::cmp::Reverse(s.len())))
        .ok_or_else(|| format!("{text:?} has no comparison (<, <=, >, >=, ==, !=)"))?;
    let field = text[..at].trim();
    let value = text[at + symbol.len()..].trim();
    if field == "category" {
        let name = value
            .strip_prefix('\'')
            .and_then(|v| v.strip_suffix('\''))
            .or_else(|| value.strip_prefix('"').and_then(|v| v.strip_suffix('"')))
            .ok_or_else(|| {
                format!("{text:?}: a category is a quoted name, e.g. category == 'tree'")
            })?;
        return match op {
            Op::Eq | Op::Ne => Ok(Condition::Category {
                equal: op == Op::Eq,
                name: name.to_string(),
            }),
            _ => Err(format!("{text:?}: a category compares with == or != only")),
        };
    }
    let field = NUMBERS
        .iter()
        .position(|(n, _)| *n == field)
        .ok_or_else(|| {
            format!(
                "{text:?}: unknown field {field:?} (fields: {})",
                field_names()
            )
        })?;
    let value: f64 = value
        .parse()
        .ok()
        .filter(|v: &f64| v.is_finite())
        .ok_or_else(|| format!("{text:?}: {value:?} is not a number"))?;
    Ok(Condition::Number { field, op, value })
}

impl FromStr for Selection {
    type Err = String;

    fn from_str(text: &str) -> Result<Self, String> {
        let mut conditions = Vec::new();
        for part in text.split(" and ") {
            if part.trim().is_empty() {
                return Err(format!("{text:?}: an empty condition"));
            }
            conditions.push(parse_condition(part.trim())?);
        }
        Ok(Self {
            text: text.trim().to_string(),
            conditions,
        })
    }
}

impl Selection {
    /// Whether `e` meets every condition; an error when it lacks a field a condition reads.
    pub fn matches(&self, e: &ManifestEntry) -> anyhow::Result<bool> {
        for c in &self.conditions {
            let holds = match c {
                Condition::Number { field, op, value } => {
                    let (name, read) = NUMBERS[*field];
                    let Some(v) = read(e) else {
                        bail!(
                            "--where {:?}: sample {} has no {name} (its manifest line was written before it was measured)",
                            self.text,
                            e.id
                        );
                    };
                    op.holds(v, *value)
                }
                Condition::Category { equal, name } => (e.category == *name) == *equal,
            };
            if !holds {
                return Ok(false);
            }
        }
        Ok(true)
    }

    /// The entries that match, in order.
    pub fn filter(&self, entries: Vec<ManifestEntry>) -> anyhow::Result<Vec<ManifestEntry>> {
        let mut kept = Vec::with_capacity(entries.len());
        for e in entries {
            if self.matches(&e)? {
                kept.push(e);
            }
        }
        Ok(kept)
    }
}

#[cfg(test)]
mod tests {
    use stereo_io::datasets::stereogen::Difficulty;

    use super::*;

    fn entry(category: &str, occluded: Option<f64>) -> ManifestEntry {
        let mut e: ManifestEntry = serde_json::from_value(serde_json::json!({
            "id": "0000007", "category": category, "index": 7,
            "files": {"left": "l", "right": "r", "disp_left": "a", "disp_right": "b", "scene": "s"},
            "width": 1, "height": 1, "f_px": 1.0, "baseline_m": 1.0, "cx": 0.5, "cy": 0.5
        }))
        .unwrap();
        e.difficulty = occluded.map(|occluded| Difficulty {
            occluded,
            low_texture: 0.5,
            disparity_p1: 1.0,
            disparity_p99: 30.0,
            transparent_mirror: None,
        });
        e
    }

    fn sel(text: &str) -> Selection {
        text.parse().unwrap_or_else(|e| panic!("{e}"))
    }

    #[test]
    fn conditions_compare_and_join_with_and() {
        let e = entry("tree", Some(0.1));
        assert!(sel("occluded < 0.2").matches(&e).unwrap());
        assert!(!sel("occluded >= 0.2").matches(&e).unwrap());
        assert!(
            sel("occluded<=0.1 and low_texture == 0.5")
                .matches(&e)
                .unwrap()
        );
        assert!(
            !sel("occluded < 0.2 and disparity_p99 > 30")
                .matches(&e)
                .unwrap()
        );
        assert!(
            sel("category == 'tree' and index != 3")
                .matches(&e)
                .unwrap()
        );
        assert!(!sel("category != \"tree\"").matches(&e).unwrap());
        assert_eq!(sel(" occluded < 0.2 ").to_string(), "occluded < 0.2");
    }

    #[test]
    fn bad_expressions_and_missing_facts_are_errors() {
        for (text, says) in [
            ("occluded", "no comparison"),
            ("blur < 2", "unknown field \"blur\""),
            ("occluded < x", "not a number"),
            ("category < 'tree'", "== or != only"),
            ("category == tree", "quoted name"),
            ("occluded < 1 and ", "empty condition"),
        ] {
            let e = text.parse::<Selection>().unwrap_err();
            assert!(e.contains(says), "{text}: {e}");
        }
        let e = sel("occluded < 0.2")
            .matches(&entry("tree", None))
            .unwrap_err()
            .to_string();
        assert!(e.contains("sample 0000007 has no occluded"), "{e}");
    }
}

//! One small declarative checker for recipes and scene specs: each checked value is a row (its
//! key path, the value, the rule it must obey), and every broken rule reads the same way:
//! "key `K` is invalid: need ..., got ...". The rows of a recipe are in `recipe/validate.rs`,
//! grouped by recipe section; the rows of a scene spec in [`scene_spec`].

use std::borrow::Cow;
use std::collections::BTreeMap;

use crate::dist::{CountRange, Dist, UniformRange};

pub mod geometry;
pub mod scene_spec;

/// A value that breaks its rule: the key path and what the key allows, with the value found.
#[derive(Debug, Clone, PartialEq, thiserror::Error)]
#[error("key `{key}` is invalid: {allowed}")]
pub struct Violation {
    pub key: String,
    pub allowed: String,
}

/// The rule a checked value must obey, holding the value.
#[derive(Debug, Clone)]
pub enum Rule<'a> {
    /// An integer in `lo..=hi`.
    Int { value: u64, lo: u64, hi: u64 },
    /// A finite number in `lo..=hi`.
    Number { value: f64, lo: f64, hi: f64 },
    /// A finite number with `lo <= value < hi`.
    BelowExclusive { value: f64, lo: f64, hi: f64 },
    /// A finite number with `0 < value <= max`.
    Positive { value: f64, max: f64 },
    /// A probability: `0..=1`.
    Probability(f64),
    /// A distribution whose support lies in `[lo, hi]` (and whose shape is well defined).
    Dist { dist: &'a Dist, lo: f64, hi: f64 },
    /// An integer range inside `lo..=hi`.
    Count {
        range: &'a CountRange,
        lo: u32,
        hi: u32,
    },
    /// A uniform range inside `[lo, hi]`.
    Range {
        range: &'a UniformRange,
        lo: f64,
        hi: f64,
    },
    /// A finite `[min, max]` pair with `0 < min <= max` (and `max <= cap` when there is one).
    PositivePair { pair: [f64; 2], cap: Option<f64> },
    /// Every value its type can hold is allowed (a switch, an unset option).
    AnyValue,
    /// A rule that spans keys or has its own words: `holds`, else `need` says what is allowed.
    Holds { holds: bool, need: String },
}

impl Rule<'_> {
    /// Weights (of any key type) that are all `>= 0` with a positive sum.
    pub fn weights<K: std::fmt::Debug>(weights: &BTreeMap<K, f64>) -> Rule<'static> {
        let holds = weights.values().all(|v| v.is_finite() && *v >= 0.0)
            && weights.values().sum::<f64>() > 0.0;
        Rule::Holds {
            holds,
            need: format!("need weights >= 0 with a positive sum, got {weights:?}"),
        }
    }

    /// A name that can be a folder: letters, digits, '_' or '-'.
    pub fn folder_name(name: &str) -> Rule<'static> {
        Rule::Holds {
            holds: is_folder_name(name),
            need: format!("need letters, digits, '_' or '-', got {name:?}"),
        }
    }

    /// What is allowed, when the value breaks the rule.
    fn broken(&self) -> Option<String> {
        let finite_in = |v: f64, lo: f64, hi: f64| v.is_finite() && (lo..=hi).contains(&v);
        match *self {
            Rule::Int { value, lo, hi } => {
                (!(lo..=hi).contains(&value)).then(|| format!("need {lo}..={hi}, got {value}"))
            }
            Rule::Number { value, lo, hi } => {
                (!finite_in(value, lo, hi)).then(|| format!("need {lo}..={hi}, got {value}"))
            }
            Rule::BelowExclusive { value, lo, hi } => {
                (!(value.is_finite() && lo <= value && value < hi))
                    .then(|| format!("need {lo} <= value < {hi}, got {value}"))
            }
            Rule::Positive { value, max } => (!(value.is_finite() && value > 0.0 && value <= max))
                .then(|| format!("need 0 < value <= {max}, got {value}")),
            Rule::Probability(p) => {
                (!finite_in(p, 0.0, 1.0)).then(|| format!("need a probability in 0..=1, got {p}"))
            }
            Rule::Dist { dist, lo, hi } => dist.validate(lo, hi).err(),
            Rule::Count { range, lo, hi } => range.validate(lo, hi).err(),
            Rule::Range { range, lo, hi } => range.validate(lo, hi).err(),
            Rule::PositivePair {
                pair: [lo, hi],
                cap,
            } => {
                let ordered = lo.is_finite() && hi.is_finite() && 0.0 < lo && lo <= hi;
                let capped = cap.is_none_or(|cap| hi <= cap);
                let need = cap.map_or(String::new(), |cap| format!(" <= {cap}"));
                (!(ordered && capped))
                    .then(|| format!("need 0 < min <= max{need}, got [{lo}, {hi}]"))
            }
            Rule::AnyValue => None,
            Rule::Holds { holds, ref need } => (!holds).then(|| need.clone()),
        }
    }
}

/// Whether `name` can be a folder name: letters, digits, '_' or '-'.
pub fn is_folder_name(name: &str) -> bool {
    !name.is_empty()
        && name
            .chars()
            .all(|c| c.is_ascii_alphanumeric() || c == '_' || c == '-')
}

/// One checked value: its key path, its rule, and whether the key has a default (it may be left
/// out of a file; recipes: a key of `added_keys!`).
#[derive(Debug, Clone)]
pub struct Check<'a> {
    pub key: Cow<'a, str>,
    pub rule: Rule<'a>,
    pub has_default: bool,
}

impl<'a> Check<'a> {
    pub fn new(key: impl Into<Cow<'a, str>>, rule: Rule<'a>) -> Self {
        Self {
            key: key.into(),
            rule,
            has_default: false,
        }
    }

    /// Marks the key as one with a default.
    pub fn with_default(mut self) -> Self {
        self.has_default = true;
        self
    }

    /// The violation, when the value breaks the rule.
    pub fn violation(&self) -> Option<Violation> {
        self.rule.broken().map(|allowed| Violation {
            key: self.key.to_string(),
            allowed,
        })
    }
}

/// The first row, in order, whose value breaks its rule.
pub fn first_violation<'a>(checks: impl IntoIterator<Item = Check<'a>>) -> Result<(), Violation> {
    match checks.into_iter().find_map(|c| c.violation()) {
        Some(v) => Err(v),
        None => Ok(()),
    }
}

/// Shorthands for the rows' rules.
pub type Key<'a> = Cow<'a, str>;

pub fn dist<'a>(key: &'a str, dist: &'a Dist, lo: f64, hi: f64) -> Check<'a> {
    Check::new(key, Rule::Dist { dist, lo, hi })
}

pub fn int(key: &str, value: impl Into<u64>, lo: u64, hi: u64) -> Check<'_> {
    let value = value.into();
    Check::new(key, Rule::Int { value, lo, hi })
}

pub fn count<'a>(key: impl Into<Key<'a>>, range: &'a CountRange, lo: u32, hi: u32) -> Check<'a> {
    Check::new(key, Rule::Count { range, lo, hi })
}

pub fn number(key: &str, value: f64, lo: f64, hi: f64) -> Check<'_> {
    Check::new(key, Rule::Number { value, lo, hi })
}

pub fn range<'a>(key: impl Into<Key<'a>>, range: &'a UniformRange, lo: f64, hi: f64) -> Check<'a> {
    Check::new(key, Rule::Range { range, lo, hi })
}

pub fn probability(key: &str, value: f64) -> Check<'_> {
    Check::new(key, Rule::Probability(value))
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn every_rule_names_the_key_and_the_value() {
        let cases = [
            (
                int("a.n", 3u32, 16, 64),
                "key `a.n` is invalid: need 16..=64, got 3",
            ),
            (number("a.x", f64::NAN, 0.0, 1.0), "need 0..=1, got NaN"),
            (
                Check::new(
                    "a.m",
                    Rule::BelowExclusive {
                        value: 0.4,
                        lo: 0.0,
                        hi: 0.4,
                    },
                ),
                "need 0 <= value < 0.4, got 0.4",
            ),
            (
                Check::new(
                    "a.p",
                    Rule::Positive {
                        value: 0.0,
                        max: 10.0,
                    },
                ),
                "need 0 < value <= 10, got 0",
            ),
            (
                probability("a.q", 1.5),
                "need a probability in 0..=1, got 1.5",
            ),
            (
                Check::new(
                    "a.w",
                    Rule::PositivePair {
                        pair: [2.0, 1.0],
                        cap: Some(64.0),
                    },
                ),
                "need 0 < min <= max <= 64, got [2, 1]",
            ),
            (
                Check::new("a.f", Rule::folder_name("a b")),
                "need letters, digits, '_' or '-', got \"a b\"",
            ),
        ];
        for (check, message) in cases {
            let v = check.violation().expect("the value breaks its rule");
            assert!(v.to_string().contains(message), "{v}");
            assert!(v.to_string().contains(&format!("`{}`", check.key)), "{v}");
        }
        assert!(int("a.n", 16u32, 16, 64).violation().is_none());
        assert!(number("a.x", 1.0, 0.0, 1.0).violation().is_none());
        let w: BTreeMap<&str, f64> = [("a", 0.0)].into();
        assert!(Check::new("w", Rule::weights(&w)).violation().is_some());
    }

    #[test]
    fn the_first_broken_row_in_order_is_reported() {
        let rows = [
            number("first", 0.5, 0.0, 1.0),
            number("second", 2.0, 0.0, 1.0),
            number("third", 3.0, 0.0, 1.0),
        ];
        assert_eq!(first_violation(rows).unwrap_err().key, "second");
    }
}

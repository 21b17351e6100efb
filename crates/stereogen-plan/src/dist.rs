//! Distributions a recipe can name for any continuous quantity, sampled with `rand_distr`.
//! Each also knows its CDF, so the stats command can measure how well a dataset follows it.

use rand::Rng;
use rand_distr::{Distribution as _, Normal, Uniform};
use serde::{Deserialize, Serialize};

/// A continuous distribution, written in TOML as e.g. `{ dist = "uniform", min = 1, max = 5 }`,
/// `{ dist = "log_uniform", ... }`, `{ dist = "normal", mean = 3, std = 1, min = 0, max = 6 }`
/// (truncated to [min, max]), `{ dist = "histogram", edges = [0, 10, 50], weights = [1, 3] }`
/// (uniform inside each bin), or a bare number for a constant.
#[derive(Debug, Clone, PartialEq, Serialize)]
#[serde(untagged)]
pub enum Dist {
    Constant(f64),
    Shaped(Shaped),
}

// By hand rather than `untagged`, so a bad table reports its own problem ("unknown variant
// `cauchy`", "missing field `max`") instead of "did not match any variant".
impl<'de> Deserialize<'de> for Dist {
    fn deserialize<D: serde::Deserializer<'de>>(d: D) -> Result<Self, D::Error> {
        struct V;
        impl<'de> serde::de::Visitor<'de> for V {
            type Value = Dist;
            fn expecting(&self, f: &mut std::fmt::Formatter) -> std::fmt::Result {
                f.write_str("a number or a table like { dist = \"uniform\", min = 1, max = 2 }")
            }
            fn visit_f64<E: serde::de::Error>(self, v: f64) -> Result<Dist, E> {
                Ok(Dist::Constant(v))
            }
            fn visit_i64<E: serde::de::Error>(self, v: i64) -> Result<Dist, E> {
                Ok(Dist::Constant(v as f64))
            }
            fn visit_u64<E: serde::de::Error>(self, v: u64) -> Result<Dist, E> {
                Ok(Dist::Constant(v as f64))
            }
            fn visit_map<A: serde::de::MapAccess<'de>>(self, map: A) -> Result<Dist, A::Error> {
                Shaped::deserialize(serde::de::value::MapAccessDeserializer::new(map))
                    .map(Dist::Shaped)
            }
        }
        d.deserialize_any(V)
    }
}

#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(tag = "dist", rename_all = "snake_case", deny_unknown_fields)]
pub enum Shaped {
    Uniform {
        min: f64,
        max: f64,
    },
    LogUniform {
        min: f64,
        max: f64,
    },
    Normal {
        mean: f64,
        std: f64,
        min: f64,
        max: f64,
    },
    Histogram {
        edges: Vec<f64>,
        weights: Vec<f64>,
    },
}

impl Dist {
    pub fn uniform(min: f64, max: f64) -> Self {
        Dist::Shaped(Shaped::Uniform { min, max })
    }

    pub fn log_uniform(min: f64, max: f64) -> Self {
        Dist::Shaped(Shaped::LogUniform { min, max })
    }

    /// Smallest and largest value the distribution can produce.
    pub fn support(&self) -> (f64, f64) {
        match self {
            Dist::Constant(v) => (*v, *v),
            Dist::Shaped(
                Shaped::Uniform { min, max }
                | Shaped::LogUniform { min, max }
                | Shaped::Normal { min, max, .. },
            ) => (*min, *max),
            Dist::Shaped(Shaped::Histogram { edges, .. }) => (edges[0], edges[edges.len() - 1]),
        }
    }

    /// Checks the parameters; `lo..=hi` is the range the quantity may take at all.
    pub fn validate(&self, lo: f64, hi: f64) -> Result<(), String> {
        let finite = |v: f64| v.is_finite();
        let (min, max) = self.support();
        if !(finite(min) && finite(max) && lo <= min && min <= max && max <= hi) {
            return Err(format!(
                "need {lo} <= min <= max <= {hi}, got [{min}, {max}]"
            ));
        }
        match self {
            Dist::Shaped(Shaped::LogUniform { min, .. }) if *min <= 0.0 => {
                Err("log_uniform needs min > 0".into())
            }
            Dist::Shaped(Shaped::Normal { mean, std, .. })
                if !(finite(*mean) && finite(*std) && *std > 0.0) =>
            {
                Err("normal needs a finite mean and std > 0".into())
            }
            Dist::Shaped(Shaped::Normal {
                mean,
                std,
                min,
                max,
            }) if self.normal_mass(*mean, *std, *min, *max) < 1e-3 => {
                Err("normal has almost no mass inside [min, max]".into())
            }
            Dist::Shaped(Shaped::Histogram { edges, weights }) => {
                if edges.len() < 2 || weights.len() != edges.len() - 1 {
                    return Err("histogram needs n+1 edges for n weights".into());
                }
                if edges.windows(2).any(|w| w[1] <= w[0]) {
                    return Err("histogram edges must increase".into());
                }
                if weights.iter().any(|w| !(finite(*w) && *w >= 0.0))
                    || weights.iter().sum::<f64>() <= 0.0
                {
                    return Err("histogram weights must be >= 0 with a positive sum".into());
                }
                Ok(())
            }
            _ => Ok(()),
        }
    }

    fn normal_mass(&self, mean: f64, std: f64, min: f64, max: f64) -> f64 {
        normal_cdf((max - mean) / std) - normal_cdf((min - mean) / std)
    }

    pub fn sample<R: Rng + ?Sized>(&self, rng: &mut R) -> f64 {
        match self {
            Dist::Constant(v) => *v,
            Dist::Shaped(Shaped::Uniform { min, max }) => uniform(rng, *min, *max),
            Dist::Shaped(Shaped::LogUniform { min, max }) => uniform(rng, min.ln(), max.ln()).exp(),
            Dist::Shaped(Shaped::Normal {
                mean,
                std,
                min,
                max,
            }) => {
                // Rejection keeps the exact truncated shape; validation guarantees enough mass.
                let n = Normal::new(*mean, *std).expect("validated");
                loop {
                    let v = n.sample(rng);
                    if (*min..=*max).contains(&v) {
                        return v;
                    }
                }
            }
            Dist::Shaped(Shaped::Histogram { edges, weights }) => {
                let total: f64 = weights.iter().sum();
                let mut pick = uniform(rng, 0.0, total);
                for (i, w) in weights.iter().enumerate() {
                    if pick < *w || i == weights.len() - 1 {
                        return uniform(rng, edges[i], edges[i + 1]);
                    }
                    pick -= w;
                }
                unreachable!()
            }
        }
    }

    /// P(X <= x).
    pub fn cdf(&self, x: f64) -> f64 {
        match self {
            Dist::Constant(v) => f64::from(u8::from(x >= *v)),
            Dist::Shaped(Shaped::Uniform { min, max }) => ramp(x, *min, *max),
            Dist::Shaped(Shaped::LogUniform { min, max }) => {
                if x <= *min {
                    0.0
                } else {
                    ramp(x.ln(), min.ln(), max.ln())
                }
            }
            Dist::Shaped(Shaped::Normal {
                mean,
                std,
                min,
                max,
            }) => {
                if x <= *min {
                    return 0.0;
                }
                if x >= *max {
                    return 1.0;
                }
                let lo = normal_cdf((min - mean) / std);
                (normal_cdf((x - mean) / std) - lo) / (normal_cdf((max - mean) / std) - lo)
            }
            Dist::Shaped(Shaped::Histogram { edges, weights }) => {
                let total: f64 = weights.iter().sum();
                let mut acc = 0.0;
                for (i, w) in weights.iter().enumerate() {
                    if x < edges[i + 1] {
                        return (acc + w * ramp(x, edges[i], edges[i + 1])) / total;
                    }
                    acc += w;
                }
                1.0
            }
        }
    }
}

fn uniform<R: Rng + ?Sized>(rng: &mut R, min: f64, max: f64) -> f64 {
    if min == max {
        min
    } else {
        Uniform::new_inclusive(min, max)
            .expect("validated range")
            .sample(rng)
    }
}

fn ramp(x: f64, a: f64, b: f64) -> f64 {
    if b <= a {
        f64::from(u8::from(x >= a))
    } else {
        ((x - a) / (b - a)).clamp(0.0, 1.0)
    }
}

/// Standard normal CDF.
pub fn normal_cdf(z: f64) -> f64 {
    0.5 * erfc(-z / std::f64::consts::SQRT_2)
}

/// Complementary error function, |relative error| < 1.2e-7 (Numerical Recipes' erfcc Chebyshev fit).
fn erfc(x: f64) -> f64 {
    let z = x.abs();
    let t = 1.0 / (1.0 + 0.5 * z);
    let r = t
        * (-z * z - 1.265_512_23
            + t * (1.000_023_68
                + t * (0.374_091_96
                    + t * (0.096_784_18
                        + t * (-0.186_288_06
                            + t * (0.278_868_07
                                + t * (-1.135_203_98
                                    + t * (1.488_515_87
                                        + t * (-0.822_152_23 + t * 0.170_872_77)))))))))
            .exp();
    if x >= 0.0 { r } else { 2.0 - r }
}

/// Kolmogorov–Smirnov distance between a sample and a distribution's CDF.
pub fn ks_distance(sample: &[f64], dist: &Dist) -> f64 {
    let mut xs: Vec<f64> = sample.iter().copied().filter(|v| v.is_finite()).collect();
    xs.sort_by(f64::total_cmp);
    let n = xs.len() as f64;
    xs.iter()
        .enumerate()
        .map(|(i, &x)| {
            let f = dist.cdf(x);
            (f - i as f64 / n).abs().max(((i + 1) as f64 / n - f).abs())
        })
        .fold(0.0, f64::max)
}

/// The KS critical distance at significance `alpha` for a sample of `n`: the asymptotic
/// c(α) = sqrt(−ln(α/2)/2) with Stephens' small-sample correction c(α) / (√n + 0.12 + 0.11/√n),
/// within about 1% of the exact table down to n = 5.
pub fn ks_critical(n: usize, alpha: f64) -> f64 {
    let c = (-0.5 * (alpha / 2.0).ln()).sqrt();
    let r = (n as f64).sqrt();
    c / (r + 0.12 + 0.11 / r)
}

/// An integer range drawn uniformly, written `[min, max]` or a single number.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
#[serde(from = "NumberOrPair<u32>", into = "[u32; 2]")]
pub struct CountRange {
    pub min: u32,
    pub max: u32,
}

/// A range as a recipe writes it: one number (min = max) or a `[min, max]` pair.
#[derive(Deserialize)]
#[serde(untagged, expecting = "a number or a [min, max] pair")]
enum NumberOrPair<T> {
    Fixed(T),
    Pair([T; 2]),
}

impl<T: Copy> NumberOrPair<T> {
    fn bounds(self) -> [T; 2] {
        match self {
            Self::Fixed(v) => [v, v],
            Self::Pair(pair) => pair,
        }
    }
}

/// The serde conversions of a `{ min, max }` range type: read from a number or a pair, written
/// as a pair.
macro_rules! range_conversions {
    ($range:ident, $t:ty) => {
        impl From<NumberOrPair<$t>> for $range {
            fn from(r: NumberOrPair<$t>) -> Self {
                let [min, max] = r.bounds();
                Self { min, max }
            }
        }

        impl From<$range> for [$t; 2] {
            fn from(r: $range) -> Self {
                [r.min, r.max]
            }
        }
    };
}

range_conversions!(CountRange, u32);

impl CountRange {
    pub fn sample<R: Rng + ?Sized>(&self, rng: &mut R) -> u32 {
        rng.random_range(self.min..=self.max)
    }

    pub fn validate(&self, lo: u32, hi: u32) -> Result<(), String> {
        if lo <= self.min && self.min <= self.max && self.max <= hi {
            Ok(())
        } else {
            Err(format!("need {lo} <= min <= max <= {hi}"))
        }
    }
}

/// A value drawn uniformly from [min, max), written `[min, max]` (or a number for a constant).
/// The planner's secondary knobs (light placement, material class ranges, leaf colours) use it:
/// it draws exactly as the planner did before they were recipe keys, so plans stay identical.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
#[serde(from = "NumberOrPair<f64>", into = "[f64; 2]")]
pub struct UniformRange {
    pub min: f64,
    pub max: f64,
}

range_conversions!(UniformRange, f64);

impl UniformRange {
    pub const fn new(min: f64, max: f64) -> Self {
        Self { min, max }
    }

    pub fn sample<R: Rng + ?Sized>(&self, rng: &mut R) -> f64 {
        if self.min < self.max {
            rng.random_range(self.min..self.max)
        } else {
            // A constant still takes its draw, so the draws after it in the stream do not move.
            let _ = rng.random::<u64>();
            self.min
        }
    }

    pub fn validate(&self, lo: f64, hi: f64) -> Result<(), String> {
        let ok = self.min.is_finite()
            && self.max.is_finite()
            && lo <= self.min
            && self.min <= self.max
            && self.max <= hi;
        if ok {
            Ok(())
        } else {
            Err(format!(
                "need {lo} <= min <= max <= {hi}, got [{}, {}]",
                self.min, self.max
            ))
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use rand::SeedableRng;

    #[test]
    fn uniform_ranges_draw_like_random_range_and_constants_keep_the_stream_aligned() {
        let mut a = rand_chacha::ChaCha8Rng::seed_from_u64(3);
        let mut b = a.clone();
        let r: UniformRange =
            toml::from_str::<std::collections::BTreeMap<String, UniformRange>>("x = [0.2, 1.0]")
                .unwrap()["x"];
        assert_eq!(r.sample(&mut a), b.random_range(0.2..1.0));
        assert_eq!(UniformRange::new(0.5, 0.5).sample(&mut a), 0.5);
        let _ = b.random_range(0.0..1.0);
        assert_eq!(a.random::<u64>(), b.random::<u64>());
        assert!(UniformRange::new(0.3, 0.1).validate(0.0, 1.0).is_err());
    }

    #[test]
    fn ranges_read_a_number_or_a_pair_and_say_so_otherwise() {
        type Ranges<T> = std::collections::BTreeMap<String, T>;
        let counts: Ranges<CountRange> = toml::from_str("a = 3\nb = [1, 4]").unwrap();
        assert_eq!(counts["a"], CountRange { min: 3, max: 3 });
        assert_eq!(counts["b"], CountRange { min: 1, max: 4 });
        let values: Ranges<UniformRange> = toml::from_str("a = 2\nb = [0.5, 1.5]").unwrap();
        assert_eq!(values["a"], UniformRange::new(2.0, 2.0));
        assert_eq!(values["b"], UniformRange::new(0.5, 1.5));
        for bad in ["a = 'many'", "a = [1, 2, 3]"] {
            let e = toml::from_str::<Ranges<CountRange>>(bad).unwrap_err();
            assert!(
                e.to_string().contains("a number or a [min, max] pair"),
                "{bad}: {e}"
            );
        }
    }

    fn check_law(dist: Dist) {
        dist.validate(f64::NEG_INFINITY, f64::INFINITY).unwrap();
        let mut rng = rand_chacha::ChaCha8Rng::seed_from_u64(5);
        let xs: Vec<f64> = (0..20_000).map(|_| dist.sample(&mut rng)).collect();
        let (lo, hi) = dist.support();
        assert!(xs.iter().all(|x| (lo..=hi).contains(x)));
        let d = ks_distance(&xs, &dist);
        assert!(d < ks_critical(xs.len(), 0.01), "{dist:?}: KS {d}");
        // A different law must be told apart.
        let other = Dist::uniform(lo, lo + (hi - lo) * 0.8);
        assert!(ks_distance(&xs, &other) > ks_critical(xs.len(), 0.01));
    }

    #[test]
    fn samples_follow_their_cdf() {
        check_law(Dist::uniform(2.0, 200.0));
        check_law(Dist::log_uniform(0.5, 300.0));
        check_law(Dist::Shaped(Shaped::Normal {
            mean: 40.0,
            std: 25.0,
            min: 1.0,
            max: 120.0,
        }));
        check_law(Dist::Shaped(Shaped::Histogram {
            edges: vec![1.0, 10.0, 50.0, 200.0],
            weights: vec![1.0, 3.0, 2.0],
        }));
    }

    #[test]
    fn ks_critical_matches_the_exact_table() {
        // Exact two-sided KS critical values at alpha = 0.01 (Miller 1956).
        for (n, exact) in [
            (5, 0.669),
            (8, 0.543),
            (10, 0.490),
            (20, 0.356),
            (40, 0.252),
        ] {
            let c = ks_critical(n, 0.01);
            assert!((c - exact).abs() / exact < 0.015, "n={n}: {c} vs {exact}");
        }
    }

    #[test]
    fn normal_cdf_is_accurate() {
        assert!((normal_cdf(0.0) - 0.5).abs() < 1e-7);
        assert!((normal_cdf(1.0) - 0.841_344_746).abs() < 1e-6);
        assert!((normal_cdf(-2.5) - 0.006_209_665).abs() < 1e-6);
    }

    #[test]
    fn toml_forms_parse() {
        #[derive(Deserialize)]
        struct T {
            a: Dist,
            b: Dist,
            c: Dist,
        }
        let text = "a = 3.0\nb = { dist = \"log_uniform\", min = 1, max = 9 }\n\
                    c = { dist = \"histogram\", edges = [0, 1, 2], weights = [1, 1] }";
        let t: T = toml::from_str(text).unwrap();
        assert_eq!(t.a, Dist::Constant(3.0));
        assert_eq!(t.b, Dist::log_uniform(1.0, 9.0));
        assert!(t.c.validate(0.0, 10.0).is_ok());
        assert!(
            toml::from_str::<T>("a = 1\nb = { dist = \"cauchy\", min = 1, max = 2 }\nc = 1")
                .is_err()
        );
    }
}

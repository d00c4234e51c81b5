//! One `[[axis]]` of a sweep file: its keys and the values they take, resolved from a list,
//! a range, random draws or a zip of lists.

use rand::{RngExt, SeedableRng};
use rand_chacha::ChaCha8Rng;
use serde::Deserialize;
use toml::Value;

/// Significant digits kept for generated floats: enough to tell sweep points apart, short
/// enough to read in labels and tables. Ranges keep more where neighbours would collide.
const DIGITS: usize = 6;

/// One dimension of a sweep: the keys it sets and, per point, one value for each key.
///
/// A plain axis has one key; a zip axis moves several keys together.
#[derive(Debug, Clone, PartialEq)]
pub struct Axis {
    /// Dotted keys into the config, in file order.
    pub keys: Vec<String>,
    /// The axis's points; each holds one value per key, in the order of `keys`.
    pub points: Vec<Vec<Value>>,
}

/// An `[[axis]]` table as written; exactly one of `values`, `range`, `random`, `zip`.
#[derive(Debug, Deserialize)]
#[serde(deny_unknown_fields)]
pub(crate) struct RawAxis {
    key: Option<String>,
    values: Option<Vec<Value>>,
    range: Option<RangeSpec>,
    random: Option<RandomSpec>,
    zip: Option<Vec<ZipEntry>>,
}

/// Evenly spaced points from `from` to `to`, both included.
#[derive(Debug, Deserialize)]
#[serde(deny_unknown_fields)]
struct RangeSpec {
    from: f64,
    to: f64,
    steps: usize,
    #[serde(default)]
    scale: Scale,
    #[serde(default)]
    integer: bool,
}

/// `draws` values drawn uniformly (or log-uniformly) from `low..=high`, reproducible from `seed`.
#[derive(Debug, Deserialize)]
#[serde(deny_unknown_fields)]
struct RandomSpec {
    low: f64,
    high: f64,
    draws: usize,
    seed: u64,
    #[serde(default)]
    scale: Scale,
    #[serde(default)]
    integer: bool,
}

#[derive(Debug, Deserialize)]
#[serde(deny_unknown_fields)]
struct ZipEntry {
    key: String,
    values: Vec<Value>,
}

#[derive(Debug, Clone, Copy, Default, PartialEq, Deserialize)]
#[serde(rename_all = "lowercase")]
enum Scale {
    #[default]
    Linear,
    Log,
}

impl RawAxis {
    /// How errors name this axis before it is known to be valid.
    pub(crate) fn describe(&self) -> String {
        match (&self.key, &self.zip) {
            (None, Some(zip)) => {
                let keys: Vec<&str> = zip.iter().map(|entry| entry.key.as_str()).collect();
                format!("zip of {}", keys.join(", "))
            }
            (Some(key), _) => format!("key `{key}`"),
            (None, None) => "no key".to_string(),
        }
    }

    /// Resolves the axis into its points.
    pub(crate) fn resolve(self) -> Result<Axis, String> {
        let values = match (self.values, self.range, self.random, self.zip) {
            (Some(values), None, None, None) if values.is_empty() => {
                return Err("`values` is empty".to_string());
            }
            (Some(values), None, None, None) => values,
            (None, Some(range), None, None) => range.points()?,
            (None, None, Some(random), None) => random.draw()?,
            (None, None, None, Some(zip)) => {
                if self.key.is_some() {
                    return Err(
                        "a `zip` axis names its keys inside `zip`, not in `key`".to_string()
                    );
                }
                return zip_axis(zip);
            }
            _ => {
                return Err("give exactly one of `values`, `range`, `random` or `zip`".to_string());
            }
        };
        let key = self
            .key
            .ok_or("`key` is missing (the dotted config key this axis sets)")?;
        Ok(Axis {
            keys: vec![key],
            points: values.into_iter().map(|value| vec![value]).collect(),
        })
    }
}

fn zip_axis(zip: Vec<ZipEntry>) -> Result<Axis, String> {
    let Some(first) = zip.first() else {
        return Err("`zip` is empty".to_string());
    };
    let len = first.values.len();
    if len == 0 {
        return Err(format!("`values` of zip key `{}` is empty", first.key));
    }
    if let Some(other) = zip.iter().find(|entry| entry.values.len() != len) {
        return Err(format!(
            "zip lengths differ: `{}` has {len} values, `{}` has {}",
            first.key,
            other.key,
            other.values.len()
        ));
    }
    let keys = zip.iter().map(|entry| entry.key.clone()).collect();
    let points = (0..len)
        .map(|i| zip.iter().map(|entry| entry.values[i].clone()).collect())
        .collect();
    Ok(Axis { keys, points })
}

impl RangeSpec {
    fn points(&self) -> Result<Vec<Value>, String> {
        let Self {
            from,
            to,
            steps,
            scale,
            integer,
        } = *self;
        if !from.is_finite() || !to.is_finite() {
            return Err("range bounds must be finite".to_string());
        }
        if steps < 2 {
            return Err(format!(
                "range steps = {steps}: a range takes at least 2 steps (it includes both ends); \
                 use `values` for a single value"
            ));
        }
        if from == to {
            return Err(format!("range from = to = {from}: use `values`"));
        }
        if scale == Scale::Log && (from <= 0.0 || to <= 0.0) {
            return Err(format!(
                "a log range needs positive bounds, got from = {from}, to = {to}"
            ));
        }
        if integer {
            check_integral("from", from)?;
            check_integral("to", to)?;
        }
        let last = steps - 1;
        let raw: Vec<f64> = (0..steps)
            .map(|i| {
                let t = i as f64 / last as f64;
                // The ends are the bounds as written, not a computation that may miss them.
                match (i, scale) {
                    (0, _) => from,
                    (i, _) if i == last => to,
                    (_, Scale::Linear) => from + (to - from) * t,
                    (_, Scale::Log) => (from.ln() + (to.ln() - from.ln()) * t).exp(),
                }
            })
            .collect();
        if integer {
            let rounded: Vec<f64> = raw.iter().map(|x| x.round()).collect();
            if let Some(pair) = rounded.windows(2).find(|pair| pair[0] == pair[1]) {
                return Err(format!(
                    "integer range repeats {} after rounding: take fewer steps",
                    pair[0]
                ));
            }
            return Ok(rounded.into_iter().map(integer_value).collect());
        }
        // Round the interior points as little as keeps neighbours apart.
        let distinct = (DIGITS..=17)
            .map(|digits| {
                let mut points = raw.clone();
                for x in &mut points[1..last] {
                    *x = round_significant(*x, digits);
                }
                points
            })
            .find(|points| points.windows(2).all(|pair| pair[0] != pair[1]))
            .ok_or("range points are too close to tell apart: take fewer steps")?;
        Ok(distinct.into_iter().map(Value::Float).collect())
    }
}

impl RandomSpec {
    fn draw(&self) -> Result<Vec<Value>, String> {
        let Self {
            low,
            high,
            draws,
            seed,
            scale,
            integer,
        } = *self;
        if !low.is_finite() || !high.is_finite() {
            return Err("random bounds must be finite".to_string());
        }
        if low > high {
            return Err(format!("random low = {low} is above high = {high}"));
        }
        if draws == 0 {
            return Err("random draws = 0: draw at least one value".to_string());
        }
        if scale == Scale::Log && low <= 0.0 {
            return Err(format!(
                "log-uniform draws need positive bounds, got low = {low}"
            ));
        }
        if integer {
            check_integral("low", low)?;
            check_integral("high", high)?;
        }
        // Integers are drawn from [low, high + 1) and floored, so each is equally likely
        // (on a log scale, each in proportion to its share of the log interval).
        let top = if integer { high + 1.0 } else { high };
        let mut rng = ChaCha8Rng::seed_from_u64(seed);
        let values = (0..draws)
            .map(|_| {
                let u: f64 = rng.random();
                let x = match scale {
                    Scale::Linear => low + (top - low) * u,
                    Scale::Log => (low.ln() + (top.ln() - low.ln()) * u).exp(),
                };
                if integer {
                    integer_value(x.floor().clamp(low, high))
                } else {
                    Value::Float(round_significant(x, DIGITS).clamp(low, high))
                }
            })
            .collect();
        Ok(values)
    }
}

/// Integers beyond 2^53 are not exact in the f64 bounds they are given as.
fn check_integral(name: &str, x: f64) -> Result<(), String> {
    const EXACT: f64 = (1u64 << 53) as f64;
    if x.fract() == 0.0 && x.abs() <= EXACT {
        Ok(())
    } else {
        Err(format!(
            "`{name}` = {x} must be an integer (within ±2^53) when `integer = true`"
        ))
    }
}

/// A whole number within ±2^53 (checked above) as a TOML integer.
fn integer_value(x: f64) -> Value {
    Value::Integer(x as i64)
}

/// `x` rounded to `digits` significant decimal digits.
fn round_significant(x: f64, digits: usize) -> f64 {
    format!("{x:.*e}", digits - 1)
        .parse()
        .expect("a float formatted by Rust parses back")
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn rounds_to_significant_digits() {
        assert_eq!(round_significant(0.000316227766016838, 6), 0.000316228);
        assert_eq!(round_significant(123456.789, 6), 123457.0);
        assert_eq!(round_significant(-0.2000000000000001, 6), -0.2);
    }
}

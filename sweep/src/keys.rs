//! Dotted keys such as `learning.learning_rate`: paths into a config table.

use toml::{Table, Value};

/// Checks that `key` is a dotted path of TOML bare keys (quoted keys are not supported).
pub(crate) fn check_syntax(key: &str) -> Result<(), String> {
    let bare = |segment: &str| {
        !segment.is_empty()
            && segment
                .chars()
                .all(|c| c.is_ascii_alphanumeric() || c == '_' || c == '-')
    };
    if key.split('.').all(bare) {
        Ok(())
    } else {
        Err(format!(
            "key `{key}` is not a dotted path of bare keys (letters, digits, `_`, `-`)"
        ))
    }
}

/// Whether setting one key would replace or descend into the other's value.
pub(crate) fn overlap(a: &str, b: &str) -> bool {
    let nested = |outer: &str, inner: &str| {
        inner
            .strip_prefix(outer)
            .is_some_and(|rest| rest.is_empty() || rest.starts_with('.'))
    };
    nested(a, b) || nested(b, a)
}

/// Sets `key` in `table` to `value`, creating missing tables on the way: a base config may
/// leave out sections whose defaults it keeps.
pub(crate) fn set(table: &mut Table, key: &str, value: Value) -> Result<(), String> {
    let segments: Vec<&str> = key.split('.').collect();
    let (last, parents) = segments
        .split_last()
        .expect("splitting a string yields at least one segment");
    let mut current = table;
    for (depth, segment) in parents.iter().enumerate() {
        let entry = current
            .entry(*segment)
            .or_insert_with(|| Value::Table(Table::new()));
        current = match entry {
            Value::Table(inner) => inner,
            other => {
                return Err(format!(
                    "cannot set `{key}`: `{}` is {} {}, not a table",
                    segments[..=depth].join("."),
                    article(other.type_str()),
                    other.type_str()
                ));
            }
        };
    }
    current.insert((*last).to_string(), value);
    Ok(())
}

fn article(noun: &str) -> &'static str {
    if noun.starts_with(['a', 'e', 'i', 'o', 'u']) {
        "an"
    } else {
        "a"
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn syntax_accepts_bare_paths_only() {
        assert!(check_syntax("learning.learning_rate").is_ok());
        assert!(check_syntax("max_failures-per_scene").is_ok());
        assert!(check_syntax("").is_err());
        assert!(check_syntax("a..b").is_err());
        assert!(check_syntax(".a").is_err());
        assert!(check_syntax("a b").is_err());
        assert!(check_syntax("\"a.b\"").is_err());
    }

    #[test]
    fn overlap_is_by_whole_segments() {
        assert!(overlap("policy", "policy.epsilon_start"));
        assert!(overlap("policy.epsilon_start", "policy"));
        assert!(overlap("seed", "seed"));
        assert!(!overlap("seed", "seeds"));
        assert!(!overlap("policy.epsilon_start", "policy.epsilon_end"));
    }
}

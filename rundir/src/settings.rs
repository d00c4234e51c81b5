//! Settings that replace a run config's own: dotted keys with TOML values, from the command
//! line (`--set learning.gamma=0.9`), a pipeline file's `[set]` table or a settings file
//! (`eval --settings configs/test-time.toml`).

use std::path::Path;

use anyhow::{Context, Result};

use crate::config::RunConfig;

/// `key=value` as the one-entry TOML table it sets (`a.b=1` is `{ a = { b = 1 } }`); the
/// value parser of every `--set`.
pub fn parse_setting(arg: &str) -> Result<toml::Table, String> {
    let (key, value) = arg
        .split_once('=')
        .ok_or_else(|| format!("`{arg}` is not KEY=VALUE"))?;
    toml::from_str(&format!("{} = {}", key.trim(), value.trim())).map_err(|e| {
        format!(
            "`{arg}`: {} (a string value needs TOML quotes: KEY='\"text\"')",
            e.message()
        )
    })
}

/// The TOML file `path` as a table: a config before settings merge into it, or a settings
/// file (`eval --settings configs/test-time.toml`), whose tables give dotted keys as
/// `--set` does. Errors name the file, and the line where the TOML is bad.
pub fn read_table(path: &Path) -> Result<toml::Table> {
    let text =
        std::fs::read_to_string(path).with_context(|| format!("reading {}", path.display()))?;
    toml::from_str(&text).map_err(|e| anyhow::anyhow!("{}: {e}", path.display()))
}

/// Sets every key of `set` in `table`; where both hold a table, merges into it.
pub fn merge(table: &mut toml::Table, set: &toml::Table) {
    for (key, value) in set {
        match (table.get_mut(key), value) {
            (Some(toml::Value::Table(inner)), toml::Value::Table(patch)) => merge(inner, patch),
            _ => {
                table.insert(key.clone(), value.clone());
            }
        }
    }
}

/// The run config in the file `config` with `set` merged into it, checked, and its text
/// when `set` changed it. Errors name the file, and `by` (what gave the settings) when there
/// are any; a file without settings is read as written, so errors point at its lines.
pub fn load_with(
    config: &Path,
    set: &toml::Table,
    by: &str,
) -> Result<(RunConfig, Option<String>)> {
    if set.is_empty() {
        return Ok((RunConfig::load(config)?, None));
    }
    let text = resolve(config, set)?;
    let origin = format!("{} with {by}", config.display());
    Ok((RunConfig::parse(&text, &origin)?, Some(text)))
}

/// The text of the config file `config` with `set` merged into it.
fn resolve(config: &Path, set: &toml::Table) -> Result<String> {
    let mut table = read_table(config)?;
    merge(&mut table, set);
    Ok(toml::to_string(&table)?)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn set_replaces_values_and_merges_into_tables() {
        let mut table: toml::Table =
            toml::from_str("seed = 1\n[buffer]\ncapacity = 8\nalpha = 0.6\n").unwrap();
        let set: toml::Table =
            toml::from_str("push_reward = \"none\"\nbuffer.relabel = false\nbuffer.alpha = 0.0\n")
                .unwrap();
        merge(&mut table, &set);
        let want: toml::Table = toml::from_str(
            "seed = 1\npush_reward = \"none\"\n[buffer]\ncapacity = 8\nalpha = 0.0\nrelabel = false\n",
        )
        .unwrap();
        assert_eq!(table, want);
    }

    #[test]
    fn a_command_line_setting_is_a_dotted_key_and_a_toml_value() {
        let want: toml::Table = toml::from_str("[learning]\nlearning_rate = 5e-4\n").unwrap();
        assert_eq!(
            parse_setting("learning.learning_rate = 5e-4").unwrap(),
            want
        );
        assert_eq!(
            parse_setting("push_reward=\"none\"").unwrap()["push_reward"].as_str(),
            Some("none")
        );
        assert!(parse_setting("seed").unwrap_err().contains("KEY=VALUE"));
        let error = parse_setting("push_reward=none").unwrap_err();
        assert!(
            error.contains("push_reward=none") && error.contains("quotes"),
            "{error}"
        );
    }
}

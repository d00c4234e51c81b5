//! The shipped stage-1 config with some settings changed, written beside a test's logs.

use std::path::{Path, PathBuf};

/// Writes `configs/stage1.toml` with each `key` (`table.key`, or a top-level key) set to its
/// value as `<dir>/<name>.toml`; returns its path.
pub fn stage1_with(dir: &Path, name: &str, settings: &[(&str, toml::Value)]) -> PathBuf {
    let shipped = Path::new(env!("CARGO_MANIFEST_DIR")).join("configs/stage1.toml");
    let mut config: toml::Table =
        toml::from_str(&std::fs::read_to_string(shipped).unwrap()).unwrap();
    for (key, value) in settings {
        let table = match key.split_once('.') {
            Some((table, _)) => config
                .entry(table)
                .or_insert_with(|| toml::Value::Table(toml::Table::new()))
                .as_table_mut()
                .unwrap(),
            None => &mut config,
        };
        let field = key.rsplit('.').next().unwrap();
        table.insert(field.into(), value.clone());
    }
    let path = dir.join(format!("{name}.toml"));
    std::fs::write(&path, toml::to_string(&config).unwrap()).unwrap();
    path
}

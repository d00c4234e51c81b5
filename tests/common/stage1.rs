//! The shipped stage-1 config with one setting changed, written beside a test's logs.

use std::path::{Path, PathBuf};

/// Writes `configs/stage1.toml` with `key` (`table.key`, or a top-level key) set to
/// `value` as `<dir>/<name>.toml`; returns its path.
pub fn stage1_with(dir: &Path, name: &str, key: &str, value: toml::Value) -> PathBuf {
    let shipped = Path::new(env!("CARGO_MANIFEST_DIR")).join("configs/stage1.toml");
    let mut config: toml::Table =
        toml::from_str(&std::fs::read_to_string(shipped).unwrap()).unwrap();
    let table = match key.split_once('.') {
        Some((table, _)) => config[table].as_table_mut().unwrap(),
        None => &mut config,
    };
    let field = key.rsplit('.').next().unwrap();
    table.insert(field.into(), value);
    let path = dir.join(format!("{name}.toml"));
    std::fs::write(&path, toml::to_string(&config).unwrap()).unwrap();
    path
}

//! The touching rows a random scene starts with, as command-line arguments (`scene render`,
//! `scene grasps`).

use clap::Args;
use clap::builder::RangedU64ValueParser;
use sim::Rows;

/// The touching rows a random scene starts with (the scenes a run config's `[rows]` asks
/// for).
#[derive(Args, Clone, Copy)]
pub struct RowArgs {
    /// Lay this many of the objects side by side, touching, before dropping the others.
    #[arg(long, default_value_t = 0)]
    pub row: usize,
    /// ... in this many lines side by side (more than one: a packed cluster).
    #[arg(long, default_value_t = 1, value_parser = RangedU64ValueParser::<usize>::new().range(1..))]
    pub lines: usize,
}

impl RowArgs {
    pub fn rows(&self) -> Rows {
        Rows {
            blocks: self.row,
            lines: self.lines,
        }
    }

    /// How a scene name says it: empty without rows.
    pub fn label(&self) -> String {
        match (self.row, self.lines) {
            (0 | 1, _) => String::new(),
            (row, 1) => format!("-row{row}"),
            (row, lines) => format!("-row{row}x{lines}"),
        }
    }
}

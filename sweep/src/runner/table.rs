//! Plain-text tables for `sweep status` and `sweep summary`: every column as wide as its
//! widest cell, two spaces apart.

pub fn render(header: &[String], rows: &[Vec<String>]) -> String {
    let mut widths: Vec<usize> = header.iter().map(|h| h.chars().count()).collect();
    for row in rows {
        for (width, cell) in widths.iter_mut().zip(row) {
            *width = (*width).max(cell.chars().count());
        }
    }
    let mut text = String::new();
    for row in std::iter::once(header).chain(rows.iter().map(Vec::as_slice)) {
        let line: Vec<String> = row
            .iter()
            .zip(&widths)
            .map(|(cell, &width)| format!("{cell:width$}"))
            .collect();
        text.push_str(line.join("  ").trim_end());
        text.push('\n');
    }
    text
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn columns_take_their_widest_cell() {
        let header = ["run".to_string(), "state".to_string()];
        let rows = [vec!["a-long-id".to_string(), "done".to_string()]];
        assert_eq!(
            render(&header, &rows),
            "run        state\na-long-id  done\n"
        );
    }
}

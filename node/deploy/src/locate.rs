//! Finding the line of a key in a launch file's text, so that an error found after parsing
//! (an unknown field, a bad value, broken wiring) still points at its line.

use toml_edit::{ImDocument, Item, TableLike};

/// One step of a path into a TOML document.
#[derive(Clone, Debug, PartialEq)]
pub(crate) enum Seg {
    Key(String),
    Index(usize),
}

/// 1-based line of a byte offset.
pub(crate) fn line_at(text: &str, offset: usize) -> usize {
    text[..offset.min(text.len())].matches('\n').count() + 1
}

/// The line of the deepest part of `path` found in `text` (the key itself when it is there,
/// else the table that should hold it).
pub(crate) fn line_of(text: &str, path: &[Seg]) -> Option<usize> {
    let document = ImDocument::parse(text).ok()?;
    let mut span = None;
    let mut table: &dyn TableLike = document.as_table();
    let mut item: Option<&Item> = None;
    for seg in path {
        match seg {
            Seg::Key(key) => {
                if let Some(current) = item {
                    table = current.as_table_like()?;
                }
                let Some((found_key, found)) = table.get_key_value(key) else { break };
                span = found_key.span().or_else(|| found.span()).or(span);
                item = Some(found);
            }
            Seg::Index(index) => {
                let Some(Item::ArrayOfTables(array)) = item else { break };
                let Some(entry) = array.get(*index) else { break };
                span = entry.span().or(span);
                table = entry;
                item = None;
            }
        }
    }
    span.map(|span| line_at(text, span.start))
}

#[cfg(test)]
mod tests {
    use super::*;

    const TEXT: &str = "[zenoh]\nmode = \"x\"\n\n[[axis]]\nname = \"a\"\n\n[[axis]]\nname = \"b\"\n[axis.fields]\nVELO = 1\nNOPE = 2\n";

    #[test]
    fn keys_inside_arrays_of_tables_are_found() {
        let key = |k: &str| Seg::Key(k.into());
        assert_eq!(line_of(TEXT, &[key("zenoh"), key("mode")]), Some(2));
        assert_eq!(line_of(TEXT, &[key("axis"), Seg::Index(1), key("fields"), key("NOPE")]), Some(11));
        assert_eq!(line_of(TEXT, &[key("axis"), Seg::Index(1), key("name")]), Some(8));
        // A key that is not there: the line of the table that should hold it.
        assert_eq!(line_of(TEXT, &[key("axis"), Seg::Index(0), key("host")]), Some(4));
    }
}

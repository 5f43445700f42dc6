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

/// The key whose value holds byte `offset` of `text`, as the launch file's other errors name
/// keys (`axis 'm1': readback_rate`, `zenoh.mode`), so that a value of the wrong type is named
/// by its key and not by its line alone.
pub(crate) fn key_at(text: &str, offset: usize) -> Option<String> {
    let document = ImDocument::parse(text).ok()?;
    let mut path = Vec::new();
    if !holding(document.as_table(), offset, &mut path) {
        return None;
    }
    let mut named = String::new();
    for (i, part) in path.iter().enumerate() {
        let separator = match (i, path.get(i.wrapping_sub(1))) {
            (0, _) => "",
            // An entry of an array of tables, then its keys.
            (_, Some(Part::Entry(_))) => ": ",
            _ => ".",
        };
        let (Part::Key(text) | Part::Entry(text)) = part;
        named.push_str(separator);
        named.push_str(text);
    }
    Some(named)
}

/// A step of the way to a value: a key, or an entry of an array of tables named by its name
/// (`axis 'm1'`) or its number (`axis 2`).
enum Part {
    Key(String),
    Entry(String),
}

/// Push onto `path` the steps down to the value that holds `offset`, if `table` has it.
fn holding(table: &dyn TableLike, offset: usize, path: &mut Vec<Part>) -> bool {
    for (key, item) in table.iter() {
        let found = match item {
            Item::Value(value) => {
                path.push(Part::Key(key.to_string()));
                value.span().is_some_and(|span| span.contains(&offset))
            }
            Item::Table(table) => {
                path.push(Part::Key(key.to_string()));
                holding(table, offset, path)
            }
            Item::ArrayOfTables(array) => {
                let mut found = false;
                for (index, entry) in array.iter().enumerate() {
                    let label = match entry.get("name").and_then(Item::as_str) {
                        Some(name) => format!("{key} '{name}'"),
                        None => format!("{key} {}", index + 1),
                    };
                    path.push(Part::Entry(label));
                    found = holding(entry, offset, path);
                    if found {
                        break;
                    }
                    path.pop();
                }
                // Nothing of this key is on the path unless found.
                if found {
                    return true;
                }
                continue;
            }
            Item::None => continue,
        };
        if found {
            return true;
        }
        path.pop();
    }
    false
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

    #[test]
    fn a_value_is_named_by_its_key() {
        let at = |needle: &str| TEXT.find(needle).unwrap();
        assert_eq!(key_at(TEXT, at("\"x\"")).as_deref(), Some("zenoh.mode"));
        assert_eq!(key_at(TEXT, at("2\n")).as_deref(), Some("axis 'b': fields.NOPE"));
        let unnamed = "[[axis]]\nreadback_rate = \"x\"\n";
        assert_eq!(key_at(unnamed, unnamed.find("\"x").unwrap()).as_deref(), Some("axis 1: readback_rate"));
        assert_eq!(key_at(TEXT, 0), None, "a table header is no value");
    }
}

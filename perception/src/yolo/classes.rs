//! Which model class is the goal, which an obstacle, which to ignore: from the class names a
//! model carries in its metadata (Ultralytics writes `names = "{0: 'goal', 1: 'obstacle'}"`),
//! else from a labels file (one class per line in model order, `name` or `name: kind`).
//!
//! With metadata names, a labels file is optional: a name that is itself `goal` or
//! `obstacle` needs no file; any other name (`person`, `cube`, …) must be mapped by the file
//! (`cube: goal`, `person: ignore`), matched by name. Without metadata the file is required
//! and its order is the model's class order.

use std::path::Path;

use crate::detection::ObjectKind;

use super::YoloLoadError;

/// A model class: its name and what it is for the twin (`None`: ignored).
pub type ClassMap = Vec<(String, Option<ObjectKind>)>;

/// Reads a labels file: one class per line in model order, `name` or `name: kind` with kind
/// `goal`, `obstacle` or `ignore`; a bare name must itself be `goal` or `obstacle`. Blank
/// lines and `#` comments are skipped.
///
/// # Errors
/// [`YoloLoadError::Io`] / [`YoloLoadError::Labels`].
pub fn read_labels(path: &Path) -> Result<ClassMap, YoloLoadError> {
    let text = std::fs::read_to_string(path).map_err(|source| YoloLoadError::Io {
        path: path.to_path_buf(),
        source,
    })?;
    let bad = |message: String| YoloLoadError::Labels {
        path: path.to_path_buf(),
        message,
    };
    let mut out = Vec::new();
    for (i, line) in text.lines().enumerate() {
        let line = line.split('#').next().unwrap_or("").trim();
        if line.is_empty() {
            continue;
        }
        let (name, kind) = match line.split_once(':') {
            Some((n, k)) => (n.trim(), k.trim()),
            None => (line, line),
        };
        let kind = if kind.eq_ignore_ascii_case("ignore") {
            None
        } else {
            Some(ObjectKind::parse(kind).ok_or_else(|| {
                bad(format!(
                    "line {}: class {name:?} needs a kind: write `{name}: goal`, `{name}: obstacle` or `{name}: ignore`",
                    i + 1
                ))
            })?)
        };
        out.push((name.to_string(), kind));
    }
    if out.is_empty() {
        return Err(bad("no classes".into()));
    }
    Ok(out)
}

/// Parses Ultralytics' `names` metadata, a Python dict literal `{0: 'goal', 1: "obstacle"}`
/// with consecutive indices from 0, into the names in class order.
///
/// # Errors
/// A message saying what is malformed.
pub fn parse_names_metadata(text: &str) -> Result<Vec<String>, String> {
    let body = text
        .trim()
        .strip_prefix('{')
        .and_then(|t| t.strip_suffix('}'))
        .ok_or_else(|| format!("`names` = {text:?} is not a {{index: 'name'}} dict"))?;
    let mut names: Vec<(usize, String)> = Vec::new();
    let mut rest = body.trim();
    while !rest.is_empty() {
        let (idx, after) = rest
            .split_once(':')
            .ok_or_else(|| format!("`names`: no `:` after {rest:?}"))?;
        let idx: usize = idx
            .trim()
            .parse()
            .map_err(|_| format!("`names`: class index {:?} is not a number", idx.trim()))?;
        let after = after.trim_start();
        let quote = after
            .chars()
            .next()
            .filter(|c| *c == '\'' || *c == '"')
            .ok_or_else(|| format!("`names`: class {idx} has no quoted name"))?;
        let close = after[1..]
            .find(quote)
            .ok_or_else(|| format!("`names`: class {idx}'s name is not closed"))?;
        names.push((idx, after[1..1 + close].to_string()));
        rest = after[close + 2..].trim_start();
        rest = rest.strip_prefix(',').unwrap_or(rest).trim_start();
    }
    names.sort_by_key(|(i, _)| *i);
    if names.is_empty() {
        return Err("`names` is empty".into());
    }
    for (k, (i, _)) in names.iter().enumerate() {
        if *i != k {
            return Err(format!(
                "`names`: class indices must be 0..{} without gaps or repeats",
                names.len()
            ));
        }
    }
    Ok(names.into_iter().map(|(_, n)| n).collect())
}

/// The class map of a model: from its metadata names (mapped through the labels file when
/// one is given), else from the labels file alone. See the module docs.
///
/// # Errors
/// [`YoloLoadError::Labels`] naming the class or the file, [`YoloLoadError::Io`].
pub fn resolve_classes(
    model: &Path,
    metadata_names: Option<&str>,
    labels: Option<&Path>,
) -> Result<ClassMap, YoloLoadError> {
    let from_file = labels.map(read_labels).transpose()?;
    let Some(text) = metadata_names else {
        return from_file.ok_or_else(|| YoloLoadError::Labels {
            path: model.to_path_buf(),
            message: "the model carries no class names in its metadata (`names`): give a labels file (--labels)".into(),
        });
    };
    let names = parse_names_metadata(text).map_err(|message| YoloLoadError::Labels {
        path: model.to_path_buf(),
        message,
    })?;
    names
        .into_iter()
        .map(|name| {
            if let Some(file) = &from_file {
                let entry = file.iter().find(|(n, _)| *n == name).ok_or_else(|| {
                    YoloLoadError::Labels {
                        path: labels.unwrap_or(model).to_path_buf(),
                        message: format!(
                            "the model's class {name:?} (from its metadata) is not in the labels file; add `{name}: goal|obstacle|ignore`"
                        ),
                    }
                })?;
                Ok((name, entry.1))
            } else {
                let kind = ObjectKind::parse(&name).ok_or_else(|| YoloLoadError::Labels {
                    path: model.to_path_buf(),
                    message: format!(
                        "the model's class {name:?} is neither `goal` nor `obstacle`: give a labels file mapping it (`{name}: goal|obstacle|ignore`)"
                    ),
                })?;
                Ok((name, Some(kind)))
            }
        })
        .collect()
}

#[cfg(test)]
mod tests {
    use super::*;

    fn tmp(name: &str, text: &str) -> std::path::PathBuf {
        let dir = std::env::temp_dir().join(format!("foresight-classes-{}", std::process::id()));
        std::fs::create_dir_all(&dir).unwrap();
        let p = dir.join(name);
        std::fs::write(&p, text).unwrap();
        p
    }

    #[test]
    fn labels_map_classes_and_reject_unknown_kinds() {
        let p = tmp(
            "l.txt",
            "# classes\ngoal\ncube: goal\nbox: obstacle\nhand: ignore\n",
        );
        let l = read_labels(&p).unwrap();
        assert_eq!(l.len(), 4);
        assert_eq!(l[1], ("cube".to_string(), Some(ObjectKind::Goal)));
        assert_eq!(l[3].1, None);
        let p = tmp("person.txt", "person\n");
        assert!(
            read_labels(&p)
                .unwrap_err()
                .to_string()
                .contains("needs a kind")
        );
        assert!(
            read_labels(Path::new("/nonexistent/missing.txt"))
                .unwrap_err()
                .to_string()
                .contains("cannot read")
        );
    }

    #[test]
    fn ultralytics_names_metadata_parses() {
        assert_eq!(
            parse_names_metadata("{0: 'goal', 1: 'obstacle'}").unwrap(),
            ["goal", "obstacle"]
        );
        assert_eq!(
            parse_names_metadata(r#"{1: "b, c", 0: 'a:x'}"#).unwrap(),
            ["a:x", "b, c"]
        );
        for bad in [
            "",
            "[0, 1]",
            "{}",
            "{0: goal}",
            "{0: 'a', 2: 'b'}",
            "{x: 'a'}",
            "{0: 'a",
        ] {
            assert!(parse_names_metadata(bad).is_err(), "{bad:?} accepted");
        }
    }

    #[test]
    fn classes_come_from_metadata_first_then_the_labels_file() {
        let m = Path::new("m.onnx");
        let c = resolve_classes(m, Some("{0: 'goal', 1: 'obstacle'}"), None).unwrap();
        assert_eq!(c[0].1, Some(ObjectKind::Goal));
        assert_eq!(c[1].1, Some(ObjectKind::Obstacle));
        // A name that is not a kind needs the file; the error names the class.
        let e = resolve_classes(m, Some("{0: 'cube', 1: 'person'}"), None).unwrap_err();
        assert!(e.to_string().contains("\"cube\""), "{e}");
        let f = tmp("map.txt", "person: ignore\ncube: goal\n");
        let c = resolve_classes(m, Some("{0: 'cube', 1: 'person'}"), Some(&f)).unwrap();
        assert_eq!(
            c,
            vec![
                ("cube".into(), Some(ObjectKind::Goal)),
                ("person".into(), None)
            ]
        );
        let f = tmp("short.txt", "cube: goal\n");
        let e = resolve_classes(m, Some("{0: 'cube', 1: 'person'}"), Some(&f)).unwrap_err();
        assert!(e.to_string().contains("\"person\""), "{e}");
        // No metadata: the file, in order; neither: a clear error.
        let f = tmp("plain.txt", "goal\nobstacle\n");
        assert_eq!(resolve_classes(m, None, Some(&f)).unwrap().len(), 2);
        let e = resolve_classes(m, None, None).unwrap_err();
        assert!(e.to_string().contains("--labels"), "{e}");
    }
}

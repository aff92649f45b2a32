//! A small well-formedness check for the SVG this crate writes (and for
//! tests that take an `<svg>` element out of a page): every element closed
//! in order, attribute values quoted, `<` and `&` only as markup or entities.
//! Not a validating parser: it checks the structure, not the SVG vocabulary.

/// Where and why the markup is not well-formed.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct XmlError {
    /// Byte offset into the text.
    pub offset: usize,
    pub reason: String,
}

impl std::fmt::Display for XmlError {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        write!(f, "byte {}: {}", self.offset, self.reason)
    }
}

impl std::error::Error for XmlError {}

/// Checks that `text` is one or more well-formed elements (with optional
/// comments, processing instructions and whitespace around them).
pub fn check_well_formed(text: &str) -> Result<(), XmlError> {
    let bytes = text.as_bytes();
    let fail = |offset: usize, reason: &str| {
        Err(XmlError {
            offset,
            reason: reason.to_string(),
        })
    };
    let mut open: Vec<&str> = Vec::new();
    let mut elements = 0usize;
    let mut i = 0;
    while i < bytes.len() {
        match bytes[i] {
            b'<' if text[i..].starts_with("<!--") => match text[i + 4..].find("-->") {
                Some(end) => i += 4 + end + 3,
                None => return fail(i, "comment not closed"),
            },
            b'<' if text[i..].starts_with("<?") => match text[i + 2..].find("?>") {
                Some(end) => i += 2 + end + 2,
                None => return fail(i, "processing instruction not closed"),
            },
            b'<' if text[i..].starts_with("</") => {
                let (name, after) = name_at(text, i + 2);
                let Some(expected) = open.pop() else {
                    return fail(i, &format!("</{name}> closes nothing"));
                };
                if name != expected {
                    return fail(i, &format!("</{name}> closes <{expected}>"));
                }
                let after = skip_space(bytes, after);
                if bytes.get(after) != Some(&b'>') {
                    return fail(after, "end tag not closed by >");
                }
                i = after + 1;
            }
            b'<' => {
                let (name, mut j) = name_at(text, i + 1);
                if name.is_empty() {
                    return fail(i, "< not followed by a tag name");
                }
                if open.is_empty() {
                    elements += 1;
                }
                loop {
                    j = skip_space(bytes, j);
                    match bytes.get(j) {
                        Some(b'>') => {
                            open.push(name);
                            i = j + 1;
                            break;
                        }
                        Some(b'/') if bytes.get(j + 1) == Some(&b'>') => {
                            i = j + 2;
                            break;
                        }
                        Some(_) => {
                            let (attribute, after) = name_at(text, j);
                            if attribute.is_empty() {
                                return fail(j, &format!("bad attribute in <{name}>"));
                            }
                            if bytes.get(after) != Some(&b'=') {
                                return fail(after, &format!("attribute {attribute} has no value"));
                            }
                            let quote = match bytes.get(after + 1) {
                                Some(q @ (b'"' | b'\'')) => *q,
                                _ => return fail(after + 1, "attribute value not quoted"),
                            };
                            let value_start = after + 2;
                            let Some(len) = bytes[value_start..].iter().position(|b| *b == quote)
                            else {
                                return fail(value_start, "attribute value not closed");
                            };
                            let value = &text[value_start..value_start + len];
                            if value.contains('<') {
                                return fail(value_start, "< inside an attribute value");
                            }
                            check_entities(value, value_start)?;
                            j = value_start + len + 1;
                        }
                        None => return fail(i, &format!("<{name}> not closed")),
                    }
                }
            }
            _ => {
                let end = text[i..].find('<').map_or(bytes.len(), |n| i + n);
                let content = &text[i..end];
                if open.is_empty() && !content.trim().is_empty() {
                    return fail(i, "text outside any element");
                }
                check_entities(content, i)?;
                i = end;
            }
        }
    }
    if let Some(name) = open.last() {
        return fail(bytes.len(), &format!("<{name}> never closed"));
    }
    if elements == 0 {
        return fail(0, "no element");
    }
    Ok(())
}

fn name_at(text: &str, from: usize) -> (&str, usize) {
    let len = text[from..]
        .find(|c: char| !(c.is_alphanumeric() || matches!(c, '-' | '_' | ':' | '.')))
        .unwrap_or(text.len() - from);
    (&text[from..from + len], from + len)
}

fn skip_space(bytes: &[u8], mut i: usize) -> usize {
    while bytes.get(i).is_some_and(u8::is_ascii_whitespace) {
        i += 1;
    }
    i
}

fn check_entities(text: &str, offset: usize) -> Result<(), XmlError> {
    for (at, _) in text.match_indices('&') {
        let rest = &text[at + 1..];
        let ok = rest.find(';').is_some_and(|end| {
            let entity = &rest[..end];
            matches!(entity, "amp" | "lt" | "gt" | "quot" | "apos")
                || entity
                    .strip_prefix("#x")
                    .is_some_and(|h| !h.is_empty() && h.chars().all(|c| c.is_ascii_hexdigit()))
                || entity
                    .strip_prefix('#')
                    .is_some_and(|d| !d.is_empty() && d.chars().all(|c| c.is_ascii_digit()))
        });
        if !ok {
            return Err(XmlError {
                offset: offset + at,
                reason: "& that is not an entity".into(),
            });
        }
    }
    Ok(())
}

/// `text` with `&`, `<`, `>` and quotes escaped, for element text and
/// attribute values alike.
pub fn escape(text: &str) -> String {
    let mut out = String::with_capacity(text.len());
    for c in text.chars() {
        match c {
            '&' => out.push_str("&amp;"),
            '<' => out.push_str("&lt;"),
            '>' => out.push_str("&gt;"),
            '"' => out.push_str("&quot;"),
            '\'' => out.push_str("&apos;"),
            c => out.push(c),
        }
    }
    out
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn accepts_nested_elements_entities_and_comments() {
        let ok = r#"<?xml version="1.0"?><!-- c --><svg a="1" b='x &amp; y'><g><text>1 &lt; 2 &#956;</text><path d="M0 0"/></g></svg>"#;
        assert_eq!(check_well_formed(ok), Ok(()));
    }

    #[test]
    fn rejects_what_a_browser_would_mangle() {
        let bad = [
            ("<svg><g></svg>", "closes <g>"),
            ("<svg>", "never closed"),
            ("<svg a=1></svg>", "not quoted"),
            ("<svg><text>a & b</text></svg>", "not an entity"),
            ("<svg><text>a < b</text></svg>", "tag name"),
            ("</svg>", "closes nothing"),
            ("<svg a=\"1></svg>", "not closed"),
            ("text only", "outside"),
            ("", "no element"),
        ];
        for (text, why) in bad {
            let e = check_well_formed(text).unwrap_err();
            assert!(e.reason.contains(why), "{text}: {e}");
        }
    }

    #[test]
    fn escaped_text_is_well_formed() {
        let text = format!("<t a=\"{0}\">{0}</t>", escape("<a & 'b' \"c\">"));
        assert_eq!(check_well_formed(&text), Ok(()));
    }
}

//! The text before the parser: comments taken out wherever they stand in a
//! block, and what the reader does not support named with its line.
//!
//! The parser ends a command's words at a comment, so a comment in the
//! middle of a block (`G2 (270 360) I0 J7 X9`) would cut the words after
//! it from their command. Each `( … )` comment becomes a space and each
//! `;` comment is dropped, so the parser sees the block's words together;
//! lines stay where they were.

use super::{GcodeError, Unsupported};

/// The program with its comments out, or the first construct the reader
/// does not support.
pub(super) fn clean(text: &str) -> Result<String, GcodeError> {
    let mut out = String::with_capacity(text.len());
    for (i, raw) in text.split('\n').enumerate() {
        let line = i + 1;
        if i > 0 {
            out.push('\n');
        }
        if let Some(code) = message_code(raw) {
            // Its text is not G-code (it may hold `;`, `(` or `[`): the
            // code alone is read, and said once to be skipped.
            out.push_str(code);
            continue;
        }
        let mut kept = String::with_capacity(raw.len());
        let mut in_comment = false;
        for c in raw.chars() {
            if in_comment {
                if c == ')' {
                    in_comment = false;
                    kept.push(' ');
                }
                continue;
            }
            match c {
                '(' => in_comment = true,
                ';' => break,
                c => kept.push(c),
            }
        }
        if in_comment {
            return Err(GcodeError::Block {
                line,
                message: "a comment \"(\" is not closed: close it with \")\" on the same line"
                    .into(),
            });
        }
        if is_o_word(&kept) {
            return Err(GcodeError::Unsupported {
                line,
                feature: Unsupported::OWord,
                text: quote(kept.trim()),
            });
        }
        for (mark, feature) in [
            ('[', Unsupported::Expression),
            ('#', Unsupported::Parameter),
        ] {
            if let Some(at) = kept.find(mark) {
                return Err(GcodeError::Unsupported {
                    line,
                    feature,
                    text: quote(word_at(&kept, at)),
                });
            }
        }
        out.push_str(&bare_home_axes(&kept));
    }
    Ok(out)
}

/// The codes whose words are free text (a display message, a file name),
/// when `raw` is one: `M117 Printing...`.
fn message_code(raw: &str) -> Option<&'static str> {
    let t = raw.trim_start();
    let head: String = t
        .chars()
        .take_while(|c| c.is_ascii_alphanumeric())
        .collect::<String>()
        .to_ascii_uppercase();
    ["M117", "M118", "M23", "M28", "M32"]
        .into_iter()
        .find(|code| head == *code)
}

/// `G28 X Y` (Marlin's bare axis letters) as `G28 X0 Y0`, which the parser
/// reads; any other line as it is.
fn bare_home_axes(line: &str) -> std::borrow::Cow<'_, str> {
    let mut words = line.split_whitespace();
    let is_g28 = words.next().is_some_and(|w| w.eq_ignore_ascii_case("G28"));
    if !is_g28 || !words.any(|w| w.len() == 1) {
        return line.into();
    }
    line.split_whitespace()
        .map(|w| {
            if w.len() == 1 && "XYZxyz".contains(w) {
                format!("{w}0")
            } else {
                w.to_string()
            }
        })
        .collect::<Vec<_>>()
        .join(" ")
        .into()
}

/// The word around the construct at byte `at` of `line`: from the letter
/// before it (if its value is the construct) to the bracket that closes it
/// (`Y[0.01*2]`), or to the next space.
fn word_at(line: &str, at: usize) -> &str {
    let before = line[..at].trim_end();
    let start = match before.char_indices().last() {
        Some((k, c)) if c.is_ascii_alphabetic() => k,
        _ => at,
    };
    let mut depth = 0usize;
    let mut end = line.len();
    for (k, c) in line[at..].char_indices() {
        match c {
            '[' => depth += 1,
            ']' => {
                depth = depth.saturating_sub(1);
                if depth == 0 {
                    end = at + k + 1;
                    break;
                }
            }
            c if c.is_whitespace() && depth == 0 => {
                end = at + k;
                break;
            }
            _ => {}
        }
    }
    &line[start..end]
}

/// At most 40 characters of `text`.
fn quote(text: &str) -> String {
    if text.chars().count() > 40 {
        text.chars().take(40).chain(['…']).collect()
    } else {
        text.to_string()
    }
}

/// Whether a line (comments out) is an O-word that controls the program
/// (`O100 sub`, `o<probe> call`, `O101 while`). A bare program number
/// (`O1234`, Fanuc's program name line) is not: it is read as before and
/// means nothing to the machine.
fn is_o_word(line: &str) -> bool {
    let mut s = line.trim_start();
    s = s.strip_prefix('/').unwrap_or(s).trim_start();
    // A block number first: N10 O100 sub.
    if let Some(rest) = s.strip_prefix(['N', 'n']) {
        s = rest
            .trim_start_matches(|c: char| c.is_ascii_digit() || c == '.')
            .trim_start();
    }
    let Some(rest) = s.strip_prefix(['O', 'o']) else {
        return false;
    };
    let rest = rest.trim_start();
    if rest.starts_with('<') {
        return true;
    }
    let after = rest.trim_start_matches(|c: char| c.is_ascii_digit());
    after.len() < rest.len() && !after.trim().is_empty()
}

/// The lines (from 1) of a slicer's layer-change comments: PrusaSlicer's,
/// SuperSlicer's and OrcaSlicer's `;LAYER_CHANGE`, Cura's `;LAYER:N`.
pub(super) fn layer_lines(text: &str) -> Vec<usize> {
    text.split('\n')
        .enumerate()
        .filter(|(_, raw)| {
            let t = raw.trim_start();
            let Some(c) = t.strip_prefix(';') else {
                return false;
            };
            let c = c.trim_start();
            c.starts_with("LAYER_CHANGE") || c.starts_with("LAYER:")
        })
        .map(|(i, _)| i + 1)
        .collect()
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn comments_go_and_lines_stay() {
        let c =
            clean("G17 G2 (270 360) I0 J7 X9 Y6 Z13 F100000\n(only)\nG0 X1 ; note (x)\n").unwrap();
        assert_eq!(
            c.lines().collect::<Vec<_>>(),
            ["G17 G2   I0 J7 X9 Y6 Z13 F100000", " ", "G0 X1 ", ""][..3]
        );
        assert_eq!(c.lines().count(), 3);
    }

    #[test]
    fn unsupported_words_are_quoted() {
        assert_eq!(word_at("G1 Y[0.01*2] F100", 4), "Y[0.01*2]");
        assert_eq!(word_at("G1 X [1 + [2*3]] F1", 5), "X [1 + [2*3]]");
        assert_eq!(word_at("G0 X#1", 4), "X#1");
        assert_eq!(word_at("#1 = 5", 0), "#1");
    }

    #[test]
    fn o_words_are_told_from_program_numbers() {
        for control in [
            "O100 sub",
            "o100 endsub",
            "O101 while",
            "N20 O102 if",
            "o<probe> call",
            "O100 call",
        ] {
            assert!(is_o_word(control), "{control}");
        }
        for plain in ["O1234", "O0001 ", "G0 X1", "N10 G1 X2", "", "%"] {
            assert!(!is_o_word(plain), "{plain}");
        }
    }
}

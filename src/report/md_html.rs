//! The Markdown the report writes, as HTML (`report --out x.html` is a page, not
//! Markdown in a `<pre>`). Only the subset [`super::Session::markdown`] produces: headings,
//! pipe tables, bullet lists, fenced code blocks, paragraphs, and inline `**bold**` and
//! `` `code` `` (shown as code, never as raw backticks).
use std::fmt::Write as _;

fn esc(s: &str) -> String {
    s.replace('&', "&amp;")
        .replace('<', "&lt;")
        .replace('>', "&gt;")
        .replace('"', "&quot;")
}

/// Inline markup of one line: `code` spans first (their content is literal), then **bold**.
pub fn inline(s: &str) -> String {
    let mut out = String::new();
    let parts = s.split('`').count();
    let even = s.matches('`').count().is_multiple_of(2);
    for (i, part) in s.split('`').enumerate() {
        // An unpaired backtick leaves an odd count: the last part is text, with its backtick.
        let paired = even || i + 1 < parts;
        if i % 2 == 1 && paired {
            let _ = write!(out, "<code>{}</code>", esc(part));
        } else {
            if i % 2 == 1 {
                out.push('`');
            }
            let mut bold = false;
            for (j, b) in esc(part).split("**").enumerate() {
                if j > 0 {
                    out.push_str(if bold { "</b>" } else { "<b>" });
                    bold = !bold;
                }
                out.push_str(b);
            }
            if bold {
                out.push_str("</b>");
            }
        }
    }
    out
}

fn cells(line: &str) -> Vec<&str> {
    let t = line.trim().trim_start_matches('|').trim_end_matches('|');
    t.split('|').map(str::trim).collect()
}

fn is_rule(line: &str) -> bool {
    let c = cells(line);
    !c.is_empty()
        && c.iter()
            .all(|x| !x.is_empty() && x.chars().all(|ch| matches!(ch, '-' | ':' | ' ')))
}

/// The Markdown `md` as an HTML fragment.
pub fn to_html(md: &str) -> String {
    let lines: Vec<&str> = md.lines().collect();
    let mut h = String::new();
    let mut i = 0;
    let mut para: Vec<String> = Vec::new();
    let flush = |h: &mut String, para: &mut Vec<String>| {
        if !para.is_empty() {
            let _ = writeln!(h, "<p>{}</p>", para.join(" "));
            para.clear();
        }
    };
    while i < lines.len() {
        let l = lines[i];
        let t = l.trim_start();
        if t.starts_with("```") {
            flush(&mut h, &mut para);
            let mut code = String::new();
            i += 1;
            while i < lines.len() && !lines[i].trim_start().starts_with("```") {
                code.push_str(lines[i]);
                code.push('\n');
                i += 1;
            }
            let _ = writeln!(h, "<pre>{}</pre>", esc(&code));
        } else if let Some(level) =
            (1..=6).find(|n| t.starts_with(&"#".repeat(*n)) && t[*n..].starts_with(' '))
        {
            flush(&mut h, &mut para);
            let _ = writeln!(h, "<h{level}>{}</h{level}>", inline(t[level..].trim()));
        } else if t.starts_with('|') && i + 1 < lines.len() && is_rule(lines[i + 1]) {
            flush(&mut h, &mut para);
            h.push_str("<table>\n<tr>");
            for c in cells(t) {
                let _ = write!(h, "<th>{}</th>", inline(c));
            }
            h.push_str("</tr>\n");
            i += 2;
            while i < lines.len() && lines[i].trim_start().starts_with('|') {
                h.push_str("<tr>");
                for c in cells(lines[i]) {
                    let _ = write!(h, "<td>{}</td>", inline(c));
                }
                h.push_str("</tr>\n");
                i += 1;
            }
            h.push_str("</table>\n");
            continue;
        } else if let Some(item) = t.strip_prefix("- ") {
            flush(&mut h, &mut para);
            h.push_str("<ul>\n");
            let _ = writeln!(h, "<li>{}</li>", inline(item));
            i += 1;
            while i < lines.len() {
                match lines[i].trim_start().strip_prefix("- ") {
                    Some(x) => {
                        let _ = writeln!(h, "<li>{}</li>", inline(x));
                        i += 1;
                    }
                    None => break,
                }
            }
            h.push_str("</ul>\n");
            continue;
        } else if t.is_empty() {
            flush(&mut h, &mut para);
        } else {
            para.push(inline(t));
        }
        i += 1;
    }
    flush(&mut h, &mut para);
    h
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn markdown_subset_becomes_html() {
        let md = "# Title\n\n**PASS** on `run-train/x.jsonl` a<b\n\n| a | b (mm) |\n|---|---:|\n| 1 | `q` |\n\n- one\n- two **bold**\n\n```text\nraw `x` <y>\n```\n";
        let h = to_html(md);
        assert!(h.contains("<h1>Title</h1>"), "{h}");
        assert!(
            h.contains("<p><b>PASS</b> on <code>run-train/x.jsonl</code> a&lt;b</p>"),
            "{h}"
        );
        assert!(h.contains("<tr><th>a</th><th>b (mm)</th></tr>"), "{h}");
        assert!(
            h.contains("<tr><td>1</td><td><code>q</code></td></tr>"),
            "{h}"
        );
        assert!(h.contains("<li>two <b>bold</b></li>"), "{h}");
        assert!(h.contains("<pre>raw `x` &lt;y&gt;\n</pre>"), "{h}");
        // No raw Markdown markers outside code blocks.
        let outside: String = h.split("<pre>").next().unwrap().into();
        assert!(!outside.contains('`') && !outside.contains("**") && !outside.contains("|---"));
        // An unpaired backtick stays text.
        assert_eq!(inline("a ` b"), "a ` b");
    }
}

//! The report's Markdown as one self-contained HTML page: the subset the
//! report writes (headings, paragraphs, lists, pipe tables, `code`,
//! **bold**, links, and image lines), with every SVG figure inlined so the
//! file stands alone.

use std::path::Path;

fn escape(s: &str) -> String {
    s.replace('&', "&amp;").replace('<', "&lt;").replace('>', "&gt;")
}

/// Inline Markdown: `code`, **bold**, [text](url).
fn inline(s: &str) -> String {
    let mut out = String::new();
    let mut rest = s;
    while !rest.is_empty() {
        if let Some(r) = rest.strip_prefix('`') {
            if let Some(end) = r.find('`') {
                out.push_str(&format!("<code>{}</code>", escape(&r[..end])));
                rest = &r[end + 1..];
                continue;
            }
        }
        if let Some(r) = rest.strip_prefix("**") {
            if let Some(end) = r.find("**") {
                out.push_str(&format!("<b>{}</b>", inline(&r[..end])));
                rest = &r[end + 2..];
                continue;
            }
        }
        if let Some(r) = rest.strip_prefix('[') {
            if let Some(mid) = r.find("](") {
                if let Some(end) = r[mid + 2..].find(')') {
                    let text = &r[..mid];
                    let url = &r[mid + 2..mid + 2 + end];
                    out.push_str(&format!("<a href=\"{}\">{}</a>", escape(url), inline(text)));
                    rest = &r[mid + 3 + end..];
                    continue;
                }
            }
        }
        let c = rest.chars().next().unwrap_or(' ');
        out.push_str(&escape(&c.to_string()));
        rest = &rest[c.len_utf8()..];
    }
    out
}

fn cells(line: &str) -> Vec<&str> {
    line.trim().trim_matches('|').split('|').map(str::trim).collect()
}

/// Converts the report's Markdown to a standalone page; image lines whose
/// target is an `.svg` under `dir` are inlined.
pub fn markdown_to_html(md: &str, title: &str, dir: &Path) -> String {
    let mut body = String::new();
    let lines: Vec<&str> = md.lines().collect();
    let mut i = 0;
    let mut para: Vec<String> = Vec::new();
    let flush = |para: &mut Vec<String>, body: &mut String| {
        if !para.is_empty() {
            body.push_str(&format!("<p>{}</p>\n", para.join(" ")));
            para.clear();
        }
    };
    while i < lines.len() {
        let l = lines[i];
        let t = l.trim();
        if t.is_empty() {
            flush(&mut para, &mut body);
        } else if let Some(h) = t.strip_prefix('#') {
            flush(&mut para, &mut body);
            let level = 1 + h.chars().take_while(|c| *c == '#').count();
            let text = h.trim_start_matches('#').trim();
            body.push_str(&format!("<h{level}>{}</h{level}>\n", inline(text)));
        } else if t.starts_with('|') {
            flush(&mut para, &mut body);
            body.push_str("<table>\n");
            let head = cells(t);
            body.push_str("<tr>");
            for c in head {
                body.push_str(&format!("<th>{}</th>", inline(c)));
            }
            body.push_str("</tr>\n");
            i += 1;
            // The header's separator row.
            if lines
                .get(i)
                .is_some_and(|l| l.trim().starts_with("|-") || l.contains("---"))
            {
                i += 1;
            }
            while i < lines.len() && lines[i].trim().starts_with('|') {
                body.push_str("<tr>");
                for c in cells(lines[i]) {
                    body.push_str(&format!("<td>{}</td>", inline(c)));
                }
                body.push_str("</tr>\n");
                i += 1;
            }
            body.push_str("</table>\n");
            continue;
        } else if let Some(item) = t.strip_prefix("- ") {
            flush(&mut para, &mut body);
            body.push_str("<ul>\n");
            let mut item = item.to_string();
            i += 1;
            loop {
                // Continuation lines of an item are indented.
                while i < lines.len() && lines[i].starts_with("  ") && !lines[i].trim().starts_with("- ") {
                    item.push(' ');
                    item.push_str(lines[i].trim());
                    i += 1;
                }
                body.push_str(&format!("<li>{}</li>\n", inline(&item)));
                match lines.get(i).and_then(|l| l.trim().strip_prefix("- ")) {
                    Some(next) => {
                        item = next.to_string();
                        i += 1;
                    }
                    None => break,
                }
            }
            body.push_str("</ul>\n");
            continue;
        } else if let Some(img) = t.strip_prefix("![") {
            flush(&mut para, &mut body);
            let (alt, target) = match img.split_once("](") {
                Some((a, r)) => (a, r.trim_end_matches(')')),
                None => (img, ""),
            };
            let svg = target
                .ends_with(".svg")
                .then(|| std::fs::read_to_string(dir.join(target)).ok())
                .flatten();
            match svg {
                Some(svg) => {
                    let svg = svg.trim_start_matches(|c| c != '<');
                    let svg = svg
                        .strip_prefix("<?xml")
                        .map_or(svg, |r| r.split_once("?>").map_or(r, |x| x.1));
                    body.push_str(&format!(
                        "<figure>{}<figcaption>{}</figcaption></figure>\n",
                        svg.trim(),
                        inline(alt)
                    ));
                }
                None => body.push_str(&format!(
                    "<figure><img alt=\"{}\" src=\"{}\"><figcaption>{}</figcaption></figure>\n",
                    escape(alt),
                    escape(target),
                    inline(alt)
                )),
            }
        } else {
            para.push(inline(t));
        }
        i += 1;
    }
    flush(&mut para, &mut body);
    format!(
        "<!DOCTYPE html>\n<html lang=\"en\"><head><meta charset=\"utf-8\"><title>{}</title>\n<style>\n\
         body {{ font-family: 'DejaVu Sans', Helvetica, Arial, sans-serif; max-width: 1100px; margin: 2em auto; \
         padding: 0 1em; color: #222; line-height: 1.45; }}\n\
         table {{ border-collapse: collapse; margin: 0.8em 0; font-size: 0.9em; }}\n\
         th, td {{ border: 1px solid #ccc; padding: 0.25em 0.6em; text-align: left; }}\n\
         th {{ background: #f0f0f0; }}\n\
         code {{ background: #f4f4f4; padding: 0 0.2em; }}\n\
         figure {{ margin: 1.5em 0; }} figure svg {{ max-width: 100%; height: auto; }}\n\
         figcaption {{ font-size: 0.9em; color: #555; }}\n\
         </style></head><body>\n{}</body></html>\n",
        escape(title),
        body
    )
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn converts_the_report_subset() {
        let dir = std::env::temp_dir().join(format!("sil-html-{}", std::process::id()));
        std::fs::create_dir_all(&dir).unwrap();
        std::fs::write(
            dir.join("f.svg"),
            "<?xml version=\"1.0\"?>\n<svg><text>hello</text></svg>",
        )
        .unwrap();
        let md = "# Title\n\nSome `code` and **bold** and [a link](x.png).\n\n| a | b |\n|---|---|\n| 1 | <2> |\n\n\
                  - one\n  more\n- two\n\n![A figure](f.svg)\n";
        let h = markdown_to_html(md, "T", &dir);
        assert!(h.contains("<h1>Title</h1>"));
        assert!(
            h.contains("<code>code</code>") && h.contains("<b>bold</b>") && h.contains("<a href=\"x.png\">a link</a>")
        );
        assert!(h.contains("<th>a</th>") && h.contains("<td>&lt;2&gt;</td>"));
        assert!(h.contains("<li>one more</li>") && h.contains("<li>two</li>"));
        assert!(h.contains("<svg><text>hello</text></svg>") && !h.contains("<?xml"));
        assert!(h.contains("<figcaption>A figure</figcaption>"));
        std::fs::remove_dir_all(&dir).unwrap();
    }
}

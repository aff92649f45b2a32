//! The report as a list of blocks, written once and rendered twice: as
//! Markdown (figures as files beside it) and as one self-contained HTML page
//! (figures inlined as SVG, styles inline, nothing fetched).

use flexloop_plot::xml::escape;

pub enum Block {
    Heading(String),
    Subheading(String),
    /// A heading within a subsection.
    Minor(String),
    Paragraph(String),
    Table(Table),
    Figure(FigureBlock),
}

pub struct Table {
    pub header: Vec<String>,
    pub rows: Vec<Vec<String>>,
    /// Columns from this one on hold numbers (right-aligned).
    pub numeric_from: usize,
}

pub struct FigureBlock {
    pub title: String,
    /// File name of the SVG beside the Markdown.
    pub file: String,
    pub svg: String,
    pub caption: String,
}

pub struct Document {
    pub title: String,
    pub blocks: Vec<Block>,
}

impl Document {
    pub fn new(title: String) -> Self {
        Self {
            title,
            blocks: Vec::new(),
        }
    }

    pub fn push(&mut self, block: Block) {
        self.blocks.push(block);
    }

    pub fn figures(&self) -> impl Iterator<Item = &FigureBlock> {
        self.blocks.iter().filter_map(|b| match b {
            Block::Figure(f) => Some(f),
            _ => None,
        })
    }

    pub fn markdown(&self) -> String {
        let mut out = format!("# {}\n", self.title);
        for block in &self.blocks {
            out.push('\n');
            match block {
                Block::Heading(text) => out.push_str(&format!("## {text}\n")),
                Block::Subheading(text) => out.push_str(&format!("### {text}\n")),
                Block::Minor(text) => out.push_str(&format!("#### {text}\n")),
                Block::Paragraph(text) => out.push_str(&format!("{text}\n")),
                Block::Table(t) => {
                    let cells = |row: &[String]| {
                        let escaped: Vec<String> =
                            row.iter().map(|c| c.replace('|', "\\|")).collect();
                        format!("| {} |\n", escaped.join(" | "))
                    };
                    out.push_str(&cells(&t.header));
                    let rule: Vec<&str> = (0..t.header.len())
                        .map(|i| if i >= t.numeric_from { "---:" } else { "---" })
                        .collect();
                    out.push_str(&format!("|{}|\n", rule.join("|")));
                    for row in &t.rows {
                        out.push_str(&cells(row));
                    }
                }
                Block::Figure(f) => {
                    out.push_str(&format!(
                        "![{}]({})\n\n*{}*\n",
                        f.title.replace(['[', ']'], ""),
                        f.file,
                        f.caption
                    ));
                }
            }
        }
        out
    }

    pub fn html(&self) -> String {
        let mut out =
            String::with_capacity(64 * 1024 + self.figures().map(|f| f.svg.len()).sum::<usize>());
        out.push_str("<!DOCTYPE html>\n<html lang=\"en\">\n<head>\n<meta charset=\"utf-8\">\n");
        out.push_str(&format!("<title>{}</title>\n", escape(&self.title)));
        out.push_str(STYLE);
        out.push_str("</head>\n<body>\n");
        out.push_str(&format!("<h1>{}</h1>\n", escape(&self.title)));
        for block in &self.blocks {
            match block {
                Block::Heading(text) => out.push_str(&format!("<h2>{}</h2>\n", escape(text))),
                Block::Subheading(text) => out.push_str(&format!("<h3>{}</h3>\n", escape(text))),
                Block::Minor(text) => out.push_str(&format!("<h4>{}</h4>\n", escape(text))),
                Block::Paragraph(text) => out.push_str(&format!("<p>{}</p>\n", inline_code(text))),
                Block::Table(t) => {
                    out.push_str("<table>\n<thead><tr>");
                    for (i, h) in t.header.iter().enumerate() {
                        out.push_str(&format!("<th{}>{}</th>", align(i, t), escape(h)));
                    }
                    out.push_str("</tr></thead>\n<tbody>\n");
                    for row in &t.rows {
                        out.push_str("<tr>");
                        for (i, c) in row.iter().enumerate() {
                            out.push_str(&format!("<td{}>{}</td>", align(i, t), inline_code(c)));
                        }
                        out.push_str("</tr>\n");
                    }
                    out.push_str("</tbody>\n</table>\n");
                }
                Block::Figure(f) => {
                    out.push_str("<figure>\n");
                    out.push_str(&f.svg);
                    out.push_str(&format!(
                        "\n<figcaption>{}</figcaption>\n</figure>\n",
                        inline_code(&f.caption)
                    ));
                }
            }
        }
        out.push_str("</body>\n</html>\n");
        out
    }
}

fn align(column: usize, t: &Table) -> &'static str {
    if column >= t.numeric_from {
        " class=\"num\""
    } else {
        ""
    }
}

/// Escaped text with Markdown's `code` spans as <code>.
fn inline_code(text: &str) -> String {
    let mut out = String::new();
    for (i, part) in text.split('`').enumerate() {
        if i % 2 == 1 {
            out.push_str(&format!("<code>{}</code>", escape(part)));
        } else {
            out.push_str(&escape(part));
        }
    }
    out
}

const STYLE: &str = "<style>
body { font-family: sans-serif; max-width: 1000px; margin: 1.5em auto; padding: 0 1em; color: #222; line-height: 1.4; }
h1 { font-size: 1.6em; } h2 { margin-top: 1.8em; border-bottom: 1px solid #ccc; } h3 { margin-top: 1.3em; } h4 { margin: 1em 0 0.4em; }
table { border-collapse: collapse; margin: 0.8em 0; font-size: 0.9em; }
th, td { border: 1px solid #ccc; padding: 0.25em 0.6em; }
th { background: #f2f2f2; } td.num, th.num { text-align: right; font-variant-numeric: tabular-nums; }
figure { margin: 1.2em 0; } figure svg { max-width: 100%; height: auto; display: block; }
figcaption { font-size: 0.9em; color: #444; margin-top: 0.3em; }
code { background: #f4f4f4; padding: 0 0.2em; }
</style>
";

#[cfg(test)]
mod tests {
    use super::*;

    fn document() -> Document {
        let mut d = Document::new("Run <1>".into());
        d.push(Block::Heading("Timing".into()));
        d.push(Block::Paragraph("see `latency.hlog` & more".into()));
        d.push(Block::Table(Table {
            header: vec!["name".into(), "p50".into()],
            rows: vec![vec!["a|b".into(), "1.0".into()]],
            numeric_from: 1,
        }));
        d.push(Block::Figure(FigureBlock {
            title: "A [figure]".into(),
            file: "f.svg".into(),
            svg: "<svg xmlns=\"http://www.w3.org/2000/svg\"></svg>".into(),
            caption: "what it shows".into(),
        }));
        d
    }

    #[test]
    fn markdown_has_tables_and_figure_links() {
        let md = document().markdown();
        assert!(md.starts_with("# Run <1>\n"));
        assert!(
            md.contains("| name | p50 |\n|---|---:|\n| a\\|b | 1.0 |\n"),
            "{md}"
        );
        assert!(md.contains("![A figure](f.svg)"));
    }

    #[test]
    fn html_inlines_figures_and_escapes_text() {
        let html = document().html();
        assert!(html.contains("<title>Run &lt;1&gt;</title>"));
        assert!(html.contains("see <code>latency.hlog</code> &amp; more"));
        assert!(html.contains("<td class=\"num\">1.0</td>"));
        assert_eq!(html.matches("<svg").count(), 1);
        assert!(!html.contains("src="));
    }
}

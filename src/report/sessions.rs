//! `robocal report --dir DIR --out x.html` on a folder that holds sessions: one
//! report per session — the session's own page ([`super::html::render_session`]), never the
//! artifacts of several sessions mixed into one page. A folder with several sessions (the
//! dry run's `session/` and `camera/`) gets one page per session beside `x.html`
//! (`x-session.html`, `x-camera.html`) and `x.html` lists them, verdict first.
use std::fmt::Write as _;
use std::path::{Path, PathBuf};

use crate::session::svg::esc;
use crate::session::SessionFile;

/// The session directories at `dir` (itself, else its immediate subdirectories that hold a
/// `session.json`), sorted.
pub fn sessions_in(dir: &Path) -> Vec<PathBuf> {
    if dir.join("session.json").is_file() {
        return vec![dir.to_path_buf()];
    }
    let mut v: Vec<PathBuf> = std::fs::read_dir(dir)
        .map(|rd| {
            rd.flatten()
                .map(|e| e.path())
                .filter(|p| p.join("session.json").is_file())
                .collect()
        })
        .unwrap_or_default();
    v.sort();
    v
}

/// One rendered page: where it goes and its HTML.
pub struct Page {
    pub path: PathBuf,
    pub html: String,
}

/// The pages for `sessions` with `out` the requested `x.html`: the session's page at `out`
/// for one session; for several, a page per session (`x-<folder>.html`) and an index at `out`.
pub fn pages(sessions: &[PathBuf], out: &Path) -> anyhow::Result<Vec<Page>> {
    let mut pages = Vec::new();
    let mut rows = Vec::new();
    for d in sessions {
        let s = SessionFile::load(&d.join("session.json"))?;
        let html = super::html::render_session(d, &s)?;
        if sessions.len() == 1 {
            pages.push(Page {
                path: out.to_path_buf(),
                html,
            });
            return Ok(pages);
        }
        let name = d
            .file_name()
            .map_or("session".into(), |n| n.to_string_lossy().into_owned());
        let stem = out
            .file_stem()
            .map_or("report".into(), |n| n.to_string_lossy().into_owned());
        let path = out.with_file_name(format!("{stem}-{name}.html"));
        let href = path
            .file_name()
            .map(|n| n.to_string_lossy().into_owned())
            .unwrap_or_default();
        rows.push((name, href, s.verdict_line.clone(), d.display().to_string()));
        pages.push(Page { path, html });
    }
    let mut h = String::from(
        "<!DOCTYPE html>\n<html lang=\"en\"><head><meta charset=\"utf-8\"><title>robocal \
         sessions</title><style>body{font-family:sans-serif;max-width:1000px;margin:1em auto;\
         padding:0 1em}td,th{border:1px solid #ccc;padding:3px 8px;text-align:left}\
         table{border-collapse:collapse}</style></head><body>\n<h1>Sessions</h1>\n\
         <p>One report per session:</p>\n<table><tr><th>session</th><th>verdict</th>\
         <th>folder</th></tr>\n",
    );
    for (name, href, verdict, folder) in &rows {
        let _ = writeln!(
            h,
            "<tr><td><a href=\"{}\">{}</a></td><td>{}</td><td>{}</td></tr>",
            esc(href),
            esc(name),
            esc(verdict),
            esc(folder)
        );
    }
    h.push_str("</table>\n</body></html>\n");
    pages.push(Page {
        path: out.to_path_buf(),
        html: h,
    });
    Ok(pages)
}

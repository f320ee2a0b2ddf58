//! A configuration as a picture: PEIS as groups, functionalities as boxes, channels as arrows
//! (dashed between PEIS), failed components marked. Laid out and written as SVG by Ecology itself,
//! so neither the web view nor `ecology configure --svg` needs anything installed.
//!
//! Layout: each PEIS is a horizontal band; within it a functionality sits in the column of its
//! depth in the data flow (producers left, consumers right), so arrows run left to right.

use std::collections::BTreeMap;
use std::fmt::Write;

/// How a node is drawn.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Mark {
    /// Part of the configuration.
    Normal,
    /// Part of the configuration, switched on for it.
    SwitchedOn,
    /// A component that failed (not part of the configuration any more).
    Failed,
}

/// One functionality instance on one component.
#[derive(Clone, Debug, PartialEq, Eq)]
pub struct Node {
    /// The PEIS it runs on.
    pub peis: String,
    /// The component that runs it.
    pub component: String,
    /// What it runs, such as `(laser astrid l1)`.
    pub label: String,
    /// A second line, such as `cost 20` or a failure's cause.
    pub detail: String,
    /// How it is drawn.
    pub mark: Mark,
}

/// A channel from one node's output to another's input.
#[derive(Clone, Debug, PartialEq, Eq)]
pub struct Edge {
    /// Index of the producer in [`Drawing::nodes`].
    pub from: usize,
    /// Index of the consumer.
    pub to: usize,
    /// The information it carries, such as `(image hsm)`.
    pub info: String,
}

/// A configuration to draw.
#[derive(Clone, Debug, Default, PartialEq, Eq)]
pub struct Drawing {
    /// The caption, such as `(navigate astrid bedroom): cost 80`.
    pub title: String,
    /// Functionality instances (and failed components).
    pub nodes: Vec<Node>,
    /// Channels.
    pub edges: Vec<Edge>,
}

const NODE_W: f64 = 215.0;
const NODE_H: f64 = 46.0;
const COL_GAP: f64 = 110.0;
const ROW_GAP: f64 = 14.0;
const BAND_PAD: f64 = 14.0;
const LABEL_W: f64 = 90.0;
const TOP: f64 = 40.0;
const MAX_LABEL: usize = 34;

impl Drawing {
    /// The index of the node for `peis:component`, if any.
    pub fn node(&self, peis: &str, component: &str) -> Option<usize> {
        self.nodes
            .iter()
            .position(|n| n.peis == peis && n.component == component)
    }

    /// Depth of each node in the data flow: 0 for nodes no channel feeds, else one more than
    /// the deepest producer (cycles are cut at the number of nodes).
    fn columns(&self) -> Vec<usize> {
        let mut column = vec![0; self.nodes.len()];
        for _ in 0..self.nodes.len() {
            let mut changed = false;
            for e in &self.edges {
                if e.from < column.len() && e.to < column.len() && column[e.to] <= column[e.from] {
                    column[e.to] = column[e.from] + 1;
                    changed = true;
                }
            }
            if !changed {
                break;
            }
        }
        column
    }

    /// The drawing as a standalone SVG document.
    pub fn svg(&self) -> String {
        let columns = self.columns();
        // Bands in order of first appearance; within a band, rows per column.
        let mut bands: Vec<&str> = Vec::new();
        for n in &self.nodes {
            if !bands.contains(&n.peis.as_str()) {
                bands.push(&n.peis);
            }
        }
        let mut slot: BTreeMap<(usize, usize), usize> = BTreeMap::new();
        let mut position = vec![(0usize, 0usize, 0usize); self.nodes.len()];
        for (i, n) in self.nodes.iter().enumerate() {
            let band = bands.iter().position(|b| *b == n.peis).unwrap_or(0);
            let row = slot.entry((band, columns[i])).or_insert(0);
            position[i] = (band, columns[i], *row);
            *row += 1;
        }
        let rows_in = |band: usize| {
            slot.iter()
                .filter(|((b, _), _)| *b == band)
                .map(|(_, rows)| *rows)
                .max()
                .unwrap_or(1)
        };
        let mut band_top = Vec::with_capacity(bands.len());
        let mut y = TOP;
        for band in 0..bands.len() {
            band_top.push(y);
            let rows = rows_in(band) as f64;
            y += rows * NODE_H + (rows - 1.0) * ROW_GAP + 2.0 * BAND_PAD + ROW_GAP;
        }
        let height = y.max(TOP + 40.0) + 10.0;
        let ncols = columns.iter().copied().max().map_or(1, |c| c + 1) as f64;
        let width = LABEL_W + ncols * NODE_W + (ncols - 1.0) * COL_GAP + 2.0 * BAND_PAD + 20.0;
        let xy = |i: usize| {
            let (band, col, row) = position[i];
            let x = LABEL_W + BAND_PAD + col as f64 * (NODE_W + COL_GAP);
            let y = band_top[band] + BAND_PAD + row as f64 * (NODE_H + ROW_GAP);
            (x, y)
        };

        let mut out = String::new();
        let _ = write!(
            out,
            r##"<svg xmlns="http://www.w3.org/2000/svg" width="{width:.0}" height="{height:.0}" viewBox="0 0 {width:.0} {height:.0}" font-family="sans-serif" font-size="12">
<defs><marker id="arrow" viewBox="0 0 10 10" refX="10" refY="5" markerWidth="7" markerHeight="7" orient="auto-start-reverse"><path d="M 0 0 L 10 5 L 0 10 z" fill="#444"/></marker></defs>
<rect width="100%" height="100%" fill="#ffffff"/>
<text x="10" y="24" font-size="15" font-weight="bold">{}</text>
"##,
            escape(&self.title)
        );
        for (band, peis) in bands.iter().enumerate() {
            let rows = rows_in(band) as f64;
            let h = rows * NODE_H + (rows - 1.0) * ROW_GAP + 2.0 * BAND_PAD;
            let _ = writeln!(
                out,
                r##"<g class="peis" data-peis="{p}"><rect x="6" y="{y:.1}" width="{w:.1}" height="{h:.1}" rx="8" fill="#f3f6fa" stroke="#9aa9bb"/><text x="14" y="{ty:.1}" font-weight="bold" fill="#34495e">{p}</text></g>"##,
                p = escape(peis),
                y = band_top[band],
                w = width - 12.0,
                ty = band_top[band] + 20.0,
            );
        }
        for e in &self.edges {
            if e.from >= self.nodes.len() || e.to >= self.nodes.len() {
                continue;
            }
            let (fx, fy) = xy(e.from);
            let (tx, ty) = xy(e.to);
            let (x1, y1) = (fx + NODE_W, fy + NODE_H / 2.0);
            let (x2, y2) = (tx, ty + NODE_H / 2.0);
            let remote = self.nodes[e.from].peis != self.nodes[e.to].peis;
            let dash = if remote {
                r#" stroke-dasharray="6 4""#
            } else {
                ""
            };
            let bend = ((x2 - x1).abs() / 2.0).max(30.0);
            let _ = writeln!(
                out,
                r##"<g class="channel{remote}"><path d="M {x1:.1} {y1:.1} C {c1:.1} {y1:.1}, {c2:.1} {y2:.1}, {x2:.1} {y2:.1}" fill="none" stroke="#444" stroke-width="1.5"{dash} marker-end="url(#arrow)"/><text x="{lx:.1}" y="{ly:.1}" font-size="10" fill="#555" text-anchor="middle">{info}</text></g>"##,
                remote = if remote { " remote" } else { "" },
                c1 = x1 + bend,
                c2 = x2 - bend,
                lx = (x1 + x2) / 2.0,
                ly = (y1 + y2) / 2.0 - 4.0,
                info = escape(&e.info),
            );
        }
        for (i, n) in self.nodes.iter().enumerate() {
            let (x, y) = xy(i);
            let (fill, stroke, dash, class) = match n.mark {
                Mark::Normal => ("#ffffff", "#2c3e50", "", "functionality"),
                Mark::SwitchedOn => ("#eafaf1", "#1e8449", "", "functionality switched-on"),
                Mark::Failed => ("#fdecea", "#c0392b", r#" stroke-dasharray="4 3""#, "failed"),
            };
            let _ = writeln!(
                out,
                r##"<g class="{class}" data-component="{p}:{c}"><rect x="{x:.1}" y="{y:.1}" width="{NODE_W}" height="{NODE_H}" rx="6" fill="{fill}" stroke="{stroke}" stroke-width="1.6"{dash}/><text x="{tx:.1}" y="{y1:.1}">{label}</text><text x="{tx:.1}" y="{y2:.1}" font-size="10" fill="#555">{p}:{c} · {detail}</text></g>"##,
                p = escape(&n.peis),
                c = escape(&n.component),
                tx = x + 8.0,
                y1 = y + 18.0,
                y2 = y + 35.0,
                label = escape(&shorten(&n.label)),
                detail = escape(&shorten(&n.detail)),
            );
        }
        out.push_str("</svg>\n");
        out
    }
}

fn shorten(text: &str) -> String {
    if text.chars().count() <= MAX_LABEL {
        text.to_owned()
    } else {
        let mut s: String = text.chars().take(MAX_LABEL - 1).collect();
        s.push('…');
        s
    }
}

/// Text made safe inside SVG (and HTML) elements and attributes.
pub fn escape(text: &str) -> String {
    let mut out = String::with_capacity(text.len());
    for c in text.chars() {
        match c {
            '&' => out.push_str("&amp;"),
            '<' => out.push_str("&lt;"),
            '>' => out.push_str("&gt;"),
            '"' => out.push_str("&quot;"),
            '\'' => out.push_str("&#39;"),
            c if c.is_control() => out.push(' '),
            c => out.push(c),
        }
    }
    out
}

#[cfg(test)]
mod tests {
    use super::*;

    fn node(peis: &str, component: &str, mark: Mark) -> Node {
        Node {
            peis: peis.into(),
            component: component.into(),
            label: format!("({component} {peis})"),
            detail: "cost 20".into(),
            mark,
        }
    }

    #[test]
    fn producers_are_left_of_consumers_and_remote_channels_are_dashed() {
        let drawing = Drawing {
            title: "(navigate astrid bedroom): cost 80 <optimal>".into(),
            nodes: vec![
                node("astrid", "tc1", Mark::Normal),
                node("hsm", "ca1", Mark::Normal),
                node("hsm", "tr1", Mark::SwitchedOn),
                node("hsm", "x9", Mark::Failed),
            ],
            edges: vec![
                Edge {
                    from: 1,
                    to: 2,
                    info: "(image hsm)".into(),
                },
                Edge {
                    from: 2,
                    to: 0,
                    info: "(global-pos astrid)".into(),
                },
            ],
        };
        assert_eq!(drawing.columns(), [2, 0, 1, 0]);
        let svg = drawing.svg();
        assert!(svg.starts_with("<svg xmlns=\"http://www.w3.org/2000/svg\""));
        assert!(svg.contains("cost 80 &lt;optimal&gt;"), "{svg}");
        assert_eq!(svg.matches("class=\"channel remote\"").count(), 1);
        assert_eq!(svg.matches("class=\"channel\"").count(), 1);
        assert!(svg.contains(r#"class="failed" data-component="hsm:x9""#));
        assert!(svg.contains(r#"class="functionality switched-on" data-component="hsm:tr1""#));
        assert_eq!(svg.matches("class=\"peis\"").count(), 2);
        assert!(svg.trim_end().ends_with("</svg>"));
    }

    #[test]
    fn cycles_and_bad_indices_do_not_hang_or_panic() {
        let drawing = Drawing {
            title: String::new(),
            nodes: vec![node("a", "x", Mark::Normal), node("a", "y", Mark::Normal)],
            edges: vec![
                Edge {
                    from: 0,
                    to: 1,
                    info: String::new(),
                },
                Edge {
                    from: 1,
                    to: 0,
                    info: String::new(),
                },
                Edge {
                    from: 7,
                    to: 0,
                    info: String::new(),
                },
            ],
        };
        assert!(drawing.svg().contains("</svg>"));
        assert!(Drawing::default().svg().contains("</svg>"));
    }
}

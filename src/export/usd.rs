//! The USD layer of a run (`export.usd`): `<shot>.usda`, one `Volume` prim whose `OpenVDBAsset`
//! fields are the VDB sequence, as Solaris/Karma, usdview and other USD pipelines take a volume.
//!
//! Written as text (USD's `usda` format, no USD library): the stage's `metersPerUnit`
//! (`export.scale`), `upAxis` (`export.up_axis`), `timeCodesPerSecond` and `framesPerSecond`
//! (`output.fps`), the start and end time codes (the first and last frame written), and per
//! grid of the VDB files (aliases included) an `OpenVDBAsset` with its `fieldName`,
//! `fieldDataType`, `fieldClass` and a `filePath` time sample per written frame (time code =
//! frame number), relative to the layer so the directory can move. The text depends only on
//! its inputs: the same frames give the same bytes.
use super::{ExportSpace, GridKind, VdbGridName};
use crate::config::UpAxis;
use std::fmt::Write as _;

/// `<shot>.usda`, at the root of a run or export directory.
pub fn layer_name(shot: &str) -> String {
    format!("{shot}.usda")
}

/// What the layer describes.
#[derive(Debug, Clone)]
pub struct Layer<'a> {
    pub shot: &'a str,
    /// Grids of the VDB files in file order (`export::vdb_grid_names`).
    pub grids: &'a [VdbGridName],
    /// OpenVDB class of the velocity grid; the float grids are fog volumes.
    pub space: &'a ExportSpace,
    /// Written frames and the VDB file of each, relative to the layer's directory.
    pub frames: &'a [(u32, String)],
}

/// A USD identifier from any name: characters other than letters, digits and `_` become `_`,
/// and a leading digit (or an empty name) gets a `_` in front.
pub fn identifier(name: &str) -> String {
    let mut s: String = name
        .chars()
        .map(|c| {
            if c.is_ascii_alphanumeric() || c == '_' {
                c
            } else {
                '_'
            }
        })
        .collect();
    if s.is_empty() || s.starts_with(|c: char| c.is_ascii_digit()) {
        s.insert(0, '_');
    }
    s
}

/// A quoted usda string.
fn quoted(s: &str) -> String {
    let mut out = String::with_capacity(s.len() + 2);
    out.push('"');
    for c in s.chars() {
        match c {
            '"' => out.push_str("\\\""),
            '\\' => out.push_str("\\\\"),
            '\n' => out.push_str("\\n"),
            c => out.push(c),
        }
    }
    out.push('"');
    out
}

/// A usda asset path, `@./rel@` (`@@@...@@@` when the path holds an `@`).
fn asset(path: &str) -> String {
    if path.contains('@') {
        format!("@@@./{}@@@", path.replace("@@@", "\\@@@"))
    } else {
        format!("@./{path}@")
    }
}

/// A number as usda writes it: integers without a fraction, others with the shortest digits
/// that read back as the same f64.
fn number(x: f64) -> String {
    if x.fract() == 0.0 && x.abs() < 1e15 {
        format!("{}", x as i64)
    } else {
        format!("{x:?}")
    }
}

impl Layer<'_> {
    /// The layer's text; `None` before the first frame is written.
    pub fn text(&self) -> Option<String> {
        let first = self.frames.iter().map(|f| f.0).min()?;
        let last = self.frames.iter().map(|f| f.0).max()?;
        let s = self.space;
        let prim = identifier(self.shot);
        let mut t = String::new();
        let _ = writeln!(t, "#usda 1.0");
        let _ = writeln!(t, "(");
        let _ = writeln!(t, "    customLayerData = {{");
        let _ = writeln!(
            t,
            "        string creator = {}",
            quoted(&format!("nimbus {}", crate::VERSION))
        );
        let _ = writeln!(t, "        string nimbus_profile = {}", quoted(&s.profile));
        let _ = writeln!(t, "        string nimbus_shot = {}", quoted(self.shot));
        let _ = writeln!(
            t,
            "        string nimbus_velocity_unit = {}",
            quoted(&s.velocity_unit)
        );
        let _ = writeln!(t, "    }}");
        let _ = writeln!(t, "    defaultPrim = {}", quoted(&prim));
        let _ = writeln!(
            t,
            "    doc = {}",
            quoted(&format!(
                "nimbus shot {}: OpenVDB frames {first}-{last}, one time code per frame",
                self.shot
            ))
        );
        let _ = writeln!(t, "    endTimeCode = {last}");
        let _ = writeln!(t, "    framesPerSecond = {}", number(s.fps));
        let _ = writeln!(t, "    metersPerUnit = {}", number(s.scale));
        let _ = writeln!(t, "    startTimeCode = {first}");
        let _ = writeln!(t, "    timeCodesPerSecond = {}", number(s.fps));
        let up = match s.up_axis {
            UpAxis::Y => "Y",
            UpAxis::Z => "Z",
        };
        let _ = writeln!(t, "    upAxis = {}", quoted(up));
        let _ = writeln!(t, ")");
        let _ = writeln!(t);
        let _ = writeln!(t, "def Volume {}", quoted(&prim));
        let _ = writeln!(t, "{{");
        let fields = self.field_prims();
        for name in &fields {
            let _ = writeln!(t, "    rel field:{name} = </{prim}/{name}>");
        }
        for (g, name) in self.grids.iter().zip(&fields) {
            let _ = writeln!(t);
            let _ = writeln!(t, "    def OpenVDBAsset {}", quoted(name));
            let _ = writeln!(t, "    {{");
            // The VDB files' grid classes: fog volumes, the velocity's own, rest grids unknown.
            let class = match (g.kind, s.velocity_class) {
                (GridKind::Scalar, _)
                | (GridKind::Velocity, crate::config::VectorClass::FogVolume) => "fogVolume",
                _ => "unknown",
            };
            let _ = writeln!(t, "        token fieldClass = {}", quoted(class));
            let _ = writeln!(
                t,
                "        token fieldDataType = {}",
                quoted(if g.vector() { "float3" } else { "float" })
            );
            let _ = writeln!(t, "        token fieldName = {}", quoted(&g.name));
            if g.vector() {
                let role = if g.kind == GridKind::Rest {
                    "Point"
                } else {
                    "Vector"
                };
                let _ = writeln!(t, "        token vectorDataRoleHint = {}", quoted(role));
            }
            let _ = writeln!(t, "        asset filePath.timeSamples = {{");
            for (frame, path) in self.frames {
                let _ = writeln!(t, "            {frame}: {},", asset(path));
            }
            let _ = writeln!(t, "        }}");
            let _ = writeln!(t, "    }}");
        }
        let _ = writeln!(t, "}}");
        Some(t)
    }

    /// A unique USD identifier per grid (`density`, `vel`, ...; `_2`, `_3` on clashes).
    fn field_prims(&self) -> Vec<String> {
        let mut used = std::collections::BTreeSet::new();
        self.grids
            .iter()
            .map(|g| {
                let base = identifier(&g.name);
                let mut name = base.clone();
                let mut n = 2;
                while !used.insert(name.clone()) {
                    name = format!("{base}_{n}");
                    n += 1;
                }
                name
            })
            .collect()
    }
}

//! Wavefront OBJ meshes for `control.target`: vertices (`v x y z`) and faces (`f a b c ...`,
//! each index `i`, `i/t`, `i//n` or `i/t/n`, negative = from the end); polygons are split into
//! triangle fans. Every other statement (normals, texture coordinates, groups, materials) is
//! skipped. Errors name the line; [`Mesh::check_closed`] says whether the surface is closed.
use std::collections::HashMap;
use std::path::Path;

/// A triangle mesh in the file's own coordinates.
#[derive(Debug, Clone, PartialEq, Default)]
pub struct Mesh {
    pub vertices: Vec<[f64; 3]>,
    pub triangles: Vec<[u32; 3]>,
}

/// Largest OBJ file read (bytes): a target is a coarse shape.
pub const MAX_BYTES: u64 = 64 << 20;

/// Reads and parses an OBJ file; the error is one line without the path.
pub fn read(path: &Path) -> Result<Mesh, String> {
    let meta = std::fs::metadata(path).map_err(|e| format!("cannot read the mesh: {e}"))?;
    if !meta.is_file() {
        return Err("cannot read the mesh: not a file".into());
    }
    if meta.len() > MAX_BYTES {
        return Err(format!(
            "the mesh file has {} bytes; at most {MAX_BYTES} are read",
            meta.len()
        ));
    }
    let bytes = std::fs::read(path).map_err(|e| format!("cannot read the mesh: {e}"))?;
    let text = String::from_utf8(bytes)
        .map_err(|_| "not a text file (an OBJ mesh is UTF-8 or ASCII text)".to_string())?;
    parse(&text)
}

/// Parses OBJ text.
pub fn parse(text: &str) -> Result<Mesh, String> {
    let mut mesh = Mesh::default();
    for (n, raw) in text.lines().enumerate() {
        let line = n + 1;
        let body = raw.split('#').next().unwrap_or("");
        let mut words = body.split_whitespace();
        match words.next() {
            Some("v") => {
                let xs: Vec<&str> = words.collect();
                if xs.len() < 3 {
                    return Err(format!(
                        "line {line}: a vertex needs 3 coordinates, got {}",
                        xs.len()
                    ));
                }
                let mut v = [0.0; 3];
                for (a, w) in xs.iter().take(3).enumerate() {
                    v[a] = w
                        .parse::<f64>()
                        .ok()
                        .filter(|x| x.is_finite())
                        .ok_or_else(|| format!("line {line}: '{w}' is not a finite number"))?;
                }
                mesh.vertices.push(v);
            }
            Some("f") => {
                let mut idx = Vec::new();
                for w in words {
                    let first = w.split('/').next().unwrap_or("");
                    let i: i64 = first
                        .parse()
                        .map_err(|_| format!("line {line}: '{w}' is not a vertex index"))?;
                    let count = mesh.vertices.len() as i64;
                    let k = if i > 0 { i - 1 } else { count + i };
                    if i == 0 || !(0..count).contains(&k) {
                        return Err(format!(
                            "line {line}: vertex index {i} is outside the {count} vertices defined so far"
                        ));
                    }
                    idx.push(k as u32);
                }
                if idx.len() < 3 {
                    return Err(format!(
                        "line {line}: a face needs at least 3 vertices, got {}",
                        idx.len()
                    ));
                }
                for k in 1..idx.len() - 1 {
                    mesh.triangles.push([idx[0], idx[k], idx[k + 1]]);
                }
            }
            _ => {}
        }
    }
    if mesh.triangles.is_empty() {
        return Err("the mesh has no faces".into());
    }
    Ok(mesh)
}

impl Mesh {
    /// Ok when the surface is closed: every edge is shared by exactly two triangles (a
    /// triangle whose corners repeat a vertex counts as a hole too).
    pub fn check_closed(&self) -> Result<(), String> {
        let mut edges: HashMap<(u32, u32), u32> = HashMap::new();
        for t in &self.triangles {
            if t[0] == t[1] || t[1] == t[2] || t[0] == t[2] {
                return Err(format!(
                    "a face repeats vertex {}: the mesh is degenerate",
                    if t[0] == t[1] { t[0] } else { t[2] } + 1
                ));
            }
            for (a, b) in [(t[0], t[1]), (t[1], t[2]), (t[2], t[0])] {
                *edges.entry((a.min(b), a.max(b))).or_default() += 1;
            }
        }
        let mut bad: Vec<(&(u32, u32), &u32)> = edges.iter().filter(|(_, n)| **n != 2).collect();
        bad.sort();
        match bad.first() {
            None => Ok(()),
            Some(((a, b), n)) => Err(format!(
                "the mesh is not closed: {} edges are not shared by exactly two faces (edge between vertices {} and {} belongs to {n})",
                bad.len(),
                a + 1,
                b + 1
            )),
        }
    }

    /// Axis-aligned bounds (min, max).
    pub fn bounds(&self) -> ([f64; 3], [f64; 3]) {
        let mut lo = [f64::INFINITY; 3];
        let mut hi = [f64::NEG_INFINITY; 3];
        for v in &self.vertices {
            for a in 0..3 {
                lo[a] = lo[a].min(v[a]);
                hi[a] = hi[a].max(v[a]);
            }
        }
        (lo, hi)
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    const CUBE: &str = "v 0 0 0\nv 1 0 0\nv 1 1 0\nv 0 1 0\nv 0 0 1\nv 1 0 1\nv 1 1 1\nv 0 1 1\n\
        f 1 4 3 2\nf 5 6 7 8\nf 1 2 6 5\nf 2 3 7 6\nf 3 4 8 7\nf 4 1 5 8\n";

    #[test]
    fn cube_is_closed_and_an_open_box_is_not() {
        let m = parse(CUBE).unwrap();
        assert_eq!((m.vertices.len(), m.triangles.len()), (8, 12));
        assert!(m.check_closed().is_ok());
        let open = parse(&CUBE.replace("f 4 1 5 8\n", "")).unwrap();
        let err = open.check_closed().unwrap_err();
        assert!(
            err.contains("not closed") && err.contains("4 edges"),
            "{err}"
        );
        // one face twice: its edges belong to three faces
        let twice = parse(&format!("{CUBE}f 1 4 3 2\n")).unwrap();
        assert!(twice.check_closed().is_err());
    }

    #[test]
    fn index_forms_and_errors() {
        let m = parse("v 0 0 0\nv 1 0 0 # c\nv 0 1 0\nf 1/1/1 2//2 -1\nvn 0 0 1\n").unwrap();
        assert_eq!(m.triangles, vec![[0, 1, 2]]);
        assert!(parse("v 0 0 0\n").unwrap_err().contains("no faces"));
        assert!(parse("v 0 0\n").unwrap_err().starts_with("line 1:"));
        assert!(parse("v 0 0 0\nf 1 2 3\n")
            .unwrap_err()
            .starts_with("line 2: vertex index 2"));
        assert!(parse("v 0 0 x\n").unwrap_err().contains("'x'"));
        assert!(parse("v 0 0 0\nv 1 0 0\nf 1 2\n")
            .unwrap_err()
            .contains("at least 3"));
    }
}

//! Triangle meshes from CT segmentations: STL (binary and ASCII) and PLY (`ascii` and
//! `binary_little_endian`; vertex `x y z` as float/double, faces as a list of indices).
//! Every count, index and number is checked: a damaged file is an error naming the file
//! and what is wrong, never a panic.
use std::path::Path;

use nalgebra::{Point3, Vector3};

use super::{io_err, RegisterError};

/// A triangle mesh (mm).
#[derive(Debug, Clone, Default, PartialEq)]
pub struct Mesh {
    pub vertices: Vec<Point3<f64>>,
    pub triangles: Vec<[usize; 3]>,
}

impl Mesh {
    /// Unit normal and area of triangle `k` (zero normal for a degenerate triangle).
    pub fn normal_area(&self, k: usize) -> (Vector3<f64>, f64) {
        let [a, b, c] = self.triangles[k];
        let n = (self.vertices[b] - self.vertices[a]).cross(&(self.vertices[c] - self.vertices[a]));
        let l = n.norm();
        if l > 0.0 {
            (n / l, 0.5 * l)
        } else {
            (Vector3::zeros(), 0.0)
        }
    }

    /// Writes binary STL.
    pub fn write_stl(&self, path: &Path) -> Result<(), RegisterError> {
        let mut b = Vec::with_capacity(84 + 50 * self.triangles.len());
        b.extend_from_slice(&[0u8; 80]);
        b.extend_from_slice(&(self.triangles.len() as u32).to_le_bytes());
        for k in 0..self.triangles.len() {
            let (n, _) = self.normal_area(k);
            for x in n.iter() {
                b.extend_from_slice(&(*x as f32).to_le_bytes());
            }
            for &v in &self.triangles[k] {
                for x in self.vertices[v].coords.iter() {
                    b.extend_from_slice(&(*x as f32).to_le_bytes());
                }
            }
            b.extend_from_slice(&[0, 0]);
        }
        crate::fsio::write(path, b).map_err(|e| io_err(path, e))
    }

    /// Writes ASCII PLY (full f64 precision).
    pub fn write_ply(&self, path: &Path) -> Result<(), RegisterError> {
        use std::fmt::Write as _;
        let mut s = String::new();
        let _ = write!(
            s,
            "ply\nformat ascii 1.0\nelement vertex {}\nproperty double x\nproperty double y\nproperty double z\nelement face {}\nproperty list uchar int vertex_indices\nend_header\n",
            self.vertices.len(),
            self.triangles.len()
        );
        for v in &self.vertices {
            let _ = writeln!(s, "{} {} {}", v.x, v.y, v.z);
        }
        for t in &self.triangles {
            let _ = writeln!(s, "3 {} {} {}", t[0], t[1], t[2]);
        }
        crate::fsio::write(path, s).map_err(|e| io_err(path, e))
    }
}

fn bad(file: &str, msg: impl Into<String>) -> RegisterError {
    RegisterError::Input {
        file: file.into(),
        line: 0,
        msg: msg.into(),
    }
}

/// Reads an STL or PLY mesh (by content: `ply` magic, `solid` + `facet` text, else binary STL).
pub fn read_mesh(path: &Path) -> Result<Mesh, RegisterError> {
    let bytes = crate::fsio::read(path).map_err(|e| io_err(path, e))?;
    let file = path.display().to_string();
    let mesh = parse_mesh(&bytes, &file)?;
    check_mesh(&mesh, &file)?;
    Ok(mesh)
}

/// Parses mesh bytes.
pub fn parse_mesh(bytes: &[u8], file: &str) -> Result<Mesh, RegisterError> {
    if bytes.starts_with(b"ply") {
        return parse_ply(bytes, file);
    }
    let head = &bytes[..bytes.len().min(512)];
    let is_ascii_stl = bytes.starts_with(b"solid")
        && head.windows(5).any(|w| w == b"facet")
        && std::str::from_utf8(bytes).is_ok();
    if is_ascii_stl {
        parse_stl_ascii(std::str::from_utf8(bytes).unwrap_or(""), file)
    } else {
        parse_stl_binary(bytes, file)
    }
}

fn check_mesh(m: &Mesh, file: &str) -> Result<(), RegisterError> {
    if m.triangles.is_empty() {
        return Err(bad(file, "the mesh has no triangles"));
    }
    if let Some(v) = m
        .vertices
        .iter()
        .find(|v| !v.coords.iter().all(|x| x.is_finite()))
    {
        return Err(bad(file, format!("non-finite vertex {v:?}")));
    }
    Ok(())
}

/// Merges identical vertices (STL stores each triangle's corners separately).
fn weld(corners: Vec<Point3<f64>>) -> Mesh {
    use std::collections::HashMap;
    let mut map: HashMap<[u64; 3], usize> = HashMap::new();
    let mut vertices = Vec::new();
    let mut idx = Vec::with_capacity(corners.len());
    for c in corners {
        let key = [c.x.to_bits(), c.y.to_bits(), c.z.to_bits()];
        let i = *map.entry(key).or_insert_with(|| {
            vertices.push(c);
            vertices.len() - 1
        });
        idx.push(i);
    }
    let triangles = idx.chunks_exact(3).map(|t| [t[0], t[1], t[2]]).collect();
    Mesh {
        vertices,
        triangles,
    }
}

fn parse_stl_binary(b: &[u8], file: &str) -> Result<Mesh, RegisterError> {
    if b.len() < 84 {
        return Err(bad(
            file,
            format!(
                "{} bytes: too short for a binary STL (84-byte header) and not PLY or ASCII STL",
                b.len()
            ),
        ));
    }
    let n = u32::from_le_bytes([b[80], b[81], b[82], b[83]]) as usize;
    let need = 84usize.saturating_add(n.saturating_mul(50));
    if b.len() != need {
        return Err(bad(
            file,
            format!("binary STL declares {n} triangles ({need} bytes) but the file has {} bytes (truncated, or not an STL)", b.len()),
        ));
    }
    let f = |o: usize| f32::from_le_bytes([b[o], b[o + 1], b[o + 2], b[o + 3]]) as f64;
    let mut corners = Vec::with_capacity(3 * n);
    for k in 0..n {
        let o = 84 + 50 * k + 12;
        for v in 0..3 {
            let p = o + 12 * v;
            corners.push(Point3::new(f(p), f(p + 4), f(p + 8)));
        }
    }
    Ok(weld(corners))
}

fn parse_stl_ascii(s: &str, file: &str) -> Result<Mesh, RegisterError> {
    let mut corners = Vec::new();
    for (i, line) in s.lines().enumerate() {
        let t = line.trim();
        if let Some(rest) = t.strip_prefix("vertex") {
            let v: Result<Vec<f64>, _> =
                rest.split_whitespace().map(|x| x.parse::<f64>()).collect();
            match v {
                Ok(v) if v.len() == 3 => corners.push(Point3::new(v[0], v[1], v[2])),
                _ => {
                    return Err(RegisterError::Input {
                        file: file.into(),
                        line: i + 1,
                        msg: format!("bad STL vertex line `{t}`"),
                    })
                }
            }
        }
    }
    if corners.len() % 3 != 0 {
        return Err(bad(
            file,
            format!("{} vertices is not a multiple of 3", corners.len()),
        ));
    }
    Ok(weld(corners))
}

#[derive(Clone, Copy, PartialEq)]
enum Scalar {
    I8,
    U8,
    I16,
    U16,
    I32,
    U32,
    F32,
    F64,
}

fn scalar(s: &str) -> Option<Scalar> {
    Some(match s {
        "char" | "int8" => Scalar::I8,
        "uchar" | "uint8" => Scalar::U8,
        "short" | "int16" => Scalar::I16,
        "ushort" | "uint16" => Scalar::U16,
        "int" | "int32" => Scalar::I32,
        "uint" | "uint32" => Scalar::U32,
        "float" | "float32" => Scalar::F32,
        "double" | "float64" => Scalar::F64,
        _ => return None,
    })
}

fn size_of(s: Scalar) -> usize {
    match s {
        Scalar::I8 | Scalar::U8 => 1,
        Scalar::I16 | Scalar::U16 => 2,
        Scalar::I32 | Scalar::U32 | Scalar::F32 => 4,
        Scalar::F64 => 8,
    }
}

enum Prop {
    Scalar(String, Scalar),
    List(String, Scalar, Scalar),
}

struct Element {
    name: String,
    count: usize,
    props: Vec<Prop>,
}

/// Reader of values from ASCII tokens or little-endian bytes.
enum Src<'a> {
    Ascii(std::str::SplitWhitespace<'a>),
    Bin(&'a [u8], usize),
}

impl Src<'_> {
    fn read(&mut self, s: Scalar) -> Option<f64> {
        match self {
            Src::Ascii(it) => it.next()?.parse::<f64>().ok(),
            Src::Bin(b, o) => {
                let n = size_of(s);
                let x = b.get(*o..*o + n)?;
                *o += n;
                Some(match s {
                    Scalar::I8 => x[0] as i8 as f64,
                    Scalar::U8 => x[0] as f64,
                    Scalar::I16 => i16::from_le_bytes([x[0], x[1]]) as f64,
                    Scalar::U16 => u16::from_le_bytes([x[0], x[1]]) as f64,
                    Scalar::I32 => i32::from_le_bytes([x[0], x[1], x[2], x[3]]) as f64,
                    Scalar::U32 => u32::from_le_bytes([x[0], x[1], x[2], x[3]]) as f64,
                    Scalar::F32 => f32::from_le_bytes([x[0], x[1], x[2], x[3]]) as f64,
                    Scalar::F64 => {
                        f64::from_le_bytes([x[0], x[1], x[2], x[3], x[4], x[5], x[6], x[7]])
                    }
                })
            }
        }
    }
}

fn parse_ply(b: &[u8], file: &str) -> Result<Mesh, RegisterError> {
    let end = b
        .windows(10)
        .position(|w| w == b"end_header")
        .ok_or_else(|| bad(file, "PLY without `end_header`"))?;
    let mut body = end + 10;
    while body < b.len() && (b[body] == b'\r' || b[body] == b'\n' || b[body] == b' ') {
        body += 1;
        if b[body - 1] == b'\n' {
            break;
        }
    }
    let header = std::str::from_utf8(&b[..end]).map_err(|_| bad(file, "PLY header is not text"))?;
    let mut format = None;
    let mut elements: Vec<Element> = Vec::new();
    for (i, line) in header.lines().enumerate() {
        let t: Vec<&str> = line.split_whitespace().collect();
        let herr = |m: &str| RegisterError::Input {
            file: file.into(),
            line: i + 1,
            msg: format!("PLY header: {m} in `{}`", line.trim()),
        };
        match t.first().copied() {
            Some("format") => format = t.get(1).map(|s| s.to_string()),
            Some("element") => {
                let count = t
                    .get(2)
                    .and_then(|c| c.parse().ok())
                    .ok_or_else(|| herr("bad element count"))?;
                elements.push(Element {
                    name: t.get(1).unwrap_or(&"").to_string(),
                    count,
                    props: Vec::new(),
                });
            }
            Some("property") => {
                let el = elements
                    .last_mut()
                    .ok_or_else(|| herr("property before any element"))?;
                if t.get(1) == Some(&"list") {
                    let (c, v) = (
                        t.get(2)
                            .and_then(|s| scalar(s))
                            .ok_or_else(|| herr("bad list count type"))?,
                        t.get(3)
                            .and_then(|s| scalar(s))
                            .ok_or_else(|| herr("bad list value type"))?,
                    );
                    el.props
                        .push(Prop::List(t.get(4).unwrap_or(&"").to_string(), c, v));
                } else {
                    let s = t
                        .get(1)
                        .and_then(|s| scalar(s))
                        .ok_or_else(|| herr("bad property type"))?;
                    el.props
                        .push(Prop::Scalar(t.get(2).unwrap_or(&"").to_string(), s));
                }
            }
            _ => {}
        }
    }
    let mut src = match format.as_deref() {
        Some("ascii") => Src::Ascii(
            std::str::from_utf8(&b[body..])
                .map_err(|_| bad(file, "ASCII PLY body is not text"))?
                .split_whitespace(),
        ),
        Some("binary_little_endian") => Src::Bin(b, body),
        Some(f) => {
            return Err(bad(
                file,
                format!("PLY format `{f}` not supported (ascii, binary_little_endian)"),
            ))
        }
        None => return Err(bad(file, "PLY header has no `format` line")),
    };
    let mut mesh = Mesh::default();
    let trunc = |what: &str| {
        bad(
            file,
            format!("PLY body ends early or holds a bad number ({what})"),
        )
    };
    for el in &elements {
        // Guard absurd counts before allocating.
        if el.count > b.len() {
            return Err(bad(
                file,
                format!(
                    "element `{}` count {} exceeds the file size",
                    el.name, el.count
                ),
            ));
        }
        for _ in 0..el.count {
            let mut xyz = [f64::NAN; 3];
            for p in &el.props {
                match p {
                    Prop::Scalar(name, s) => {
                        let v = src.read(*s).ok_or_else(|| trunc(&el.name))?;
                        if el.name == "vertex" {
                            match name.as_str() {
                                "x" => xyz[0] = v,
                                "y" => xyz[1] = v,
                                "z" => xyz[2] = v,
                                _ => {}
                            }
                        }
                    }
                    Prop::List(name, c, s) => {
                        let n = src.read(*c).ok_or_else(|| trunc(&el.name))?;
                        if !(0.0..=1e6).contains(&n) || n.fract() != 0.0 {
                            return Err(bad(file, format!("bad list length {n} in `{}`", el.name)));
                        }
                        let mut idx = Vec::with_capacity(n as usize);
                        for _ in 0..n as usize {
                            idx.push(src.read(*s).ok_or_else(|| trunc(&el.name))?);
                        }
                        if el.name == "face" && (name == "vertex_indices" || name == "vertex_index")
                        {
                            if idx.len() < 3 {
                                return Err(bad(file, "a face with fewer than 3 vertices"));
                            }
                            let ix: Vec<usize> = idx
                                .iter()
                                .map(|&v| {
                                    if v >= 0.0 && v.fract() == 0.0 {
                                        Ok(v as usize)
                                    } else {
                                        Err(bad(file, format!("bad vertex index {v}")))
                                    }
                                })
                                .collect::<Result<_, _>>()?;
                            for k in 1..ix.len() - 1 {
                                mesh.triangles.push([ix[0], ix[k], ix[k + 1]]);
                            }
                        }
                    }
                }
            }
            if el.name == "vertex" {
                if xyz.iter().any(|x| x.is_nan()) {
                    return Err(bad(file, "vertex without x, y, z"));
                }
                mesh.vertices.push(Point3::new(xyz[0], xyz[1], xyz[2]));
            }
        }
    }
    let nv = mesh.vertices.len();
    if let Some(t) = mesh.triangles.iter().find(|t| t.iter().any(|&i| i >= nv)) {
        return Err(bad(
            file,
            format!("face {t:?} indexes past the {nv} vertices"),
        ));
    }
    Ok(mesh)
}

#[cfg(test)]
mod tests {
    use super::*;

    fn tetra() -> Mesh {
        Mesh {
            vertices: vec![
                Point3::new(0.0, 0.0, 0.0),
                Point3::new(10.0, 0.0, 0.0),
                Point3::new(0.0, 10.0, 0.0),
                Point3::new(0.0, 0.0, 10.0),
            ],
            triangles: vec![[0, 2, 1], [0, 1, 3], [0, 3, 2], [1, 2, 3]],
        }
    }

    #[test]
    fn stl_and_ply_round_trip_and_damage_is_an_error() {
        let d = tempfile::tempdir().unwrap();
        let m = tetra();
        let stl = d.path().join("m.stl");
        m.write_stl(&stl).unwrap();
        let r = read_mesh(&stl).unwrap();
        assert_eq!(r.triangles.len(), 4);
        assert_eq!(r.vertices.len(), 4);
        let ply = d.path().join("m.ply");
        m.write_ply(&ply).unwrap();
        assert_eq!(read_mesh(&ply).unwrap(), m);
        // Truncated binary STL.
        let b = crate::fsio::read(&stl).unwrap();
        let e = parse_mesh(&b[..b.len() - 7], "t.stl")
            .unwrap_err()
            .to_string();
        assert!(e.contains("truncated"), "{e}");
        // Bad index in PLY.
        let s = crate::fsio::read_to_string(&ply)
            .unwrap()
            .replace("3 1 2 3", "3 1 2 9");
        let e = parse_mesh(s.as_bytes(), "t.ply").unwrap_err().to_string();
        assert!(e.contains("indexes past"), "{e}");
        // Binary little-endian PLY.
        let mut bin = b"ply\nformat binary_little_endian 1.0\nelement vertex 3\nproperty float x\nproperty float y\nproperty float z\nelement face 1\nproperty list uchar int vertex_indices\nend_header\n".to_vec();
        for v in [[0f32, 0., 0.], [1., 0., 0.], [0., 1., 0.]] {
            for x in v {
                bin.extend_from_slice(&x.to_le_bytes());
            }
        }
        bin.push(3);
        for i in [0i32, 1, 2] {
            bin.extend_from_slice(&i.to_le_bytes());
        }
        let r = parse_mesh(&bin, "b.ply").unwrap();
        assert_eq!(r.triangles, vec![[0, 1, 2]]);
        let e = parse_mesh(&bin[..bin.len() - 2], "b.ply")
            .unwrap_err()
            .to_string();
        assert!(e.contains("ends early"), "{e}");
        // ASCII STL.
        let a = "solid x\nfacet normal 0 0 1\nouter loop\nvertex 0 0 0\nvertex 1 0 0\nvertex 0 1 0\nendloop\nendfacet\nendsolid x\n";
        assert_eq!(
            parse_mesh(a.as_bytes(), "a.stl").unwrap().triangles.len(),
            1
        );
    }
}
